"""Honest Monte-Carlo statistics (softsbi.workflows.criticism.stats): p-values, max-T, adaptive resolution."""
from dataclasses import replace

import numpy as np
import pytest

from softsbi.core.errors import SoftsbiError
from softsbi.core.results import JointTest, MCPValue
from softsbi.workflows.criticism.statistics import max_t_adjusted, mc_pvalue, misspecification_test, resolution_needed
from softsbi.workflows.fit.jobs import JobResult


def test_monte_carlo_p_value_counts_and_never_goes_below_its_resolution():
    null = np.arange(30, dtype=float)
    p = mc_pvalue(26.5, null)  # 27, 28, 29 are as extreme
    assert (p.exceed, p.n) == (3, 30) and p.value == pytest.approx(4 / 31)
    assert not p.at_floor and p.floor == pytest.approx(1 / 31)
    far = mc_pvalue(1e9, null)
    assert far.value == pytest.approx(1 / 31) == far.floor and far.at_floor
    assert far.exceed == 0 and far.n == 30
    assert mc_pvalue(29.0, null).exceed == 1  # ties count as extreme
    with pytest.raises(SoftsbiError, match="non-finite"):
        mc_pvalue(np.nan, null)
    with pytest.raises(SoftsbiError, match="at least one"):
        mc_pvalue(1.0, [])


def test_misspecification_test_is_calibrated_and_floored():
    rng = np.random.default_rng(0)
    sims = rng.normal(size=(40, 30))
    s_in, inside = misspecification_test(rng.normal(size=30), sims)
    s_out, outside = misspecification_test(rng.normal(size=30) + 3.0, sims)
    assert inside.value > 0.05 and inside.n == 40
    assert outside.exceed == 0 and outside.value == pytest.approx(1 / 41)
    assert s_out > 5 * s_in and outside.at_floor and outside.n == 40
    # under the null the p-value is (close to) uniform: rejections at 0.1 about 10% of the time
    rej = [misspecification_test(rng.normal(size=30), rng.normal(size=(19, 30)))[1].value <= 0.1
           for _ in range(300)]
    assert abs(np.mean(rej) - 0.1) < 3 * np.sqrt(0.1 * 0.9 / 300)


def _correlated(rng, n, C, rho=0.6):
    common = rng.normal(size=(n, 1))
    return np.sqrt(rho) * common + np.sqrt(1 - rho) * rng.normal(size=(n, C))


def test_max_t_controls_the_family_wise_error_and_beats_bonferroni_at_low_resolution():
    rng = np.random.default_rng(1)
    C, n, alpha, reps = 5, 39, 0.05, 1500
    fwe = 0
    for _ in range(reps):
        x = _correlated(rng, n + 1, C) ** 2  # chi-square-like drops, dependent across candidates
        adj, _ = max_t_adjusted(x[0], x[1:])
        fwe += min(p.value for p in adj) <= alpha
    rate = fwe / reps
    assert rate <= alpha + 3 * np.sqrt(alpha * (1 - alpha) / reps)
    assert rate > alpha / 3  # and not absurdly conservative
    # adjusted p-values are never below the marginal ones
    x = _correlated(rng, n + 1, C) ** 2
    adj, z = max_t_adjusted(x[0], x[1:])
    for c in range(C):
        assert adj[c].value >= mc_pvalue(x[0, c], x[1:, c]).value
    # one strong candidate among five with 30 nulls: max-T can reach 1/31 < 0.05, Bonferroni needs
    # a marginal p <= 0.01 that 30 nulls cannot give
    null = _correlated(rng, 30, C) ** 2
    obs = null.mean(0).copy()
    obs[2] = 50.0
    adj, z = max_t_adjusted(obs, null)
    assert adj[2].value == pytest.approx(1 / 31) and adj[2].value <= alpha
    assert mc_pvalue(obs[2], null[:, 2]).value > alpha / C
    assert all(adj[c].value > alpha for c in (0, 1, 3, 4)) and np.argmax(z) == 2
    with pytest.raises(SoftsbiError, match="shape"):
        max_t_adjusted(obs, null[:, :3])


