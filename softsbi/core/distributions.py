"""Gaussian mixtures and the sequential (BayesSim) proposal correction, in NumPy.

All densities here live on the unit-cube coordinates ``u`` of a :class:`ParamSpace`
(prior = uniform on ``[0, 1]^D``, density 1).

Proposal correction (BayesSim, Ramos et al. 2019, eq. 4; Papamakarios & Murray 2016):
an estimator trained on pairs ``(u, x)`` with ``u ~ p~(u)`` learns
``q(u | x) ∝ p~(u) p(x | u)``, so the posterior under the prior ``p`` is

    p(u | x_obs) ∝ p(u) / p~(u) * q(u | x_obs),  restricted to the prior's support.

With all rounds' data pooled, ``p~`` is the *mixture* of the proposals of all rounds,
weighted by the number of simulations each round contributed (round 1 = the prior), which
keeps the importance ratio bounded by ``N_total / N_round1``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy.special import logsumexp

from .errors import ShapeError


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
        return self.means.shape[1]

    @property
    def covariances(self) -> np.ndarray:
        return self.scale_tril @ np.swapaxes(self.scale_tril, -1, -2)

    def mean(self) -> np.ndarray:
        return self.weights @ self.means

    def cov(self) -> np.ndarray:
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
        return {"weights": self.weights, "means": self.means, "scale_tril": self.scale_tril}


class Distribution:
    """Interface of a proposal / posterior over the unit cube."""

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


class ProposalMixture(Distribution):
    """Mixture of the proposals of all rounds so far, weighted by simulations per round.

    Args:
        components: the per-round proposals (round 1 is normally :class:`UnitBoxPrior`).
        counts: simulations drawn from each (only successful ones should count).
    """

    def __init__(self, components: Sequence[Distribution], counts: Sequence[float]):
        if len(components) != len(counts) or not components:
            raise ShapeError("ProposalMixture needs one count per component")
        c = np.asarray(counts, float)
        self.components = list(components)
        self.logw = np.log(np.maximum(c, 1e-300) / c.sum())

    def log_prob(self, u: np.ndarray) -> np.ndarray:
        u = np.atleast_2d(u)
        return logsumexp(np.stack([lw + comp.log_prob(u) for lw, comp in zip(self.logw, self.components)]), axis=0)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        k = rng.choice(len(self.components), size=n, p=np.exp(self.logw))
        out = np.empty((n, self.components[0].sample(1, rng).shape[1]))
        for j, comp in enumerate(self.components):
            idx = np.nonzero(k == j)[0]
            if len(idx):
                out[idx] = comp.sample(len(idx), rng)
        return out


@dataclass
class CorrectedPosterior(Distribution):
    """``p(u | x_obs) ∝ 1[u in box] / p~(u) * q(u | x_obs)`` (uniform prior on the unit cube).

    Sampling is by sampling-importance-resampling from ``q`` restricted to the box: draws
    from ``q`` inside the box weighted by ``1 / p~``. With ``proposal=None`` (all data
    from the prior) this is just ``q`` truncated to the box.

    ``log_prob`` is normalised by a Monte Carlo estimate of the constant (``n_norm`` draws),
    which is all the next round needs (it enters the proposal mixture as a density).

    Attributes:
        q: the estimator's conditional at ``x_obs``.
        proposal: the pooled proposal ``p~`` of the training data, or None for the prior.
    """

    q: MixtureOfGaussians
    proposal: Distribution | None = None
    n_norm: int = 20000
    seed: int = 0
    _log_z: float | None = field(default=None, repr=False)

    def _log_ratio(self, u: np.ndarray) -> np.ndarray:
        lr = np.where(_inside(u), 0.0, -np.inf)
        if self.proposal is not None:
            with np.errstate(invalid="ignore"):
                lr = lr - self.proposal.log_prob(u)
        return lr

    @property
    def log_z(self) -> float:
        """``log ∫_box q(u) / p~(u) du`` estimated by Monte Carlo with draws from ``q``."""
        if self._log_z is None:
            rng = np.random.default_rng(self.seed + 7919)
            u = self.q.sample(self.n_norm, rng)
            lr = self._log_ratio(u)
            finite = np.isfinite(lr)
            if not finite.any():
                self._log_z = -np.inf
            else:
                self._log_z = float(logsumexp(lr[finite]) - np.log(len(u)))
        return self._log_z

    @property
    def mass_in_box(self) -> float:
        """Fraction of ``q``'s mass inside the prior box (diagnoses a posterior pushed
        against the prior's bounds)."""
        rng = np.random.default_rng(self.seed + 104729)
        return float(_inside(self.q.sample(self.n_norm, rng)).mean())

    def log_prob(self, u: np.ndarray) -> np.ndarray:
        u = np.atleast_2d(u)
        return self.q.log_prob(u) + self._log_ratio(u) - self.log_z

    def sample(self, n: int, rng: np.random.Generator, oversample: int = 20) -> np.ndarray:
        """``n`` draws ``(n, D)`` inside the unit box.

        Raises:
            RuntimeError: ``q`` has (numerically) no mass inside the prior box.
        """
        out: list[np.ndarray] = []
        tries = 0
        while sum(len(o) for o in out) < n:
            m = max(oversample * n, 1000)
            u = self.q.sample(m, rng)
            lr = self._log_ratio(u)
            ok = np.isfinite(lr)
            tries += 1
            if not ok.any():
                if tries > 20:
                    raise RuntimeError("the posterior has no mass inside the prior box; widen the prior "
                                       "bounds or check that the observation is reachable by the simulator")
                continue
            u, lr = u[ok], lr[ok]
            w = np.exp(lr - lr.max())
            w /= w.sum()
            k = min(n, max(1, int(len(u) / oversample)))
            # systematic resampling keeps the draw close to the weights with few samples
            pos = (rng.random() + np.arange(k)) / k
            idx = np.searchsorted(np.cumsum(w), pos)
            out.append(u[np.minimum(idx, len(u) - 1)])
        res = np.concatenate(out)[:n]
        return res[rng.permutation(len(res))]

    def moments(self, n: int = 20000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Monte Carlo mean ``(D,)`` and covariance ``(D, D)`` in the unit cube."""
        u = self.sample(n, np.random.default_rng(seed))
        return u.mean(0), np.cov(u.T).reshape(u.shape[1], u.shape[1])


def gaussian(mean: np.ndarray, cov: np.ndarray) -> MixtureOfGaussians:
    """Single Gaussian as a one-component mixture."""
    mean = np.asarray(mean, float)
    return MixtureOfGaussians(np.ones(1), mean[None], np.linalg.cholesky(np.asarray(cov, float))[None])
