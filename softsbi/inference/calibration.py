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

**The verdict** (:func:`verdict`) reads all three diagnostics as one family of tests at the family-wise
level :data:`~softsbi.core.defaults.ALPHA` (0.05), split equally over them (Bonferroni): a calibrated estimator
is called "calibrated" in at least 95 % of test sets, and the verdict is "calibrated" only when none of the
three rejects:

* joint coverage: the HPD coverage curve inside its simultaneous band (:func:`coverage_band_simultaneous`,
  Bonferroni over the levels) at confidence ``1 - ALPHA / 3``;
* TARP: the Kolmogorov-Smirnov test of its per-case fractions against U(0, 1) at ``ALPHA / 3``;
* SBC per parameter: four tests per parameter, at ``ALPHA / (3 * 4 D)`` each (Bonferroni over the ``4 D``):
  the KS test of the normalised ranks (sbi's ``check_sbc``; omnibus, but weak against a symmetric U or
  hump), the two moment tests of :func:`rank_shape` (mean: bias; spread: width), and "every bin of the rank
  histogram inside its band" (:func:`rank_band_simultaneous`, Bonferroni over the bins), so the histogram
  drawn with that band and the verdict agree. A rejected parameter is named by the shape of its ranks
  (:func:`rank_shape`): too narrow (U-shaped), too wide (hump-shaped) or biased (piled at one end).
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np
from scipy import stats

from softsbi.core.errors import PosteriorError, ShapeError
from softsbi.core.defaults import ALPHA

__all__ = ["draws_in_box", "hpd_levels", "expected_coverage", "coverage_band", "coverage_band_simultaneous",
           "curve_outside", "sbc_ranks", "rank_tests", "rank_band", "rank_band_simultaneous", "rank_shape",
           "tarp_coverage", "verdict", "LEVELS", "DIAGNOSTICS"]

#: credibility levels of the coverage curve
LEVELS = np.round(np.linspace(0.0, 1.0, 21), 3)


def posteriors_at(est: Any, x: np.ndarray) -> list[Any]:
    """``est``'s posterior at each of ``x`` (``(n, ...)``, cast to float64): its batched ``posteriors_at`` when it
    has one, else ``posterior_at`` one observation at a time."""
    x = np.asarray(x, np.float64)
    return list(est.posteriors_at(x)) if hasattr(est, "posteriors_at") else [est.posterior_at(v) for v in x]


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


def rank_band_simultaneous(n: int, n_bins: int, alpha: float) -> tuple[float, float]:
    """Band (counts) that every bin of a uniform rank histogram (``n`` cases, ``n_bins`` bins) stays inside
    with probability at least ``1 - alpha``: the binomial ``(n, 1/n_bins)`` band of one bin at ``1 - alpha /
    n_bins`` (Bonferroni over the bins). Raises ValueError for ``alpha`` outside (0, 1)."""
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must lie in (0, 1), got {alpha}")
    return rank_band(n, n_bins, 1 - alpha / n_bins)


#: the shapes :func:`rank_shape` names, with what each says of the marginal posterior
SHAPES = {"too-narrow": "too narrow (U-shaped ranks: the truth often lies in the posterior's tails)",
          "too-wide": "too wide (hump-shaped ranks: the truth lies near the posterior's centre too often)",
          "biased-high": "biased high (ranks piled at the low end: the truth lies below most posterior draws)",
          "biased-low": "biased low (ranks piled at the high end: the truth lies above most posterior draws)"}