def test_adaptive_resolution_extends_only_when_promising_and_keeps_the_level():
    assert resolution_needed(MCPValue(exceed=0, n=30), 0.01, 200)
    assert resolution_needed(MCPValue(exceed=1, n=30), 0.01, 200)  # 2/201 <= 0.01: the cap can still decide
    assert not resolution_needed(MCPValue(exceed=1, n=30), 0.01, 120, promising=0)  # 2/121 > 0.01 and no eager rule
    assert resolution_needed(MCPValue(exceed=2, n=30), 0.005, 200)  # 3/201 > 0.005, but the first stage's 3/31 <= 0.1
    assert not resolution_needed(MCPValue(exceed=3, n=30), 0.005, 200)  # 4/31 > 0.1 and 4/201 > 0.005
    assert resolution_needed(MCPValue(exceed=0, n=199), 0.01, 300)  # 1/200 <= 0.01, but rejections are the cap's
    assert not resolution_needed(MCPValue(exceed=0, n=200), 0.01, 200)
    # the two-stage test under the null: reject at most alpha of the time
    rng = np.random.default_rng(2)
    alpha, n1, cap, reps = 0.02, 30, 99, 4000
    rej = 0
    for _ in range(reps):
        x = rng.normal(size=cap + 1)
        p = mc_pvalue(x[0], x[1:n1 + 1])
        if resolution_needed(p, alpha, cap):
            p = mc_pvalue(x[0], x[1:])
        rej += p.value <= alpha
    assert rej / reps <= alpha + 3 * np.sqrt(alpha * (1 - alpha) / reps)


def test_a_null_cap_that_cannot_resolve_the_level_is_refused_in_one_line_naming_the_smallest_that_can():
    """The resolution guard: the joint p-value of the min-p combination is never below 1/(n + 1), so a cap of 18
    nulls can never reject at 0.05 (1/19 > 0.05); check and diagnose refuse it before any simulation, naming the
    smallest cap that can (19: 1/20 = 0.05)."""
    from softsbi.workflows.criticism.screening import check_resolution, smallest_null
    assert smallest_null(0.05) == 19 and smallest_null(0.01) == 99
    assert 1 / (smallest_null(0.05) + 1) <= 0.05 < 1 / smallest_null(0.05)
    with pytest.raises(SoftsbiError, match=r"^max_null 18 cannot resolve alpha 0.05: .* 1/19 = 0.0526; "
                                           r"use max_null >= 19$"):
        check_resolution(0.05, 18)
    check_resolution(0.05, 19)  # resolvable: nothing raised
    for bad in (0.0, 1.0, -0.1):
        with pytest.raises(SoftsbiError, match="--alpha must be > 0 and < 1"):
            check_resolution(bad, 200)


def test_the_null_grows_to_its_cap_only_when_a_first_stage_is_promising_and_decides_there(monkeypatch):
    """misspecification_verdict's adaptive resolution (the omnibus test alone, alpha 0.01, cap 200): 0 or 2 of 30
    nulls as extreme (beyond all of them, or p = 3/31 <= EXTEND_P) cannot decide at 30 (1/31 > 0.01), so the null
    grows to the cap and the decision is taken on all 200 (rejected at 1 of 200, accepted at 60 of 200); 12 of 30
    (p = 0.42) is decided at 30 without simulating more."""
    from softsbi.workflows.criticism import screening as scr

    class Pool:
        def __init__(self):
            self.rollouts, self.requested, self.first, self.run = [None] * 30, 30, 30, type("R", (), {"dense": None})()

        @property
        def features(self):
            return np.zeros((len(self.rollouts), 2))

        def ensure_successful(self, n):
            self.rollouts, self.requested = [None] * n, n
            return self

    def verdict(exceed_at):
        monkeypatch.setattr(scr, "omnibus_statistics", lambda f_obs, feats: (1.0, np.zeros(len(feats))))
        monkeypatch.setattr(scr, "mc_pvalue", lambda d, null: MCPValue(exceed=exceed_at(len(null)), n=len(null)))
        monkeypatch.setattr(scr, "run_features", lambda run, dense: np.zeros(2))
        test, screen, ranking = scr.misspecification_verdict(Pool(), [], 0.01, 200)
        assert screen is None and ranking == () and test.directional is None and test.tests == 1
        return test

    rejected = verdict(lambda n: 0 if n == 30 else 1)
    assert rejected.n_null == 200 and rejected.p_value == pytest.approx(2 / 201) and rejected.misspecified
    accepted = verdict(lambda n: 2 if n == 30 else 60)
    assert accepted.n_null == 200 and accepted.p_value == pytest.approx(61 / 201) and not accepted.misspecified
    assert accepted.omnibus == MCPValue(exceed=60, n=200) and accepted.best == accepted.omnibus
    decided_early = verdict(lambda n: 12)
    assert decided_early.n_null == 30 and not decided_early.misspecified


