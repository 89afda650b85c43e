"""Gaussian mixtures and the sequential (BayesSim) proposal correction, in NumPy.

All densities here live on the unit-cube coordinates ``u`` of a :class:`ParamSpace`
(prior = uniform on ``[0, 1]^D``, density 1).

Proposal correction (BayesSim, Ramos et al. 2019, eq. 4; Papamakarios & Murray 2016):
an estimator trained on pairs ``(u, x)`` with ``u ~ p~(u)`` learns
``q(u | x) ∝ p~(u) p(x | u)``, so the posterior under the prior ``p`` is

    p(u | x_obs) ∝ p(u) / p~(u) * q(u | x_obs),  restricted to the prior's support.

With all rounds' data pooled, ``p~`` is the *mixture* of the proposals of all rounds,
weighted by the number of simulations each round contributed (round 1 = the prior), which
keeps the importance ratio bounded by ``N_total / N_round1`` (see :class:`PosteriorChain`).

Truncated proposals (TSNPE; Deistler, Goncalves & Macke 2022, "Truncated proposals for
scalable and hassle-free simulation-based inference", Alg. 1): round r+1 draws from the
prior restricted to the highest-density region of round r's posterior
(:class:`TruncatedPrior`). Inside that region every round's proposal is proportional to the
prior, so ``q(u | x_obs)`` trained on the pooled data *is* the posterior there and needs no
importance correction (whose weights, ``1 / p~``, amplify the estimator's errors in the tails
of ``q`` when the proposals are narrow).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from softsbi.core.errors import PosteriorError, ShapeError


@dataclass
class MixtureOfGaussians:
    """Full-covariance Gaussian mixture.

    Attributes:
        weights: ``(C,)`` non-negative, summing to 1.
        means: ``(C, D)``.
        scale_tril: ``(C, D, D)`` lower-triangular Cholesky factors of the covariances.
    """

    weights: np.ndarray
    means: np.ndarray
    scale_tril: np.ndarray

    def __post_init__(self) -> None:
        self.weights = np.asarray(self.weights, float)
        self.means = np.asarray(self.means, float)
        self.scale_tril = np.asarray(self.scale_tril, float)
        C, D = self.means.shape
        if self.weights.shape != (C,) or self.scale_tril.shape != (C, D, D):
            raise ShapeError(f"mixture shapes inconsistent: weights {self.weights.shape}, means "
                             f"{self.means.shape}, scale_tril {self.scale_tril.shape}")
        self.weights = self.weights / self.weights.sum()

    @property
    def dim(self) -> int:
        """Number of dimensions D."""
        return self.means.shape[1]

    @property
    def covariances(self) -> np.ndarray:
        """Component covariances ``(C, D, D)``."""
        return self.scale_tril @ np.swapaxes(self.scale_tril, -1, -2)

    def mean(self) -> np.ndarray:
        """Mixture mean ``(D,)``."""
        return self.weights @ self.means

    def cov(self) -> np.ndarray:
        """Mixture covariance ``(D, D)`` (within- plus between-component)."""
        m = self.mean()
        d = self.means - m
        return np.einsum("c,cij->ij", self.weights, self.covariances) + np.einsum("c,ci,cj->ij", self.weights, d, d)

    def log_prob(self, u: np.ndarray) -> np.ndarray:
        """Log density ``(n,)`` at ``u (n, D)``."""
        u = np.atleast_2d(np.asarray(u, float))
        D = self.dim
        out = []
        for w, m, L in zip(self.weights, self.means, self.scale_tril):
            z = np.linalg.solve(L, (u - m).T).T  # (n, D)
            logdet = np.log(np.abs(np.diag(L))).sum()
            out.append(np.log(max(w, 1e-300)) - 0.5 * (z * z).sum(1) - logdet - 0.5 * D * np.log(2 * np.pi))
        return logsumexp(np.stack(out, 0), axis=0)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` draws ``(n, D)``."""
        comp = rng.choice(len(self.weights), size=n, p=self.weights)
        eps = rng.standard_normal((n, self.dim))
        return self.means[comp] + np.einsum("nij,nj->ni", self.scale_tril[comp], eps)

    def to_dict(self) -> dict:
        """``{"weights", "means", "scale_tril"}`` arrays (as stored in a run)."""
        return {"weights": self.weights, "means": self.means, "scale_tril": self.scale_tril}