def rank_shape(ranks: np.ndarray, n_draws: int, alpha: float) -> dict[str, Any]:
    """The shape of one parameter's SBC ranks ``(N,)`` (each in ``0..n_draws``) from the first two moments of
    the normalised ranks ``r = (rank + 0.5) / (n_draws + 1)``, uniform on (0, 1) for a calibrated marginal
    (Talts et al. 2018, Sec. 4: a U shape = over-dispersed ranks = a posterior too narrow; a hump = too wide;
    a pile at one end = biased).

    ``z_bias = (mean(r) - 1/2) / sqrt(1 / (12 N))`` and ``z_dispersion = (mean((r - 1/2)^2) - 1/12) /
    sqrt(1 / (180 N))`` are standard normal for uniform ranks (the mean and variance of ``(r - 1/2)^2`` under
    U(0, 1) are 1/12 and 1/180). ``shapes``: those whose ``|z|`` exceeds the two-sided normal quantile at
    ``alpha``, largest first (``"biased-high"``/``"biased-low"`` from ``z_bias``, ``"too-narrow"``/``"too-wide"``
    from ``z_dispersion``); when neither does, the larger one alone (a rank histogram another test rejected
    is still named by its dominant departure).

    Returns:
        ``{"z_bias", "z_dispersion", "shapes"}``.
    """
    r = (np.asarray(ranks, float) + 0.5) / (n_draws + 1)
    n = max(len(r), 1)
    z_bias = float((r.mean() - 0.5) / np.sqrt(1 / (12 * n))) if len(r) else 0.0
    z_disp = float((((r - 0.5) ** 2).mean() - 1 / 12) / np.sqrt(1 / (180 * n))) if len(r) else 0.0
    named = [("biased-high" if z_bias < 0 else "biased-low", abs(z_bias)),
             ("too-narrow" if z_disp > 0 else "too-wide", abs(z_disp))]
    crit = float(stats.norm.ppf(1 - alpha / 2))
    shapes = [k for k, z in sorted(named, key=lambda t: -t[1]) if z > crit] or [max(named, key=lambda t: t[1])[0]]
    return {"z_bias": z_bias, "z_dispersion": z_disp, "shapes": shapes}


#: the diagnostics the verdict reads (module docstring); the family-wise level is split equally over them
DIAGNOSTICS = ("joint coverage (HPD)", "TARP", "SBC per parameter")
#: the tests of each parameter's SBC ranks (module docstring), each at the diagnostic's level over ``len * D``
SBC_TESTS = ("KS", "bias (mean rank)", "width (rank spread)", "histogram band")


def _direction(below: bool, above: bool) -> str | None:
    if below and above:
        return "over- and under-confident"
    return "over-confident" if below else ("under-confident" if above else None)


