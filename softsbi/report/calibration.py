"""The figure of ``softsbi calibrate``: expected coverage with its binomial band, and SBC rank histograms.

Read in seconds: left, the coverage curve (blue) against the diagonal inside the grey band a
calibrated estimator stays in (below the band: over-confident, above: under-confident); right, one
rank histogram per parameter inside the grey band of a uniform histogram (a U shape: over-confident;
a hump: under-confident; a slope: biased).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from softsbi.report.figures import (FS_LABEL, FS_LEGEND, FS_SUB, FS_TICK, FS_TITLE, ROLE_COLOURS, _header,
                                    _plt, _save)

__all__ = ["calibration_figure", "plot_calibration"]

VERDICT_COLOUR = {"calibrated": "#009E73", "over-confident": "#D55E00", "under-confident": "#E69F00"}


def calibration_figure(cal: Mapping[str, Any]) -> Any:
    """Figure of :func:`plot_calibration` for a ``calibration.json`` dict."""
    plt = _plt()
    names = list(cal["parameters"])
    D = len(names)
    ncol = min(D, 3)
    nrow = -(-D // ncol)
    fig = plt.figure(figsize=(4.6 + 2.3 * ncol, max(4.4, 2.0 * nrow + 1.6)))
    gs = fig.add_gridspec(nrow, 1 + ncol, width_ratios=[2.0] + [1.0] * ncol)
    pc, qc = ROLE_COLOURS["posterior"], ROLE_COLOURS["prior"]
    c = cal["coverage"]
    g = np.asarray(c["levels"])
    ax = fig.add_subplot(gs[:, 0])
    ax.fill_between(g, c["band_lo"], c["band_hi"], color=qc, alpha=0.5, lw=0,
                    label=f"calibrated ({int(100 * c['band_confidence'])}% binomial band)")
    if "band_simultaneous_lo" in c:  # the whole curve's band (calibration.json before it: pointwise only)
        for key in ("band_simultaneous_lo", "band_simultaneous_hi"):
            ax.plot(g, c[key], color="#8a8a8a", lw=0.9, ls="--",
                    label="whole curve: simultaneous 95% band" if key.endswith("lo") else None)
    ax.plot([0, 1], [0, 1], color="#5a5a5a", lw=1, ls=":")
    ax.plot(g, c["hpd"], color=pc, lw=2.2, marker="o", ms=3, label="expected coverage (HPD)")
    ax.plot(cal["tarp"]["levels"], cal["tarp"]["coverage"], color=pc, lw=1.2, ls="--", alpha=0.7, label="TARP")
    for lev, key in ((0.5, "at_50"), (0.9, "at_90")):
        ax.plot([lev], [c[key]], marker="o", ms=8, color=VERDICT_COLOUR[cal[f"verdict_{int(100 * lev)}"]],
                mec="white", zorder=5)
        ax.annotate(f"{c[key]:.2f} at {int(100 * lev)}%", (lev, c[key]), textcoords="offset points",
                    xytext=(8, -12), fontsize=FS_LABEL)
    ax.text(0.04, 0.93, "under-confident\n(too wide)", fontsize=FS_TICK, color="#5a5a5a", va="top")
    ax.text(0.96, 0.05, "over-confident\n(too narrow)", fontsize=FS_TICK, color="#5a5a5a", ha="right")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_aspect("equal")
    ax.set_xlabel("credibility level", fontsize=FS_LABEL)
    ax.set_ylabel("fraction of test truths inside the region", fontsize=FS_LABEL)
    ax.tick_params(labelsize=FS_TICK)
    ax.legend(fontsize=FS_LEGEND, loc="upper left", bbox_to_anchor=(0.0, 0.84), frameon=False)
    ax.set_title("Coverage", fontsize=FS_SUB, weight="bold")
    s = cal["sbc"]
    lo, hi = s["band"]
    for d, name in enumerate(names):
        a = fig.add_subplot(gs[d // ncol, 1 + d % ncol])
        h = np.asarray(s["histograms"][d])
        B = len(h)
        a.axhspan(lo, hi, color=qc, alpha=0.5, lw=0)
        a.axhline(h.sum() / B, color="#5a5a5a", lw=0.8, ls=":")
        bad = (h < lo) | (h > hi)
        a.bar(np.arange(B), h, width=0.9, color=[VERDICT_COLOUR["over-confident"] if b else pc for b in bad])
        a.set_xticks([0, B - 1])
        a.set_xticklabels(["truth\nbelow", "truth\nabove"], fontsize=FS_TICK - 1)
        a.tick_params(labelsize=FS_TICK)
        a.set_ylim(0, max(h.max(initial=0), hi) * 1.15)
        p = s["ks_pvalue"][d]
        a.set_title(f"{name}  (KS p={p:.2g})", fontsize=FS_LABEL)
    v = cal["verdict"]
    opts = cal.get("estimator_options") or {}
    est = cal["estimator"] + (" (" + ", ".join(f"{k}={v}" for k, v in opts.items()) + ")" if opts else "")
    frac = _header(fig, [(f"Calibration: {v}", {"fontsize": FS_TITLE, "weight": "bold",
                                                 "color": VERDICT_COLOUR.get(v, "black")}),
                         (f"{Path(str(cal.get('run', ''))).name}: {est}, {cal['n_test']} fresh test simulations from the run's proposals "
                          f"(trained on {cal['n_train']}); SBC rank histograms right "
                          f"(grey: {int(100 * s['band_confidence'])}% band of a uniform histogram; orange: a bin outside it)",
                          {"fontsize": FS_SUB})])
    fig.tight_layout(rect=(0, 0, 1, 1 - frac), pad=0.6)
    return fig


def plot_calibration(path: str | Path, cal: Mapping[str, Any]) -> Path:
    """Save :func:`calibration_figure` of a ``calibration.json`` dict to ``path`` (PNG)."""
    return _save(calibration_figure(cal), Path(path))
