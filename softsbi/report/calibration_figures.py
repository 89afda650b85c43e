"""The figure of ``softsbi calibrate``: expected coverage with its binomial band, and SBC rank histograms.

Read in seconds: the title is the verdict (it reads all three diagnostics, naming the parameters whose
marginals are too narrow, too wide or biased); left, the coverage curve (blue) against the diagonal
inside the grey band a calibrated estimator stays in (below the band: over-confident, above:
under-confident), with the whole curve's band the verdict uses (dashed) and TARP's curve; right, one
rank histogram per parameter inside the band the verdict uses (a U shape: too narrow; a hump: too
wide; a pile at one end: biased), titled with its verdict.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from softsbi.core.results.fitreport import CalibrationResult, RankHistograms
from softsbi.report.style import (FS_LABEL, FS_LEGEND, FS_SUB, FS_TICK, FS_TITLE, ROLE_COLOURS, _header, _plt,
                                  save_figure)

__all__ = ["calibration_figure", "plot_calibration"]

VERDICT_COLOUR = {"calibrated": "#009E73", "over-confident": "#D55E00", "under-confident": "#E69F00"}
#: a rank histogram's shape (:data:`softsbi.inference.calibration.SHAPES`) in a panel title
SHAPE_WORDS = {"too-narrow": "too narrow (U)", "too-wide": "too wide (hump)", "biased-high": "biased high",
               "biased-low": "biased low"}


def _band_words(s: RankHistograms) -> str:
    """What the grey band of the rank histograms is (older calibration.json: a pointwise band)."""
    if s.band_level is not None:
        return (f"grey: a uniform histogram keeps every bin inside it with probability {1 - s.band_level:.4g}, "
                f"the verdict's level")
    return f"grey: {int(100 * (s.band_confidence or 0.99))}% band of a uniform histogram"


def calibration_figure(cal: CalibrationResult) -> Any:
    """Figure of :func:`plot_calibration` for a :class:`~softsbi.core.results.fitreport.CalibrationResult`."""
    plt = _plt()
    names = list(cal.parameters)
    D = len(names)
    ncol = min(D, 3)
    nrow = -(-D // ncol)
    fig = plt.figure(figsize=(4.6 + 2.3 * ncol, max(4.8, 2.0 * nrow + 2.0)))
    gs = fig.add_gridspec(nrow, 1 + ncol, width_ratios=[2.0] + [1.0] * ncol)
    pc, qc = ROLE_COLOURS["posterior"], ROLE_COLOURS["prior"]
    c = cal.coverage
    g = np.asarray(c.levels)
    ax = fig.add_subplot(gs[:, 0])
    ax.fill_between(g, c.band_lo, c.band_hi, color=qc, alpha=0.5, lw=0,
                    label=f"calibrated ({int(100 * c.band_confidence)}% binomial band)")
    if c.band_simultaneous_lo is not None:  # the whole curve's band (calibration.json before it: pointwise only)
        conf = 100 * (c.band_simultaneous_confidence or 0.95)
        for band, label in ((c.band_simultaneous_lo, f"whole curve: simultaneous {conf:.3g}% band"),
                            (c.band_simultaneous_hi, None)):
            ax.plot(g, band, color="#8a8a8a", lw=0.9, ls="--", label=label)
    ax.plot([0, 1], [0, 1], color="#5a5a5a", lw=1, ls=":")
    ax.plot(g, c.hpd, color=pc, lw=2.2, marker="o", ms=3, label="expected coverage (HPD)")
    tarp_p = cal.tarp.ks_pvalue
    ax.plot(cal.tarp.levels, cal.tarp.coverage, color=pc, lw=1.2, ls="--", alpha=0.7,
            label="TARP" + ("" if tarp_p is None else f" (KS p={tarp_p:.2g})"))
    for lev, at, verdict in ((0.5, c.at_50, cal.verdict_50), (0.9, c.at_90, cal.verdict_90)):
        ax.plot([lev], [at], marker="o", ms=8, color=VERDICT_COLOUR.get(verdict, "#5a5a5a"),
                mec="white", zorder=5)
        ax.annotate(f"{at:.2f} at {int(100 * lev)}%", (lev, at), textcoords="offset points",
                    xytext=(8, -12), fontsize=FS_LABEL)
    ax.text(0.04, 0.93, "under-confident\n(too wide)", fontsize=FS_TICK, color="#5a5a5a", va="top")
    ax.text(0.96, 0.05, "over-confident\n(too narrow)", fontsize=FS_TICK, color="#5a5a5a", ha="right")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_aspect("equal")
    ax.set_xlabel("credibility level", fontsize=FS_LABEL)
    ax.set_ylabel("fraction of test truths inside the region", fontsize=FS_LABEL)
    ax.tick_params(labelsize=FS_TICK)
    handles, labels = ax.get_legend_handles_labels()
    ax.set_title("Coverage", fontsize=FS_SUB, weight="bold")
    s = cal.sbc
    lo, hi = s.band
    shapes = s.shapes or [() for _ in names]  # calibration.json before the per-parameter verdict: none
    for d, name in enumerate(names):
        a = fig.add_subplot(gs[d // ncol, 1 + d % ncol])
        h = np.asarray(s.histograms[d])
        B = len(h)
        a.axhspan(lo, hi, color=qc, alpha=0.5, lw=0)
        a.axhline(h.sum() / B, color="#5a5a5a", lw=0.8, ls=":")
        bad = (h < lo) | (h > hi)
        a.bar(np.arange(B), h, width=0.9, color=[VERDICT_COLOUR["over-confident"] if b else pc for b in bad])
        a.set_xticks([0, B - 1])
        a.set_xticklabels(["truth\nbelow", "truth\nabove"], fontsize=FS_TICK - 1)
        a.tick_params(labelsize=FS_TICK)
        a.set_ylim(0, max(h.max(initial=0), hi) * 1.15)
        p = s.ks_pvalue[d]
        words = " + ".join(SHAPE_WORDS[k] for k in shapes[d]) or "uniform"
        a.set_title(f"{name}: {words}\n(KS p={p:.2g})", fontsize=FS_LABEL,
                    color=VERDICT_COLOUR["over-confident"] if shapes[d] else "black")
    v = cal.verdict
    opts = cal.estimator_options
    est = cal.estimator + (" (" + ", ".join(f"{k}={v}" for k, v in opts.items()) + ")" if opts else "")
    ok = cal.is_calibrated
    frac = _header(fig, [(f"Calibration: {v}", {"fontsize": FS_TITLE, "weight": "bold",
                                                 "color": VERDICT_COLOUR["calibrated" if ok else "over-confident"]}),
                         (f"{Path(cal.run).name}: {est}, {cal.n_test} fresh test simulations from the run's proposals "
                          f"(trained on {cal.n_train}); SBC rank histograms right "
                          f"({_band_words(s)}; orange: a bin outside it)",
                          {"fontsize": FS_SUB})])
    leg_h = 0.45 / fig.get_figheight()
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=FS_LEGEND, frameon=False,
               bbox_to_anchor=(0.5, 0.0))
    fig.tight_layout(rect=(0, leg_h, 1, 1 - frac), pad=0.6)
    return fig


def plot_calibration(path: str | Path, cal: CalibrationResult) -> Path:
    """Save :func:`calibration_figure` of a :class:`~softsbi.core.results.fitreport.CalibrationResult` to ``path``
    (PNG)."""
    return save_figure(calibration_figure(cal), Path(path))