def verdict(coverage: Sequence[float], n: int, tarp: Mapping[str, Any], ranks: np.ndarray, n_draws: int,
            n_bins: int, names: Sequence[str], levels: Sequence[float] = LEVELS, alpha: float = ALPHA) -> dict[str, Any]:
    """The calibration verdict of :func:`softsbi.workflows.tasks.calibrate.calibrate_run` from its three diagnostics
    (module docstring: one family of tests at family-wise level ``alpha``, Bonferroni over the diagnostics).

    Args:
        coverage: ``(L,)`` expected HPD coverage at ``levels`` (:func:`expected_coverage`) of ``n`` test cases.
        tarp: :func:`tarp_coverage`'s result (``ks_pvalue``, ``atc``).
        ranks: ``(N, D)`` SBC ranks (:func:`sbc_ranks`), each in ``0..n_draws``; histograms of ``n_bins`` bins.
        names: the ``D`` parameter names.
        alpha: family-wise level in (0, 1).

    Returns:
        ``{"verdict", "calibrated", "alpha", "coverage", "tarp", "sbc", "too_narrow", "too_wide", "biased"}``:
        ``verdict`` is ``"calibrated"`` or ``"not calibrated: "`` followed by what rejects; ``coverage``: the
        band at confidence ``1 - alpha/3`` (``band_lo``/``band_hi``, simultaneous over the levels inside (0, 1)),
        ``outside`` (levels), ``rejects``, ``direction`` and the verdicts ``at_50``/``at_90`` against that
        band; ``tarp``: ``level``, ``rejects``, ``direction`` (from the ATC's sign); ``sbc``: ``level`` (of each
        of the ``4 D`` tests, :data:`SBC_TESTS`), ``band`` (counts of one bin, :func:`rank_band_simultaneous`) and per parameter
        ``{"name", "ks_pvalue", "bins_outside", "rejects", "shapes", "z_bias", "z_dispersion"}``;
        ``too_narrow``/``too_wide``/``biased``: the rejected parameters by shape.

    Raises:
        ShapeError: ``ranks`` not ``(N, len(names))`` or ``coverage`` not ``(len(levels),)``.
        ValueError: ``alpha`` outside (0, 1).
    """
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must lie in (0, 1), got {alpha}")
    g = np.asarray(levels, float)
    cov = np.asarray(coverage, float)
    ranks = np.asarray(ranks)
    if cov.shape != g.shape or ranks.ndim != 2 or ranks.shape[1] != len(names):
        raise ShapeError(f"verdict needs coverage ({len(g)},) and ranks (N, {len(names)}); got {cov.shape}, "
                         f"{ranks.shape}")
    a_diag = alpha / len(DIAGNOSTICS)
    conf = 1 - a_diag
    lo, hi = coverage_band_simultaneous(n, g, conf)
    out_idx = curve_outside(cov, lo, hi)
    below = [i for i in out_idx if cov[i] < lo[i]]
    above = [i for i in out_idx if cov[i] > hi[i]]

    def at(level: float) -> dict[str, Any]:
        i = int(np.argmin(np.abs(g - level)))
        v = "over-confident" if cov[i] < lo[i] - 1e-12 else ("under-confident" if cov[i] > hi[i] + 1e-12
                                                             else "calibrated")
        return {"level": float(g[i]), "coverage": float(cov[i]), "band": [float(lo[i]), float(hi[i])], "verdict": v}

    cov_out = {"confidence": conf, "band_lo": lo.tolist(), "band_hi": hi.tolist(),
               "outside": [float(g[i]) for i in out_idx], "rejects": bool(out_idx),
               "direction": _direction(bool(below), bool(above)), "at_50": at(0.5), "at_90": at(0.9)}
    t_rej = bool(float(tarp["ks_pvalue"]) < a_diag)
    tarp_out = {"level": a_diag, "ks_pvalue": float(tarp["ks_pvalue"]), "atc": float(tarp["atc"]),
                "rejects": t_rej,
                "direction": (("over-confident" if tarp["atc"] < 0 else "under-confident") if t_rej else None)}
    D = len(names)
    a_test = a_diag / (len(SBC_TESTS) * D)
    blo, bhi = rank_band_simultaneous(len(ranks), n_bins, a_test)
    ks = rank_tests(ranks, n_draws, n_bins)["ks_pvalue"] if len(ranks) else [1.0] * D
    params = []
    for d, name in enumerate(names):
        h = np.histogram(ranks[:, d], bins=n_bins, range=(0, n_draws + 1))[0]
        bins_out = [int(b) for b in np.flatnonzero((h < blo) | (h > bhi))]
        shape = rank_shape(ranks[:, d], n_draws, a_test)
        moments = len(shape["shapes"]) > 0 and max(abs(shape["z_bias"]), abs(shape["z_dispersion"])) > \
            float(stats.norm.ppf(1 - a_test / 2))
        rej = bool(ks[d] < a_test or bins_out or moments)
        params.append({"name": name, "ks_pvalue": float(ks[d]), "bins_outside": bins_out, "rejects": rej,
                       "shapes": shape["shapes"] if rej else [], "z_bias": shape["z_bias"],
                       "z_dispersion": shape["z_dispersion"]})
    sbc_out = {"level": a_test, "band": [float(blo), float(bhi)], "parameters": params}
    by = {k: [p["name"] for p in params if any(k in sh for sh in p["shapes"])] for k in ("narrow", "wide", "biased")}
    parts = []
    if cov_out["rejects"]:
        parts.append(f"joint coverage {cov_out['direction']} (HPD coverage outside its band at "
                     + ", ".join(f"{int(round(100 * x))}%" for x in cov_out["outside"]) + ")")
    if t_rej:
        parts.append(f"TARP rejects ({tarp_out['direction']}, KS p={tarp_out['ks_pvalue']:.2g})")
    for p in params:
        if p["rejects"]:
            parts.append(f"{p['name']} " + " and ".join(SHAPES[s].split(" (")[0] for s in p["shapes"]))
    ok = not parts
    return {"verdict": "calibrated" if ok else "not calibrated: " + "; ".join(parts), "calibrated": ok,
            "alpha": float(alpha), "coverage": cov_out, "tarp": tarp_out, "sbc": sbc_out,
            "too_narrow": by["narrow"], "too_wide": by["wide"], "biased": by["biased"]}


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
