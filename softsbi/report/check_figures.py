"""The figures of ``check`` (one run's posterior-predictive check) and ``compare`` (two runs' checks, before and
after)."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from softsbi.core.metrics import describe_change
from softsbi.core.results.comparison import CompareResult
from softsbi.core.results import CheckResult, JointTest
from softsbi.report.text import phases_from, regions_from
from softsbi.report.style import (FS_LABEL, FS_LEGEND, FS_SUB, FS_TICK, FS_TITLE, ROLE_COLOURS, _header, _layout, _plt,
                                   save_figure, source_name)


def short_p(test: JointTest) -> str:
    """A joint test's Monte-Carlo p-value with its resolution, short: ``p ≤ 2/201`` or ``p = 0.4 (30 sims)``, or for a
    calibrated omnibus test deciding ``p = 0.4 (100 replicates)``."""
    n, joint = test.n_null, test.combined is not None
    if test.p_value <= test.resolution:
        return f"p ≤ {1 if joint else test.tests}/{n + 1}"
    of = "replicates" if test.calibrated and (joint or test.deciding == "omnibus") else "sims"
    return f"p = {test.p_value:.2g} ({n if joint else test.best.n} {of})"


def check_headline(out: CheckResult) -> str:
    """The verdict of a check in one line: mean error, worst phase, misspecification p-value."""
    verdict = ("the model does NOT explain the measurement" if out.test.misspecified
               else "no evidence of misspecification")
    s = f"Mean error {out.chamfer_mean_m * 100:.2f} cm"
    fit_phases = [ph for ph in out.phases if ph.in_fit]  # the sensor model's frames
    if fit_phases:
        w = max(fit_phases, key=lambda ph: ph.chamfer_m)
        s += f"  ·  worst: {w.phase} phase ({w.chamfer_m * 100:.2f} cm)"
    return s + f"  ·  misspecification {short_p(out.test)}: {verdict}"


#: the angle (deg) of phase labels that would overlap side by side (short phases)
PHASE_LABEL_ROTATION = 35


def _unoverlap(fig: Any, ax: Any, labels: Sequence[Any]) -> None:
    """Tilt tick ``labels`` by :data:`PHASE_LABEL_ROTATION` when any two overlap side by side (measured on the
    figure's canvas with the axes' final width), so that short phases keep readable names."""
    fig.tight_layout()
    renderer = fig.canvas.get_renderer()
    boxes = sorted((lab.get_window_extent(renderer) for lab in labels if lab.get_text()), key=lambda b: b.x0)
    if any(a.x1 > b.x0 - 2 for a, b in zip(boxes, boxes[1:])):
        for lab in labels:
            lab.set(rotation=PHASE_LABEL_ROTATION, ha="left", rotation_mode="anchor")


def _region_short(name: str) -> str:
    return (name.replace(" (at the grasp)", " grasp").replace(" (farthest from the grasp)", " farthest")
            .replace(" (grasped end)", " grasped end").replace(" (far end)", " far end"))


def region_parts(regions: Sequence[str]) -> str:
    """What a check's regions are: ``"segment of the rope"`` when they are segments along a rope (named from its
    grasped end by :func:`~softsbi.workflows.criticism.check.material_regions`), else ``"region of the cloth"``."""
    return "segment of the rope" if regions and regions[0].endswith("(grasped end)") else "region of the cloth"


def check_figure(out: CheckResult) -> Any:
    """Figure of :func:`plot_check`."""
    plt = _plt()
    t = np.array(out.times_s, dtype=float)
    reg = np.array(out.region_error_m, dtype=float) * 100
    pc = ROLE_COLOURS["posterior"]
    fig, axes = plt.subplots(1, 2, figsize=(12.5, 5.0), gridspec_kw={"width_ratios": [1.2, 1]})
    ax = axes[0]
    c = out.chamfer
    m = np.array(c.mean) * 100
    ax.fill_between(t, np.array(c.q05) * 100, np.array(c.q95) * 100, color=pc, alpha=0.25, lw=0,
                    label="posterior rollouts: 5-95%")
    ax.plot(t, m, color=pc, lw=2, label="posterior rollouts: mean")
    phases = out.phases
    fit_phases = [ph for ph in phases if ph.in_fit]  # phases outside the fit's frames: not blamed
    worst = max(fit_phases, key=lambda ph: ph.chamfer_m) if fit_phases else None
    dt = (t[1] - t[0]) / 2 if len(t) > 1 else 0.02
    for k, ph in enumerate(phases):
        if k % 2 == 0:
            ax.axvspan(ph.t_s[0] - dt, ph.t_s[1] + dt, color="0.5", alpha=0.08, lw=0)
    if phases:  # phase names and their mean error on a top axis, clear of the data
        top = ax.secondary_xaxis("top")
        top.set_xticks([float(np.mean(ph.t_s)) for ph in phases])
        top.set_xticklabels([f"{ph.phase}{' (worst)' if ph is worst else ''}"
                             f"{'' if ph.in_fit else ' (not fitted)'}\n{ph.chamfer_m * 100:.2f} cm"
                             for ph in phases], fontsize=FS_TICK, linespacing=1.1)
        top.tick_params(length=0)
        for lab, ph in zip(top.get_xticklabels(), phases):
            lab.set_weight("bold" if ph is worst else "normal")
        _unoverlap(fig, ax, top.get_xticklabels())
    ax.set_xlabel("time [s]", fontsize=FS_LABEL)
    ax.set_ylabel("Chamfer to the measurement [cm]", fontsize=FS_LABEL)
    ax.tick_params(labelsize=FS_TICK)
    ax.set_ylim(bottom=0)
    ax.set_xlim(t[0] - dt, t[-1] + dt)
    ax.set_title(f"Error per frame, by phase ({phases_from(out)})",
                 fontsize=FS_SUB)
    ax.legend(fontsize=FS_LEGEND, loc="best")
    ax.grid(alpha=0.3)
    ax = axes[1]
    compared = np.array(out.region_compared, dtype=bool)
    cmap = plt.get_cmap("magma").with_extremes(bad="0.75")  # regions the sensor model never sees: grey, not a match
    fitted = np.zeros(len(reg), bool)
    fitted[list(out.metric_frames) if out.metric_frames is not None else slice(None)] = True
    # the colour scale runs from 0 to at least HEATMAP_MIN_CM, so that a passing run's small errors look small
    # (a scale set by each run's own maximum made a passing control as "hot" as a failing one); above that it follows
    # the fitted frames (frames outside them, e.g. a real recording's cloth on the table, can be ten times worse and
    # would leave the fitted part black)
    vals = reg[fitted][compared[fitted]]
    vmax = max(float(np.max(vals)) if vals.size else 0.0, HEATMAP_MIN_CM)
    im = ax.imshow(np.ma.masked_where(~compared, reg).T, aspect="auto", origin="lower", cmap=cmap, vmin=0,
                   vmax=vmax, extent=[t[0] - dt, t[-1] + dt, 0.5, reg.shape[1] + 0.5])
    for ph in phases[1:]:
        ax.axvline(ph.t_s[0] - dt, color="white", lw=1, ls="--", alpha=0.8)
    ax.set_yticks(range(1, reg.shape[1] + 1))
    ax.set_yticklabels([_region_short(n) for n in out.regions], fontsize=FS_TICK)
    ax.set_xlabel("time [s]", fontsize=FS_LABEL)
    parts = region_parts(out.regions)
    ax.set_ylabel(f"{parts} (R1 at {regions_from(out)})" if "rope" in parts
                  else f"region of the object (R1 nearest {regions_from(out)})", fontsize=FS_LABEL)
    ax.tick_params(labelsize=FS_TICK)
    ax.set_title(f"Error per {parts} (dashed: phase boundaries"
                 + ("; grey: not seen by the sensor model)" if not compared.all() else ")"), fontsize=FS_SUB)
    cb = fig.colorbar(im, ax=ax, fraction=0.046)
    cb.set_label(f"mean error [cm] (scale from 0 to at least {HEATMAP_MIN_CM:g} cm"
                 + ("; above: fitted frames)" if not fitted.all() else ")"), fontsize=FS_LABEL)
    cb.ax.tick_params(labelsize=FS_TICK)
    frac = _header(fig, [(check_headline(out), {"fontsize": FS_TITLE, "weight": "bold"}),
                         (f"Posterior predictive check of {source_name(out.run)}: {out.n_rollouts} "
                          f"rollouts at posterior samples" + (f"; worst region {out.worst_regions[0]}"
                                                              if out.worst_regions else ""),
                          {"fontsize": FS_SUB})])
    _layout(fig, frac)
    return fig


#: the least top of the check heat map's colour scale (cm): errors below it never look "hot", whatever the run
HEATMAP_MIN_CM = 5.0


def plot_check(path: Path, out: CheckResult) -> Path:
    """Chamfer per frame with its posterior band and phases, and heatmap (frame x region); the
    headline gives the verdict (mean error, worst phase, misspecification p-value)."""
    return save_figure(check_figure(out), path)


def compare_figure(res: CompareResult) -> Any:
    """Figure of :func:`plot_compare`."""
    plt = _plt()
    a, b, la, lb = res.check_a, res.check_b, res.label_a, res.label_b
    t = np.array(a.times_s)
    fig, axes = plt.subplots(1, 2, figsize=(12.5, 5.0))
    ca, cb = ROLE_COLOURS["nominal"], ROLE_COLOURS["with_effect"]
    ax = axes[0]
    for chk, lab, col in ((a, f"A (before): {la}", ca), (b, f"B (after): {lb}", cb)):
        c = chk.chamfer
        ax.fill_between(t, np.array(c.q05) * 100, np.array(c.q95) * 100, color=col, alpha=0.22, lw=0)
        ax.plot(t, np.array(c.mean) * 100, color=col, lw=2, label=f"{lab}, mean {chk.chamfer_mean_m * 100:.2f} cm (n={chk.n_rollouts} rollouts)")
    ax.set_xlabel("time [s]", fontsize=FS_LABEL)
    ax.set_ylabel("Chamfer to the measurement [cm]", fontsize=FS_LABEL)
    ax.tick_params(labelsize=FS_TICK)
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=FS_LEGEND, loc="best")
    ax.set_title("Error per frame (line: mean, band: 5-95% over posterior rollouts)", fontsize=FS_SUB)
    ax = axes[1]
    names = a.regions
    x = np.arange(len(names))
    ax.bar(x - 0.2, [a.region_mean_m[n] * 100 for n in names], 0.4, color=ca, label=f"A (before): {la}")
    ax.bar(x + 0.2, [b.region_mean_m.get(n, 0) * 100 for n in names], 0.4, color=cb, label=f"B (after): {lb}")
    top = max([a.region_mean_m[n] * 100 for n in names] + [b.region_mean_m.get(n, 0) * 100 for n in names] + [0.1])
    ax.set_ylim(0, 1.3 * top)  # room for the legend above the bars
    ax.set_xticks(x)
    ax.set_xticklabels([n.split(" ")[0] for n in names], fontsize=FS_TICK)
    ax.tick_params(labelsize=FS_TICK)
    parts = region_parts(names)
    ax.set_xlabel(parts + (" (R1 at the grasped end ... far end)" if "rope" in parts
                           else " (R1 at the grasp ... farthest)"), fontsize=FS_LABEL)
    ax.set_ylabel("mean error [cm]", fontsize=FS_LABEL)
    ax.legend(fontsize=FS_LEGEND, loc="best")
    ax.grid(alpha=0.3, axis="y")
    ax.set_title(f"Error per {parts}", fontsize=FS_SUB)
    ma, mb = a.chamfer_mean_m * 100, b.chamfer_mean_m * 100
    pa, pb = short_p(a.test), short_p(b.test)
    head = (f"Mean error {ma:.2f} → {mb:.2f} cm ({describe_change(ma, mb)})"
            f"  ·  misspecification {pa} → {pb}")
    frac = _header(fig, [(head, {"fontsize": FS_TITLE, "weight": "bold"}),
                         (f"A (before): {la}   vs   B (after): {lb}", {"fontsize": FS_SUB})])
    _layout(fig, frac)
    return fig


def plot_compare(path: Path, res: CompareResult) -> Path:
    """Two runs' posterior-predictive checks: Chamfer per frame and error per region; run A
    (before) in the ``nominal`` colour, run B (after) in the ``with_effect`` colour."""
    return save_figure(compare_figure(res), path)