def _screening(r_obs, r_null, cols, generic=()):
    """A screening on synthetic residuals: effect ``name`` adds ``coef * cols[name]`` (coef >= 0)."""
    from softsbi.core.interfaces import Effect
    from softsbi.core.types import Param, ParamSpace
    from softsbi.workflows.criticism.screening import Screening

    def effect(nm):
        return type(nm, (Effect,), {"name": nm, "description": nm, "generic": nm in generic,
                                    "kind": "sensor" if nm == "B" else "physics",
                                    "param_space": lambda self: ParamSpace([Param("k", 0.0, 10.0, "")])})()
    sc = Screening.__new__(Screening)
    rng = np.random.default_rng(5)
    sc.J_theta = rng.normal(size=(len(r_obs), 2))
    sc.r_obs, sc.r_null, sc.failed = r_obs, r_null, []
    sc.design = {nm: {"effect": effect(nm), "J": c[:, None], "offset": np.zeros(len(r_obs)), "lo": np.array([0.0]),
                      "hi": np.array([10.0]), "steps": [("k", 0.0, 0.1)]} for nm, c in cols.items()}
    return sc


def test_the_screening_ranks_the_effects_present_first_by_max_t_evidence_and_marks_a_generic_term():
    """Screening.ranking: every candidate tested alone against the same null, max-T adjusted over the family. Two
    effects present rank first (the stronger first, its linearised estimate near the truth, each kind kept); only a
    generic term present: it ranks first, marked generic (the diagnosis never refits or names it); pure noise: no
    candidate reaches the level."""
    rng = np.random.default_rng(4)
    F = 60
    cols = {n: rng.normal(size=F) for n in ("A", "B", "C")}
    null = rng.normal(size=(60, F))
    sc = _screening(rng.normal(size=F) + 1.2 * cols["A"] + 0.8 * cols["B"], null, cols, generic=("C",))
    ranking = sc.ranking()
    assert [c.effect for c in ranking[:2]] == ["A", "B"] and [c.kind for c in ranking] == ["physics", "sensor",
                                                                                           "physics"]
    assert ranking[0].adjusted.value <= 0.05 and ranking[1].adjusted.value <= 0.05
    assert ranking[0].explained > ranking[1].explained > ranking[2].explained
    assert ranking[0].estimate["k"] == pytest.approx(1.2, abs=0.3)
    assert all(c.screened and c.adjusted.n == 60 and c.adjusted.value >= 1 / 61 for c in ranking)
    assert [c.generic for c in ranking] == [False, False, True]
    # only the generic term explains it: it ranks first, marked generic
    sc = _screening(rng.normal(size=F) + 1.5 * cols["C"], null, cols, generic=("C",))
    ranking = sc.ranking()
    assert ranking[0].effect == "C" and ranking[0].generic and ranking[0].adjusted.value <= 0.05
    # pure noise: nothing is significant
    sc = _screening(rng.normal(size=F), null, cols)
    assert all(c.adjusted.value > 0.05 for c in sc.ranking())


def test_the_joint_test_is_bonferroni_over_two_monte_carlo_p_values_and_keeps_its_level():
    """check's test (JointTest): the omnibus and the directional test on one null, joint p = 2 x the smaller one,
    never below its resolution 2/(n + 1); under the null it rejects at most at its level, whatever the
    dependence of the two statistics."""
    def joint(omnibus, directional, alpha=0.01):
        return JointTest(omnibus=omnibus, directional=directional, directional_effect="x" if directional else None,
                         family=("x",), alpha=alpha, max_null=200)

    j = joint(MCPValue(exceed=0, n=200), MCPValue(exceed=30, n=200))
    assert j.p_value == pytest.approx(2 / 201) == j.resolution and j.tests == 2 and j.misspecified
    assert j.deciding == "omnibus" and j.best == MCPValue(exceed=0, n=200) and j.best.at_floor
    j = joint(MCPValue(exceed=12, n=200), MCPValue(exceed=3, n=200))
    assert j.p_value == pytest.approx(8 / 201) and j.deciding == "directional" and j.p_value > j.resolution
    assert j.best == MCPValue(exceed=3, n=200) and j.p_value == pytest.approx(2 * j.best.value) and j.n_null == 200
    assert joint(MCPValue(exceed=20, n=30), MCPValue(exceed=25, n=30)).p_value == 1.0  # capped at 1
    one = joint(MCPValue(exceed=5, n=30), None)  # no candidate screened: the omnibus test alone
    assert one.tests == 1 and one.p_value == pytest.approx(6 / 31) and one.resolution == pytest.approx(1 / 31)
    # level under the null: observation and 40 nulls exchangeable, two strongly dependent statistics
    rng = np.random.default_rng(11)
    rej = 0
    reps = 3000
    for _ in range(reps):
        x = rng.normal(size=41)
        s1, s2 = x, 0.8 * x + 0.6 * rng.normal(size=41)
        rej += joint(mc_pvalue(s1[0], s1[1:]), mc_pvalue(s2[0], s2[1:]), 0.1).misspecified
    rate = rej / reps
    assert rate <= 0.1 + 2 * np.sqrt(0.1 * 0.9 / reps)
    assert rate >= 0.05  # not vacuous: dependent tests lose little to Bonferroni here


