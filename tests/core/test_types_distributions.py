"""ParamSpace transforms and the sequential proposal correction against exact posteriors."""
import json
import math

import numpy as np
import pytest
from scipy.stats import multivariate_normal, norm

from softsbi.core.distributions import MixtureOfGaussians, PosteriorChain, gaussian
from softsbi.core.errors import ParameterError
from softsbi.core.types import Param, ParamSpace


def space():
    return ParamSpace([Param("bend", 1e-6, 1e-3, "N*m", log=True), Param("friction", 0.0, 2.0)])


def test_unit_transform_round_trip_and_log_scale():
    ps = space()
    theta = np.array([[1e-6, 0.0], [1e-3, 2.0], [np.sqrt(1e-6 * 1e-3), 1.0]])
    u = ps.to_unit(theta)
    np.testing.assert_allclose(u, [[0, 0], [1, 1], [0.5, 0.5]], atol=1e-12)
    np.testing.assert_allclose(ps.from_unit(u), theta, rtol=1e-12)
    # the corners of the box map exactly onto the bounds (no rounding outside a log bound)
    corners = ParamSpace([Param("k", 5.0, 1000.0, log=True)]).from_unit(np.array([[0.0], [1.0]]))
    assert corners[0, 0] >= 5.0 and corners[1, 0] <= 1000.0
    # log-uniform prior: the density in physical units integrates to one
    grid = np.geomspace(1e-6, 1e-3, 20001)
    dens = np.exp(ps.subset(["bend"]).log_det_jacobian(grid[:, None]))
    assert np.trapezoid(dens, grid) == pytest.approx(1.0, rel=1e-3)


def test_check_names_the_problem():
    ps = space()
    with pytest.raises(ParameterError, match="Did you mean 'friction'"):
        ps.check({"frictoin": 0.3}, allow_missing=True)
    with pytest.raises(ParameterError, match="outside its bounds"):
        ps.check({"bend": 1e-6, "friction": 3.0})
    with pytest.raises(ParameterError, match="missing"):
        ps.check({"friction": 0.3})
    with pytest.raises(ParameterError, match="low"):
        Param("x", 1.0, 0.5)


def test_prior_bounds_widen_up_to_the_physical_limits_and_a_simulator_accepts_them():
    """``--bounds`` may widen a prior beyond the declared guess (the fix ``bound_sentence`` advises); the
    physical limits, not the declared prior, bound what can be simulated."""
    friction, noise, wind = Param("friction", 0.05, 1.5), Param("noise_std", 0.0, 0.01, "m"), Param("wind_x", -1.0, 1.0)
    assert friction.physical_limits == (0.0, math.inf) and noise.physical_limits == (0.0, math.inf)
    assert wind.physical_limits == (-math.inf, math.inf)
    assert Param("bend", 1e-6, 1e-3, log=True).physical_limits == (0.0, math.inf)
    declared = ParamSpace([friction, noise, wind])
    wide = declared.with_bounds({"friction": (0.05, 2.5), "wind_x": (-3.0, 1.0)})
    assert (wide["friction"].high, wide["wind_x"].low) == (2.5, -3.0)
    # the declared space refuses the widened prior's draws as prior values but accepts them as physical ones
    with pytest.raises(ParameterError, match="outside its bounds"):
        declared.check({"friction": 2.0}, allow_missing=True)
    assert declared.check({"friction": 2.0, "noise_std": 0.02, "wind_x": -3.0}, within="limits")["friction"] == 2.0
    with pytest.raises(ParameterError, match="outside its physical limits"):
        declared.check({"noise_std": -0.001}, allow_missing=True, within="limits")
    # bounds beyond the physical limits: one line naming them
    with pytest.raises(ParameterError, match=r"noise_std.*within its physical limits \[0, inf\]"):
        declared.with_bounds({"noise_std": (-0.01, 0.01)})
    # a widened prior keeps the declared parameter's limits (a prior moved to [0.5, 2] is still >= 0, not >= 0.5)
    assert declared.with_bounds({"friction": (0.5, 2.0)})["friction"].physical_limits == (0.0, math.inf)
    explicit = Param("slope", 0.0, 0.1, limits=(-0.5, 0.5))
    with pytest.raises(ParameterError, match="within its physical limits"):
        Param("slope", 0.0, 1.0, limits=(-0.5, 0.5))
    # the JSON round trip keeps limits (infinite ends as None) and leaves parameters without them unchanged
    for ps in (declared, wide, ParamSpace([explicit])):
        assert ParamSpace.from_json(json.loads(json.dumps(ps.to_json()))) == ps
    assert "limits" not in declared.to_json()[0]


