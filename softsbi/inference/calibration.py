"""Simulation-based calibration statistics of a posterior estimator, in unit-cube coordinates.

Given test pairs ``(u_i, x_i)`` drawn from the joint the estimator was trained on (``u_i`` from
the training proposal, ``x_i`` simulated at ``u_i``, never used in training) and ``L`` draws of
``q(u | x_i)`` per pair:

* **Expected coverage** (highest-density regions; Hermans et al. 2022, "A trust crisis in
  simulation-based inference?", Sec. 3): ``u_i`` lies in the level-``gamma`` HPD region of
  ``q(. | x_i)`` iff the fraction of draws with a higher density than ``u_i`` is below ``gamma``.
  A calibrated ``q`` gives coverage ``gamma`` at every level; below it: over-confident, above:
  under-confident (conservative).
* **SBC rank statistics** per parameter (Talts et al. 2018, "Validating Bayesian inference
  algorithms with simulation-based calibration"): the number of draws below ``u_i``; uniform on
  ``0..L`` when ``q`` is calibrated. Tested with the Kolmogorov-Smirnov test (as sbi's
  ``check_sbc``) and shown as histograms with the binomial band of a uniform histogram.
* **TARP** (Lemos et al. 2023, "Sampling-based accuracy testing of posterior estimators"):
  coverage of balls around random reference points; reference points uniform in the bounding
  box of the test parameters (sbi's default ``get_tarp_references``).

These are the few lines of sbi's ``run_sbc`` / ``check_sbc`` / ``run_tarp`` written against this
project's mixtures (sbi is not a dependency of the core package); the statistics are scipy's.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from scipy import stats

from softsbi.core.errors import PosteriorError, ShapeError

__all__ = ["draws_in_box", "hpd_levels", "expected_coverage", "coverage_band", "coverage_band_simultaneous",
           "curve_outside", "sbc_ranks", "rank_tests",
           "rank_band", "tarp_coverage", "coverage_verdict", "LEVELS"]

#: credibility levels of the coverage curve
LEVELS = np.round(np.linspace(0.0, 1.0, 21), 3)


def draws_in_box(q: Any, n: int, rng: np.random.Generator, max_tries: int = 20) -> np.ndarray:
    """``(n, D)`` draws of the mixture ``q`` restricted to the unit box (rejection sampling), as the
    fit's posterior is restricted to the prior box.

    Raises:
        PosteriorError: less than ~1/(max_tries * 4) of ``q``'s mass lies in the box.
    """
    out: list[np.ndarray] = []
    have = 0
    for _ in range(max_tries):
        s = q.sample(4 * n, rng)
        s = s[np.all((s >= 0.0) & (s <= 1.0), axis=1)]
        out.append(s)
        have += len(s)
        if have >= n:
            return np.concatenate(out)[:n]
    raise PosteriorError(f"the estimator's posterior has almost no mass in the prior box ({have} of "
                         f"{4 * n * max_tries} draws inside); it cannot be calibrated at this observation")


def hpd_levels(log_q_true: np.ndarray, log_q_draws: np.ndarray) -> np.ndarray:
    """Smallest HPD credibility level containing the truth, per test case.

    Args:
        log_q_true: ``(N,)`` log density of ``q(. | x_i)`` at the true ``u_i``.
        log_q_draws: ``(N, L)`` log density at ``L`` draws of ``q(. | x_i)``.

    Returns:
        ``(N,)`` in ``[0, 1]``: the fraction of draws with a higher density than the truth.
    """
    log_q_true = np.asarray(log_q_true, float)
    log_q_draws = np.asarray(log_q_draws, float)
    if log_q_draws.ndim != 2 or log_q_true.shape != (len(log_q_draws),):
        raise ShapeError(f"hpd_levels needs log_q_true (N,) and log_q_draws (N, L); got {log_q_true.shape}, "
                         f"{log_q_draws.shape}")
    return (log_q_draws > log_q_true[:, None]).mean(1)


def expected_coverage(levels_hpd: np.ndarray, levels: Sequence[float] = LEVELS) -> np.ndarray:
    """Expected coverage ``(len(levels),)``: the fraction of test cases whose truth lies in the
    level-``gamma`` HPD region, for each ``gamma`` in ``levels``."""
    h = np.asarray(levels_hpd, float)
    return np.array([float((h < g).mean()) if g < 1 else 1.0 for g in levels])


def coverage_band(n: int, levels: Sequence[float] = LEVELS, confidence: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """Pointwise ``confidence`` band of the expected coverage of a calibrated estimator with ``n``
    test cases: the binomial ``(n, gamma)`` quantiles divided by ``n`` (``(lo, hi)``, each ``(len(levels),)``)."""
    g = np.asarray(levels, float)
    a = (1 - confidence) / 2
    return stats.binom.ppf(a, n, g) / n, stats.binom.ppf(1 - a, n, g) / n


def coverage_band_simultaneous(n: int, levels: Sequence[float] = LEVELS,
                               confidence: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """Simultaneous ``confidence`` band of a calibrated estimator's whole coverage curve over ``levels``
    (``n`` test cases): the pointwise binomial band at ``1 - (1 - confidence) / L`` per level, ``L`` the
    levels strictly inside (0, 1) (Bonferroni: a calibrated estimator's curve leaves it anywhere with
    probability at most ``1 - confidence``). The pointwise band (:func:`coverage_band`) judges one level;
    a curve of 21 levels leaves a 95 % pointwise band somewhere far more often than 5 % of the time even
    when calibrated, so "the curve is inside the band" is judged with this one. Returns ``(lo, hi)``."""
    g = np.asarray(levels, float)
    L = max(int(((g > 0) & (g < 1)).sum()), 1)
    return coverage_band(n, g, 1 - (1 - confidence) / L)


def curve_outside(coverage: Sequence[float], lo: Sequence[float], hi: Sequence[float]) -> list[int]:
    """Indices of the levels where a coverage curve lies outside a band ``(lo, hi)``."""
    c, lo, hi = (np.asarray(a, float) for a in (coverage, lo, hi))
    return [int(i) for i in np.flatnonzero((c < lo - 1e-12) | (c > hi + 1e-12))]


def coverage_verdict(coverage: float, n: int, level: float, confidence: float = 0.95) -> str:
    """``"calibrated"``, ``"over-confident"`` (coverage below the binomial band of a calibrated
    estimator with ``n`` cases) or ``"under-confident"`` (above it) at credibility ``level``."""
    lo, hi = coverage_band(n, [level], confidence)
    if coverage < lo[0]:
        return "over-confident"
    if coverage > hi[0]:
        return "under-confident"
    return "calibrated"


def sbc_ranks(u_true: np.ndarray, draws: np.ndarray) -> np.ndarray:
    """SBC ranks ``(N, D)``: per test case and parameter, the number of the ``L`` draws below the
    truth (Talts et al. 2018, Alg. 1); uniform on ``0..L`` for a calibrated posterior.

    Args:
        u_true: ``(N, D)``. draws: ``(N, L, D)``.
    """
    u_true = np.asarray(u_true, float)
    draws = np.asarray(draws, float)
    if draws.ndim != 3 or u_true.shape != (draws.shape[0], draws.shape[2]):
        raise ShapeError(f"sbc_ranks needs u_true (N, D) and draws (N, L, D); got {u_true.shape}, {draws.shape}")
    return (draws < u_true[:, None, :]).sum(1)


def rank_tests(ranks: np.ndarray, n_draws: int, n_bins: int) -> dict[str, list[float]]:
    """Uniformity tests of SBC ranks ``(N, D)`` per parameter: the Kolmogorov-Smirnov p-value of the
    normalised ranks ``(rank + 0.5) / (L + 1)`` against U(0, 1) (sbi's ``check_sbc``) and the
    chi-square p-value of the ``n_bins`` histogram."""
    ranks = np.asarray(ranks)
    N, D = ranks.shape
    ks, chi = [], []
    for d in range(D):
        r = (ranks[:, d] + 0.5) / (n_draws + 1)
        ks.append(float(stats.kstest(r, "uniform").pvalue))
        h = np.histogram(ranks[:, d], bins=n_bins, range=(0, n_draws + 1))[0]
        chi.append(float(stats.chisquare(h).pvalue))
    return {"ks_pvalue": ks, "chi2_pvalue": chi}


def rank_band(n: int, n_bins: int, confidence: float = 0.99) -> tuple[float, float]:
    """Pointwise ``confidence`` band (counts) of one bin of a uniform rank histogram with ``n`` cases
    and ``n_bins`` bins (Talts et al. 2018, Fig. 1: binomial ``(n, 1/n_bins)``, 99 %)."""
    a = (1 - confidence) / 2
    return float(stats.binom.ppf(a, n, 1 / n_bins)), float(stats.binom.ppf(1 - a, n, 1 / n_bins))


def tarp_coverage(u_true: np.ndarray, draws: np.ndarray, rng: np.random.Generator,
                  levels: Sequence[float] = LEVELS) -> dict[str, Any]:
    """TARP expected coverage (Lemos et al. 2023, Alg. 2) of draws ``(N, L, D)`` for truths ``(N, D)``.

    One reference point per test case, uniform in the bounding box of the test parameters; for
    each case ``f_i`` = fraction of draws closer to the reference than the truth. Coverage at
    ``alpha`` = fraction of cases with ``f_i < alpha``; a calibrated posterior gives the diagonal.

    Returns:
        ``{"levels", "coverage", "atc", "ks_pvalue"}``: ``atc`` = mean of (coverage - level) over the
        levels (0: calibrated; < 0: over-confident, > 0: under-confident, as sbi's ``check_tarp``
        sign convention), ``ks_pvalue`` of ``f`` against U(0, 1).
    """
    u_true = np.asarray(u_true, float)
    draws = np.asarray(draws, float)
    lo, hi = u_true.min(0), u_true.max(0)
    ref = lo + (hi - lo) * rng.random(u_true.shape)
    d_true = np.linalg.norm(u_true - ref, axis=-1)  # (N,)
    d_draw = np.linalg.norm(draws - ref[:, None, :], axis=-1)  # (N, L)
    f = (d_draw < d_true[:, None]).mean(1)
    g = np.asarray(levels, float)
    cov = np.array([float((f < a).mean()) if a < 1 else 1.0 for a in g])
    return {"levels": g.tolist(), "coverage": cov.tolist(), "atc": float((cov - g).mean()),
            "ks_pvalue": float(stats.kstest(f, "uniform").pvalue)}