def test_a_null_grown_to_its_cap_counts_successful_rollouts():
    """Failed posterior-predictive rollouts do not cost resolution: the cap is reached in successes (an
    other-engine fling with 193 successes of 200 could not resolve the joint test's 2/201 <= 0.01), within a
    bound on requests when most fail."""
    from softsbi.workflows.criticism.stats import PosteriorPredictive

    class Flaky(PosteriorPredictive):
        def __init__(self, fail_every):
            self.rollouts, self.requested, self.first, self.fail_every = [], 0, 0, fail_every

        def ensure(self, n):
            for i in range(self.requested, n):
                if i % self.fail_every:
                    self.rollouts.append({"sample": i})
            self.first = self.first or n
            self.requested = max(n, self.requested)
            return self

    pool = Flaky(10).ensure(30)
    assert len(pool.rollouts) == 27
    pool.ensure_successful(200)
    assert len(pool.rollouts) == 200 and pool.requested == 223
    always = Flaky(1).ensure(30)  # every rollout fails: stops at twice the cap
    always.ensure_successful(200)
    assert always.requested == 400 and always.rollouts == []


def _sheet(n: int = 12, size: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """A flat square sheet ``(n * n, 3)`` m at height 0.2 m and its triangles."""
    u = np.linspace(0, size, n)
    xx, yy = np.meshgrid(u, u)
    v = np.stack([xx.ravel(), yy.ravel(), np.full(n * n, 0.2)], 1)
    f = [(i * n + j, i * n + j + 1, (i + 1) * n + j) for i in range(n - 1) for j in range(n - 1)]
    f += [(i * n + j + 1, (i + 1) * n + j + 1, (i + 1) * n + j) for i in range(n - 1) for j in range(n - 1)]
    return v, np.array(f)


def test_the_energy_score_is_smallest_at_the_measurements_own_noise_where_the_chamfer_is_not():
    """A measurement with 1 cm point noise on the observed surface; models that predict noise of 0, 1 and 2 cm.
    The posterior-predictive Chamfer is smallest for the noise-free model (it rewards predicting no spread), so
    the right sensor model raises it; the energy score (proper) is smallest at the measurement's own noise."""
    from types import SimpleNamespace

    from softsbi.perception.pointcloud import sensor_chamfer_per_frame
    from softsbi.workflows.criticism.stats import energy_score, sampled_points

    v, f = _sheet()
    T, P, S, sigma = 3, 300, 30, 0.01
    rng = np.random.default_rng(0)
    verts = np.repeat(v[None], T, 0)
    y = sampled_points(verts + rng.normal(0, sigma, verts.shape), f, P, 999)
    run = SimpleNamespace(post_theta=np.zeros(S), dense=y, metric_frames=None, metric_min_z=None,
                          record=SimpleNamespace(metric_camera=None))

    def pool(noise: float, n: int = S) -> SimpleNamespace:
        ro = []
        for i in range(n):
            vv = verts + rng.normal(0, noise, verts.shape)
            ch = sensor_chamfer_per_frame(sampled_points(vv, f, P, 5000 + i), y)[0]
            ro.append(JobResult(status=0, vertices=vv, faces=f, chamfer=ch, sample=i))
        return SimpleNamespace(run=run, rollouts=ro, energy_scores={})

    none, right, double = (energy_score(pool(s)) for s in (0.0, sigma, 2 * sigma))
    assert none.chamfer_m < right.chamfer_m < double.chamfer_m
    assert right.energy_m < none.energy_m - 5 * np.hypot(right.se_m, none.se_m)
    assert right.energy_m < double.energy_m - 5 * np.hypot(right.se_m, double.se_m)
    for e in (none, right, double):
        assert e.energy_m == pytest.approx(e.chamfer_m - e.spread_m / 2)
        assert e.n == S and 0 < e.se_m < 0.1 * e.energy_m
    assert energy_score(pool(sigma, 2)) is None  # no spread from fewer than 3 rollouts
    # a pool shared by check and diagnose is scored once: the second call reads what the first stored
    p = pool(sigma)
    first = energy_score(p)
    # a recomputation would now give another Chamfer term
    p.rollouts[:] = [replace(r, chamfer=np.zeros_like(r.chamfer)) for r in p.rollouts]
    assert energy_score(p) == first


def test_the_null_accepts_as_few_rollouts_as_check_simulates_and_no_fewer():
    """The misspecification test's minimum is the named MIN_NULL, the smallest `--n-eval` check accepts: a check at
    that setting whose rollouts all succeed is tested, one failed rollout is refused in one line."""
    from softsbi.core.defaults import MIN_ROLLOUTS
    from softsbi.workflows.criticism.statistics import MIN_NULL
    assert MIN_NULL == MIN_ROLLOUTS
    rng = np.random.default_rng(1)
    _, p = misspecification_test(rng.normal(size=6), rng.normal(size=(MIN_NULL, 6)))
    assert p.n == MIN_NULL
    with pytest.raises(SoftsbiError, match=f"at least {MIN_NULL} successful posterior rollouts \\(got {MIN_NULL - 1}\\)"):
        misspecification_test(rng.normal(size=6), rng.normal(size=(MIN_NULL - 1, 6)))


def test_the_min_p_combination_is_uniform_on_exchangeable_nulls_where_bonferroni_piles_up_at_one():
    """Two correlated tests on one null: Bonferroni (2 x the smaller p) is valid but puts about 40% of the null's
    p-values at exactly 1 (the controls of the lift's diagnosis split: 8 of 40 at 1, KS p 0.016); the min-p
    combination against the null's own minima is uniform, keeps the level, and is never below 1/(n + 1)."""
    from scipy.stats import kstest
    from softsbi.workflows.criticism.statistics import min_p_combined
    rng = np.random.default_rng(0)
    minp, bonf = [], []
    for _ in range(1500):
        x = rng.normal(size=(40, 2))
        x[:, 1] = 0.7 * x[:, 0] + 0.7 * x[:, 1]
        p = min_p_combined(x[0], x[1:])
        assert p.n == 39 and p.value >= 1 / 40
        minp.append(p.value)
        bonf.append(min(1.0, 2 * min(mc_pvalue(x[0, j], x[1:, j]).value for j in range(2))))
    minp, bonf = np.array(minp), np.array(bonf)
    assert abs((minp <= 0.05).mean() - 0.05) < 0.02 and (minp == 1).mean() < 0.05
    assert (bonf == 1).mean() > 0.3 and (bonf <= 0.05).mean() <= 0.07
    # uniform up to the rank resolution: the smoothed p-values pass a KS test
    assert kstest(minp - rng.random(len(minp)) / 40, "uniform").pvalue > 0.01
    # one test: the combination is that test's Monte-Carlo p-value
    x = rng.normal(size=(31, 1))
    assert min_p_combined(x[0], x[1:]) == mc_pvalue(x[0, 0], x[1:, 0])


def test_the_min_p_combination_gains_power_over_bonferroni_when_the_tests_agree_and_loses_none_otherwise():
    from softsbi.workflows.criticism.statistics import min_p_combined
    rng = np.random.default_rng(1)
    for rho, better in ((0.0, False), (0.8, True)):
        gained = lost = 0
        for _ in range(400):
            x = rng.normal(size=(201, 2))
            x[:, 1] = rho * x[:, 0] + np.sqrt(1 - rho ** 2) * x[:, 1]
            x[0] += (2.0, 2.0 * rho)
            mp = min_p_combined(x[0], x[1:]).value <= 0.05
            bf = min(1.0, 2 * min(mc_pvalue(x[0, j], x[1:, j]).value for j in range(2))) <= 0.05
            gained += mp and not bf
            lost += bf and not mp
        assert lost <= 2 and (gained >= 3) == better, (rho, gained, lost)