class Distribution:
    """Interface of a proposal / posterior over the unit cube: ``dim``, ``sample(n, rng)`` ``(n, D)`` and
    ``log_prob(u (n, D))`` ``(n,)``. Everything in this module (the proposal correction, truncated
    proposals) uses a round's posterior through these alone."""

    def log_prob(self, u: np.ndarray) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError


class UnitBoxPrior(Distribution):
    """Uniform prior on ``[0, 1]^D`` (log density 0 inside, -inf outside)."""

    def __init__(self, dim: int):
        self.dim = dim

    def log_prob(self, u: np.ndarray) -> np.ndarray:
        u = np.atleast_2d(u)
        inside = np.all((u >= 0) & (u <= 1), axis=1)
        return np.where(inside, 0.0, -np.inf)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        return rng.random((n, self.dim))


def _inside(u: np.ndarray) -> np.ndarray:
    return np.all((u >= 0) & (u <= 1), axis=1)


def _sir(u: np.ndarray, logw: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """Systematic resampling of ``k`` rows of ``u`` with log weights ``logw`` (finite)."""
    w = np.exp(logw - logw.max())
    c = np.cumsum(w / w.sum())
    pos = (rng.random() + np.arange(k)) / k
    return u[np.minimum(np.searchsorted(c, pos), len(u) - 1)]


class PosteriorChain:
    """The sequence of corrected posteriors of a sequential (BayesSim) fit.

    Round ``k`` draws its simulations from ``p~_k`` (round 0: the prior; round k > 0: the
    corrected posterior of round k-1). After round ``k`` the estimator has been trained on
    all data so far, whose parameters come from the pooled proposal

        m_k(u) = sum_{j<=k} c_j p~_j(u) / sum_{j<=k} c_j      (c_j = usable simulations of round j)

    and the corrected posterior is ``post_k(u) = 1[u in box] q_k(u | x_obs) / m_k(u) / Z_k``.
    Because ``m_k >= c_0 / sum c`` on the box, the importance weights are bounded.

    Densities of all rounds are evaluated together in one pass (``O(k)`` mixture
    evaluations), avoiding the exponential cost of evaluating the recursion naively.

    Args:
        dim: number of parameters D.
        n_norm: Monte Carlo draws for each normalising constant ``Z_k``.
        seed: seeds those draws (results are deterministic).
    """

    def __init__(self, dim: int, n_norm: int = 20000, seed: int = 0):
        self.dim = dim
        self.n_norm = n_norm
        self.seed = seed
        self.qs: list[Distribution] = []
        self.counts: list[float] = []
        self.log_z: list[float] = []

    def __len__(self) -> int:
        return len(self.qs)

    def _log_mix_and_posts(self, u: np.ndarray, upto: int) -> tuple[np.ndarray, list[np.ndarray]]:
        """``log m_upto(u)`` and ``[log post_j(u) for j < upto]``."""
        inside = _inside(u)
        log_prior = np.where(inside, 0.0, -np.inf)
        posts: list[np.ndarray] = []
        for j in range(upto + 1):
            c = np.asarray(self.counts[: j + 1], float)
            lw = np.log(np.maximum(c, 1e-300) / c.sum())
            comps = np.stack([log_prior] + posts[:j])
            with np.errstate(invalid="ignore"):
                log_mix = logsumexp(lw[:, None] + comps, axis=0)
            if j == upto:
                return log_mix, posts
            with np.errstate(invalid="ignore"):
                lp = self.qs[j].log_prob(u) - log_mix - self.log_z[j]
            posts.append(np.where(inside, lp, -np.inf))
        raise AssertionError("unreachable")

    def add_round(self, q: "Distribution", count: float) -> "RoundPosterior":
        """Append round ``k = len(self)``, whose ``q(u | x_obs)`` (a :class:`MixtureOfGaussians` or any
        :class:`Distribution` with ``dim``) was trained on data whose newest ``count`` usable simulations
        came from the current proposal; returns ``post_k``."""
        if q.dim != self.dim:
            raise ShapeError(f"q has dimension {q.dim}, chain has {self.dim}")
        k = len(self.qs)
        self.qs.append(q)
        self.counts.append(float(count))
        rng = np.random.default_rng([self.seed, k, 7919])
        u = q.sample(self.n_norm, rng)
        inside = _inside(u)
        if not inside.any():
            log_z = -np.inf
        else:
            log_mix, _ = self._log_mix_and_posts(u[inside], k)
            log_z = float(logsumexp(-log_mix) - np.log(len(u)))
        self.log_z.append(log_z)
        return RoundPosterior(self, k)

    def posterior(self, k: int = -1) -> "RoundPosterior":
        return RoundPosterior(self, k % len(self.qs))


class RoundPosterior(Distribution):
    """The corrected posterior after round ``k`` of a :class:`PosteriorChain` (unit cube)."""

    def __init__(self, chain: PosteriorChain, k: int):
        self.chain, self.k = chain, k

    @property
    def q(self) -> Distribution:
        """The estimator's ``q(u | x_obs)`` of this round."""
        return self.chain.qs[self.k]

    def _log_w(self, u: np.ndarray) -> np.ndarray:
        """Log importance weight ``-log m_k(u)`` of draws from ``q``."""
        log_mix, _ = self.chain._log_mix_and_posts(u, self.k)
        return -log_mix

    def log_prob(self, u: np.ndarray) -> np.ndarray:
        u = np.atleast_2d(np.asarray(u, float))
        with np.errstate(invalid="ignore"):
            lp = self.q.log_prob(u) + self._log_w(u) - self.chain.log_z[self.k]
        return np.where(_inside(u), lp, -np.inf)

    @property
    def mass_in_box(self) -> float:
        """Fraction of ``q``'s mass inside the prior box; a small value means the estimator
        puts the observation outside what the prior allows (widen bounds or suspect the model)."""
        rng = np.random.default_rng([self.chain.seed, self.k, 104729])
        return float(_inside(self.q.sample(self.chain.n_norm, rng)).mean())

    def sample(self, n: int, rng: np.random.Generator, oversample: int = 10,
               max_draws: int = 2_000_000) -> np.ndarray:
        """``n`` draws ``(n, D)`` inside the unit box, by sampling-importance-resampling from
        ``q`` with weights ``1 / m_k``.

        Draws from ``q`` are added until their effective sample size (Kish) is at least
        ``min(oversample * n, max(2 n, 20000))`` (or ``max_draws`` are used), so uneven
        weights do not turn into repeated draws.

        Raises:
            PosteriorError: ``q`` has (numerically) no mass inside the prior box.
        """
        us: list[np.ndarray] = []
        lws: list[np.ndarray] = []
        drawn, tries = 0, 0
        batch = max(oversample * n, 2000)
        while True:
            tries += 1
            u = self.q.sample(batch, rng)
            drawn += batch
            u = u[_inside(u)]
            if len(u):
                us.append(u)
                lws.append(self._log_w(u))
            elif tries > 20 and not us:
                raise PosteriorError("the posterior has no mass inside the prior box; widen the prior bounds "
                                   "or check that the observation is reachable by the simulator")
            if us:
                lw = np.concatenate(lws)
                w = np.exp(lw - lw.max())
                ess = w.sum() ** 2 / (w * w).sum()
                if ess >= min(oversample * n, max(2 * n, 20000)) or drawn >= max_draws:
                    break
            batch = min(2 * batch, 200_000)
        res = _sir(np.concatenate(us), np.concatenate(lws), n, rng)
        return res[rng.permutation(len(res))]

    def moments(self, n: int = 20000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Monte Carlo mean ``(D,)`` and covariance ``(D, D)`` in the unit cube."""
        u = self.sample(n, np.random.default_rng(seed))
        return u.mean(0), np.atleast_2d(np.cov(u.T))


class TruncatedPrior(Distribution):
    """The prior (uniform on the unit box) restricted to a posterior's highest-density region.

    The TSNPE proposal (Deistler, Goncalves & Macke 2022, Alg. 1): the region is
    ``{u in [0,1]^D : log post(u) >= tau}`` with ``tau`` the ``eps``-quantile of
    ``log post`` at draws from ``post`` (so it holds ``1 - eps`` of the posterior mass).
    Draws are made by rejection from the prior restricted to the region's bounding box
    (the extent of ``n_ref`` posterior draws, widened by ``pad`` of its width per side).

    Args:
        posterior: the previous round's posterior (unit cube), e.g. a :class:`RoundPosterior`.
        eps: posterior mass left outside the region (sbi's default is 1e-4).
        n_ref: posterior draws that set ``tau`` and the bounding box.
        seed: seeds those draws (results are deterministic).

    Raises:
        PosteriorError: ``posterior`` has no finite log-density at any of its draws (no region); from ``sample``:
            the region is too small to hit by rejection.
    """

    def __init__(self, posterior: Distribution, eps: float = 1e-3, n_ref: int = 20000, seed: int = 0,
                 pad: float = 0.1):
        if not 0 < eps < 1:
            raise ValueError(f"eps must lie in (0, 1), got {eps}")
        self.posterior = posterior
        ref = posterior.sample(n_ref, np.random.default_rng([seed, 31337]))
        self.dim = ref.shape[1]
        lp = posterior.log_prob(ref)
        lp = lp[np.isfinite(lp)]
        if not lp.size:
            raise PosteriorError(f"the previous round's posterior has no finite density at any of its {n_ref} draws, "
                                 f"so it defines no truncation region: its estimator failed on this observation "
                                 f"(more simulations per round, --sims-per-round, give it more to learn from)")
        self.tau = float(np.quantile(lp, eps))
        lo, hi = ref.min(0), ref.max(0)
        w = hi - lo
        self.low = np.clip(lo - pad * w, 0.0, 1.0)
        self.high = np.clip(hi + pad * w, 0.0, 1.0)
        rng = np.random.default_rng([seed, 27644437])
        u = self._box(20000, rng)
        #: fraction of the prior box inside the region (its prior probability)
        self.prior_mass = float(self.in_region(u).mean() * np.prod(self.high - self.low))

    def _box(self, n: int, rng: np.random.Generator) -> np.ndarray:
        return self.low + rng.random((n, self.dim)) * (self.high - self.low)

    def in_region(self, u: np.ndarray) -> np.ndarray:
        """Whether each row of ``u (n, D)`` lies in the truncation region."""
        u = np.atleast_2d(np.asarray(u, float))
        box = np.all((u >= self.low) & (u <= self.high), axis=1)
        with np.errstate(invalid="ignore"):
            return box & (self.posterior.log_prob(u) >= self.tau)

    def log_prob(self, u: np.ndarray) -> np.ndarray:
        return np.where(self.in_region(u), -np.log(max(self.prior_mass, 1e-300)), -np.inf)

    def sample(self, n: int, rng: np.random.Generator, max_draws: int = 5_000_000) -> np.ndarray:
        out: list[np.ndarray] = []
        got, drawn = 0, 0
        while got < n:
            u = self._box(max(4 * (n - got), 2000), rng)
            drawn += len(u)
            u = u[self.in_region(u)]
            out.append(u[: n - got])
            got += len(out[-1])
            if got < n and drawn >= max_draws:
                raise PosteriorError(f"the truncated prior's region is too small to sample by rejection "
                                   f"({got} of {n} draws after {drawn} tries); use --proposal corrected")
        return np.concatenate(out)[:n]


def gaussian(mean: np.ndarray, cov: np.ndarray) -> MixtureOfGaussians:
    """Single Gaussian as a one-component mixture."""
    mean = np.asarray(mean, float)
    return MixtureOfGaussians(np.ones(1), mean[None], np.linalg.cholesky(np.asarray(cov, float))[None])