def test_mixture_log_prob_matches_scipy():
    rng = np.random.default_rng(0)
    L = np.array([[[0.2, 0], [0.05, 0.1]], [[0.1, 0], [-0.03, 0.3]]])
    q = MixtureOfGaussians(np.array([0.3, 0.7]), np.array([[0.2, 0.5], [0.6, 0.4]]), L)
    u = rng.random((50, 2))
    ref = np.log(0.3 * multivariate_normal(q.means[0], q.covariances[0]).pdf(u)
                 + 0.7 * multivariate_normal(q.means[1], q.covariances[1]).pdf(u))
    np.testing.assert_allclose(q.log_prob(u), ref, rtol=1e-10)
    s = q.sample(200000, rng)
    np.testing.assert_allclose(s.mean(0), q.mean(), atol=5e-3)
    np.testing.assert_allclose(np.cov(s.T), q.cov(), atol=5e-3)


def test_round0_posterior_is_q_truncated_to_the_prior_box():
    chain = PosteriorChain(1, seed=0)
    post = chain.add_round(gaussian([0.9], [[0.2**2]]), 100)
    grid = np.linspace(0, 1, 4001)[:, None]
    dens = np.exp(post.log_prob(grid))
    ref = norm(0.9, 0.2).pdf(grid[:, 0]) / (norm(0.9, 0.2).cdf(1) - norm(0.9, 0.2).cdf(0))
    np.testing.assert_allclose(dens, ref, rtol=0.02)
    assert np.all(np.isneginf(post.log_prob(np.array([[-0.1], [1.1]]))))
    s = post.sample(20000, np.random.default_rng(1))
    assert s.min() >= 0 and s.max() <= 1
    assert s.mean() == pytest.approx((grid[:, 0] * ref).sum() / ref.sum(), abs=0.01)


def test_sequential_correction_recovers_the_exact_posterior():
    """Known case: the true posterior is N(m, s^2) (inside the box). Round 0 data come from the
    prior; round 1 data from post_0. An exact estimator trained on the pooled data learns
    q_1(u) ∝ m_1(u) p*(u) with m_1 = (c0 U + c1 post_0) / (c0 + c1), which here is a
    two-component Gaussian mixture; the chain must divide m_1 out and return p* again."""
    m, s, c0, c1 = 0.4, 0.08, 100.0, 300.0
    chain = PosteriorChain(1, seed=0, n_norm=200000)
    p0 = chain.add_round(gaussian([m], [[s * s]]), c0)  # exact q_0 = p* (uniform proposal)
    z0 = norm(m, s).cdf(1) - norm(m, s).cdf(0)
    # q_1 ∝ c0 * N(u; m, s) + c1 * N(u; m, s)^2 / z0, and N^2 = N(u; m, s/sqrt2) / (2 sqrt(pi) s)
    w = np.array([c0, c1 / z0 / (2 * np.sqrt(np.pi) * s)])
    q1 = MixtureOfGaussians(w, np.array([[m], [m]]), np.array([[[s]], [[s / np.sqrt(2)]]]))
    p1 = chain.add_round(q1, c1)
    grid = np.linspace(0.01, 0.99, 99)[:, None]
    np.testing.assert_allclose(np.exp(p1.log_prob(grid)), np.exp(p0.log_prob(grid)), rtol=0.03)
    samp = p1.sample(40000, np.random.default_rng(2))
    assert samp.mean() == pytest.approx(m, abs=0.003)
    assert samp.std() == pytest.approx(s, rel=0.03)
    # without the correction (q_1 as the posterior) the result would be too narrow
    assert np.sqrt(q1.cov()[0, 0]) < 0.9 * s


def test_sequential_correction_2d_three_rounds():
    """Same construction in 2-D over three rounds with correlated Gaussians."""
    mean = np.array([0.45, 0.55])
    cov = np.array([[0.004, 0.002], [0.002, 0.006]])
    chain = PosteriorChain(2, seed=3, n_norm=200000)
    rng = np.random.default_rng(4)
    grid = rng.uniform(0.3, 0.7, (200, 2))
    target = multivariate_normal(mean, cov)
    posts = [chain.add_round(gaussian(mean, cov), 200)]
    counts = [200.0]
    for r in (1, 2):
        # exact q_r ∝ m_r p*: mixture of p* (from the prior part) and p* x post_{j} (= N(mean, cov/2) scaled)
        counts.append(150.0)
        comps_w = [counts[0]]
        for j in range(r):
            # post_j equals p* (by induction), so p* x post_j = N(mean, cov/2) * N(mean; mean, 2 cov) / z
            z = 1.0  # p* has essentially all its mass inside the box
            comps_w.append(counts[j + 1] * multivariate_normal(mean, 2 * cov).pdf(mean) / z)
        covs = [cov] + [cov / 2] * r
        q = MixtureOfGaussians(np.array(comps_w), np.tile(mean, (r + 1, 1)), np.linalg.cholesky(np.array(covs)))
        posts.append(chain.add_round(q, counts[-1]))
    np.testing.assert_allclose(np.exp(posts[-1].log_prob(grid)), target.pdf(grid), rtol=0.05)
    s = posts[-1].sample(30000, rng)
    np.testing.assert_allclose(s.mean(0), mean, atol=0.003)
    np.testing.assert_allclose(np.cov(s.T), cov, rtol=0.08, atol=2e-4)


def test_truncated_prior_is_uniform_on_the_posterior_hpd_region():
    """TSNPE proposal of a 2-D Gaussian posterior: the region is the ellipse holding 1 - eps of
    the posterior mass; draws are uniform on it (its centroid) and its prior mass is the
    ellipse's area."""
    from scipy.stats import chi2

    from softsbi.core.distributions import TruncatedPrior
    mean = np.array([0.4, 0.6])
    cov = np.array([[0.004, 0.0015], [0.0015, 0.002]])
    post = PosteriorChain(2, seed=0).add_round(gaussian(mean, cov), 100)
    eps = 1e-3
    tp = TruncatedPrior(post, eps=eps, seed=1)
    r2 = chi2.ppf(1 - eps, 2)
    area = np.pi * r2 * np.sqrt(np.linalg.det(cov))
    assert tp.prior_mass == pytest.approx(area, rel=0.05)
    s = tp.sample(20000, np.random.default_rng(2))
    d2 = np.einsum("ni,ij,nj->n", s - mean, np.linalg.inv(cov), s - mean)
    assert d2.max() <= r2 * 1.01  # inside the region
    assert np.mean(d2 > 0.5 * r2) == pytest.approx(0.5, abs=0.02)  # uniform: half the area beyond r/sqrt2
    np.testing.assert_allclose(s.mean(0), mean, atol=0.004)
    # the region holds 1 - eps of the posterior
    ps = post.sample(50000, np.random.default_rng(3))
    assert tp.in_region(ps).mean() == pytest.approx(1 - eps, abs=1e-3)
    lp = tp.log_prob(np.array([mean, [0.95, 0.05]]))
    assert lp[0] == pytest.approx(-np.log(tp.prior_mass)) and np.isneginf(lp[1])
    with pytest.raises(ValueError, match="eps"):
        TruncatedPrior(post, eps=0.0)
    # a posterior with no finite density at its own draws defines no region: one clear error, not numpy's
    from softsbi.core.errors import PosteriorError
    broken = type("Broken", (), {"sample": post.sample, "log_prob": lambda self, u: np.full(len(u), -np.inf)})()
    with pytest.raises(PosteriorError, match="no finite density at any of its 20000 draws"):
        TruncatedPrior(broken)


def test_posterior_draws_are_not_repeated_when_importance_weights_are_uneven():
    """Sampling-importance-resampling from a corrected posterior whose weights vary by orders of
    magnitude (narrow proposal, broad q) draws until the effective sample size is large
    enough: a small sample holds no repeated rows."""
    chain = PosteriorChain(3, seed=0)
    chain.add_round(gaussian([0.5] * 3, np.eye(3) * 0.03 ** 2), 100)  # narrow round-0 posterior
    post = chain.add_round(gaussian([0.5] * 3, np.eye(3) * 0.04 ** 2), 900)  # q barely wider
    u = post.q.sample(2000, np.random.default_rng(0))
    lw = post._log_w(u)
    w = np.exp(lw - lw.max())
    assert w.sum() ** 2 / (w * w).sum() < 100  # 2000 draws from q are worth < 100 posterior draws
    s = post.sample(30, np.random.default_rng(0))
    assert len(np.unique(s, axis=0)) == 30


def test_a_posterior_outside_the_prior_box_gives_a_clear_error():
    from softsbi.core.errors import PosteriorError
    post = PosteriorChain(2, seed=0).add_round(gaussian([5.0, 5.0], np.eye(2) * 0.01), 100)
    assert post.mass_in_box == 0.0
    with pytest.raises(PosteriorError, match="no mass inside the prior box; widen the prior bounds"):
        post.sample(10, np.random.default_rng(0))
