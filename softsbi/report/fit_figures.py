"""The figures of a fit: Chamfer per round, the posterior's pair plot, measured vs simulated clouds and, for image
fits, measured vs rendered frames. They draw what they are given: the caller (:mod:`softsbi.workflows.fit.plots`)
simulates."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from softsbi.inference.contraction import INFORMED_MAX_RATIO, contraction
from softsbi.report.style import (FS_LABEL, FS_LEGEND, FS_SUB, FS_TICK, FS_TITLE, ROLE_COLOURS, _header, _layout, _plt,
                                   _unit, fit_label, grip_label, save_figure, source_name, view_planes)
from softsbi.scenarios.handles import handle_tracks, pinned_vertices


def chamfer_rounds_figure(report: dict[str, Any]) -> Any:
    """Figure of :func:`plot_chamfer_rounds`."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    if report.get("metric") == "mask_chamfer_px":
        key, scale, unit, what = "mask_chamfer_{}_px", 1.0, "px", "mask Chamfer"
    else:
        key, scale, unit, what = "chamfer_{}_m", 100.0, "cm", "Chamfer"
    post, post_std = key.format("posterior"), key.format("posterior_std")
    rows = [r for r in report["per_round"] if r.get(post) is not None]
    if report.get(key.format("prior")) is not None:
        m, s = report[key.format("prior")] * scale, (report.get(key.format("prior_std")) or 0) * scale
        ax.axhspan(m - s, m + s, color=ROLE_COLOURS["prior"], alpha=0.35, lw=0, label="prior: ± std")
        ax.axhline(m, color=ROLE_COLOURS["prior"], lw=2, label=f"prior: mean {m:.2f} {unit}")
    if rows:
        x = [r["round"] + 1 for r in rows]
        y = np.array([r[post] for r in rows]) * scale
        e = np.array([r[post_std] or 0 for r in rows]) * scale
        # after round r < last, the point is round r+1's rollouts, drawn from the proposal round r's posterior
        # gives (the posterior itself for corrected rounds, the truncated prior for truncated ones); after the
        # last round it is the posterior predictive (n_eval rollouts at final-posterior samples)
        final = (report.get(post) is not None
                 and rows[-1]["round"] == max(r["round"] for r in report["per_round"]))
        k = len(rows) - 1 if final else len(rows)
        if k:
            truncated = report.get("proposal") == "truncated"
            what_prop = ("next round's rollouts, from the truncated prior" if truncated
                         else "next round's rollouts, from the posterior")
            ax.errorbar(x[:k], y[:k], yerr=e[:k], marker="o", mfc="white", ls="--", color=ROLE_COLOURS["posterior"],
                        capsize=3, lw=1.5, label=f"{what_prop}: mean ± std")
        if final:
            ax.errorbar(x[-1:], y[-1:], yerr=e[-1:], marker="o", ms=8, color=ROLE_COLOURS["posterior"], capsize=3,
                        lw=2, label=f"posterior predictive: mean ± std ({y[-1]:.2f} {unit})")
        ax.set_xticks(x)
        ax.set_xlim(min(x) - 0.5, max(x) + 0.5)
    ax.set_xlabel("after round (number)", fontsize=FS_LABEL)
    ax.set_ylabel(f"{what} to the measurement,\nmean over frames [{unit}]", fontsize=FS_LABEL)
    ax.tick_params(labelsize=FS_TICK)
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=FS_LEGEND, loc="best")
    ax.grid(alpha=0.3)
    frac = _header(fig, [(f"Distance to the measurement per round — fit: {fit_label(report)}",
                          {"fontsize": FS_TITLE, "weight": "bold"}),
                         (f"measurement: {source_name(report.get('observed'))}", {"fontsize": FS_SUB})])
    _layout(fig, frac)
    return fig


def plot_chamfer_rounds(path: Path, report: dict[str, Any]) -> Path:
    """Mean Chamfer of rollouts at prior samples (band), of each later round's rollouts (drawn from
    the proposal the previous round's posterior gives: that posterior for ``proposal="corrected"``,
    the truncated prior for ``"truncated"``, which is wider) and of the posterior predictive (the
    fit's ``n_eval`` rollouts at final-posterior samples, the reported number): 3-D Chamfer in cm,
    or for image fits the mask Chamfer in px. Titled with what was fitted (backend + effects) and,
    below, the measurement."""
    return save_figure(chamfer_rounds_figure(report), path)


def _param_ticks(p: Any, n: int = 3) -> list[float]:
    """At most ``n`` round, evenly spaced tick values inside ``[p.low, p.high]``: powers of ten
    (every k-th decade) for log parameters spanning two decades or more, 1-2-5 values for
    narrower log parameters, 1-2-2.5-5 steps for linear ones."""
    lo, hi = float(p.low), float(p.high)
    eps = 1e-9 * (hi - lo)
    if p.log:
        a, b = np.log10(lo), np.log10(hi)
        decs = np.arange(np.ceil(a - 1e-9), np.floor(b + 1e-9) + 1)
        if len(decs) >= 2:
            step = int(np.ceil((len(decs) - 1) / max(n - 1, 1)))
            return [float(10.0 ** d) for d in decs[::step]]
        cand = [m * 10.0 ** e for e in range(int(np.floor(a)), int(np.ceil(b)) + 1) for m in (1, 2, 5)]
        ticks = [c for c in cand if lo - eps <= c <= hi + eps]
    else:
        from matplotlib.ticker import MaxNLocator  # heavy: loaded on the first figure only
        ticks = []
        for nb in (n, n - 1, 1):
            ticks = [float(t) for t in MaxNLocator(max(nb, 1), steps=[1, 2, 2.5, 5, 10]).tick_values(lo, hi)
                     if lo - eps <= t <= hi + eps]
            if len(ticks) <= n:
                break
    if len(ticks) > n:
        idx = sorted(set(np.round(np.linspace(0, len(ticks) - 1, n)).astype(int)))
        ticks = [ticks[i] for i in idx]
    return [float(f"{t:.6g}") for t in ticks]


def _tick_texts(ticks: Sequence[float]) -> list[str]:
    """Short, consistent labels for one axis: plain numbers (``0.25``, ``400``) when every tick lies
    in [0.01, 1e4) (with a real minus sign), else powers of ten (``10^-5``, ``2×10^-4``) for all."""
    def plain(v: float) -> str:
        return f"{int(v)}" if float(v).is_integer() else f"{v:.3g}"

    def power(v: float) -> str:
        e = int(np.floor(np.log10(abs(v))))
        m = v / 10.0 ** e
        return f"$10^{{{e}}}$" if np.isclose(m, 1) else f"${m:.2g}{{\\times}}10^{{{e}}}$"

    use_plain = all(v == 0 or 0.01 <= abs(v) < 1e4 for v in ticks)
    return [("0" if v == 0 else plain(v).replace("-", "\u2212") if use_plain else power(v)) for v in ticks]


def _padded(p: Any, frac: float = 0.05) -> tuple[float, float]:
    """Axis limits a little beyond the prior bounds (so the prior box shows as a box)."""
    if p.log:
        a, b = np.log10(p.low), np.log10(p.high)
        d = frac * (b - a)
        return 10.0 ** (a - d), 10.0 ** (b + d)
    d = frac * (p.high - p.low)
    return p.low - d, p.high + d


def pairs_figure(space: Any, samples: np.ndarray, truth: dict[str, float] | None = None,
                 subtitle: str = "", max_points: int = 1500) -> Any:
    """Figure of :func:`plot_pairs`."""
    plt = _plt()
    from matplotlib.lines import Line2D  # heavy: loaded on the first figure only
    from matplotlib.patches import Patch, Rectangle  # heavy: loaded on the first figure only
    from matplotlib.ticker import FixedFormatter, FixedLocator, NullLocator  # heavy: loaded on the first figure only

    D = space.dim
    samples = np.asarray(samples, dtype=float)
    panel = float(np.clip(11.0 / D, 1.45, 2.6))  # inches per panel: 6-12 in in all for D = 2..8
    fig, axes = plt.subplots(D, D, figsize=(panel * D + 0.9, panel * D + 1.1), squeeze=False)
    fs_tick = FS_TICK if panel >= 1.8 else FS_TICK - 0.5
    truth = dict(truth or {})
    nbins = 25
    pc, qc, tc = ROLE_COLOURS["posterior"], ROLE_COLOURS["prior"], ROLE_COLOURS["truth"]
    params = list(space)
    show = samples[:max_points]
    con = contraction(space, samples) if len(samples) > 1 else {}

    def axis_style(axis, p):
        ticks = _param_ticks(p)
        axis.set_major_locator(FixedLocator(ticks))
        axis.set_minor_locator(NullLocator())
        axis.set_major_formatter(FixedFormatter(_tick_texts(ticks)))
        return _padded(p)

    for i, pi in enumerate(params):
        for j, pj in enumerate(params):
            ax = axes[i, j]
            if j > i:
                ax.axis("off")
                continue
            if pj.log:
                ax.set_xscale("log")
            ax.set_xlim(*axis_style(ax.xaxis, pj))
            if i == j:
                edges = np.geomspace(pi.low, pi.high, nbins + 1) if pi.log else np.linspace(pi.low, pi.high, nbins + 1)
                h, _ = np.histogram(samples[:, i], bins=edges)
                h = h / max(len(samples), 1)
                ax.fill_between([pi.low, pi.high], 0, 1.0 / nbins, color=qc, alpha=0.45, lw=0, zorder=1)
                ax.plot([pi.low, pi.low, pi.high, pi.high], [0, 1.0 / nbins, 1.0 / nbins, 0], color=qc, lw=1.2,
                        zorder=1)
                ax.stairs(h, edges, fill=True, color=pc, alpha=0.85, zorder=2)
                ax.set_ylim(0, 1.12 * max(h.max(initial=0), 1.0 / nbins))
                ax.set_yticks([])
                if pi.name in truth:
                    ax.axvline(truth[pi.name], color=tc, lw=2, zorder=3)
                if pi.name in con:  # contraction: 90% width over the prior's, in the parameter's own scale
                    c = con[pi.name]
                    ax.set_title(f"width {c['width_ratio']:.2f} of prior" + ("" if c["informed"] else
                                                                            "\nnot informed"),
                                 fontsize=FS_TICK, color="black" if c["informed"] else "#5a5a5a", pad=2)
            else:
                if pi.log:
                    ax.set_yscale("log")
                ax.set_ylim(*axis_style(ax.yaxis, pi))
                ax.add_patch(Rectangle((pj.low, pi.low), pj.high - pj.low, pi.high - pi.low, facecolor=qc,
                                       alpha=0.22, edgecolor="none", zorder=0))
                ax.add_patch(Rectangle((pj.low, pi.low), pj.high - pj.low, pi.high - pi.low, facecolor="none",
                                       edgecolor=qc, lw=1.2, zorder=1))
                ax.scatter(show[:, j], show[:, i], s=3, alpha=0.35, color=pc, linewidths=0, zorder=2)
                if pi.name in truth and pj.name in truth:
                    ax.plot(truth[pj.name], truth[pi.name], marker="X", ms=8, color=tc, mec="white", mew=0.8,
                            ls="none", zorder=3)
            # tick labels and axis labels only on the outer row / column
            ax.tick_params(labelsize=fs_tick, length=3, pad=2)
            if i == D - 1:
                ax.set_xlabel(f"{pj.name} [{_unit(pj.unit)}]", fontsize=FS_LABEL)
                for lab in ax.get_xticklabels():
                    lab.set_rotation(30 if panel < 2.2 else 0)
                    lab.set_ha("right" if panel < 2.2 else "center")
            else:
                ax.tick_params(labelbottom=False)
            if j == 0 and i > 0:
                ax.set_ylabel(f"{pi.name} [{_unit(pi.unit)}]", fontsize=FS_LABEL)
            elif i != j:
                ax.tick_params(labelleft=False)
    handles = [Patch(facecolor=pc, alpha=0.85, label=f"posterior ({len(samples)} samples)"),
               Patch(facecolor=qc, alpha=0.45, edgecolor=qc, label="prior (flat over the box)")]
    if any(p.name in truth for p in params):
        handles.append(Line2D([], [], color=tc, lw=2, marker="X", ms=8, mec="white", label="truth (hidden value)"))
    leg_ax = axes[0, -1] if D > 1 else axes[0, 0]
    leg = leg_ax.legend(handles=handles, loc="upper right" if D > 1 else "best",
                        fontsize=FS_LEGEND + 1, frameon=D == 1, borderaxespad=0.0)
    leg.set_in_layout(False)  # it sits in the empty upper triangle; the grid keeps its size
    frac = _header(fig, [("Posterior over the prior box (grey box = prior bounds)", {"fontsize": FS_TITLE,
                                                                                      "weight": "bold"}),
                         (subtitle, {"fontsize": FS_SUB}),
                         (f"width: the 90% interval over the prior's, in each parameter's own scale (log for "
                          f"log-scaled ones); not informed above {INFORMED_MAX_RATIO:g}" if con else "",
                          {"fontsize": FS_TICK, "color": "#5a5a5a"})])
    fig.tight_layout(rect=(0, 0, 1, 1 - frac), pad=0.6, h_pad=0.3, w_pad=0.3)
    return fig


def plot_pairs(path: Path, space: Any, samples: np.ndarray, truth: dict[str, float] | None = None,
               subtitle: str = "") -> Path:
    """Corner plot of posterior samples over the prior box (log axes for log-scaled parameters):
    the prior box as a light grey box (off-diagonal) and a flat band (diagonal: fraction of samples
    per bin; the prior's is ``1 / bins``), the truth when known; ticks and labels on the outer
    row and column only."""
    return save_figure(pairs_figure(space, samples, truth, subtitle), path)


def clouds_figure(scenario: Any, dense: np.ndarray, sim_pts: np.ndarray | None, frames: Sequence[int],
                  title: str = "", status: str = "", vertices: np.ndarray | None = None, rope: bool = False,
                  best_pts: np.ndarray | None = None, best_label: str = "") -> Any:
    """Figure of :func:`plot_clouds`, in two rows: the scenario's view, then the other
    (:func:`~softsbi.report.style.view_planes`); ``dense (T, N, 3)`` measured, ``sim_pts (T, M, 3)`` simulated
    (None: the simulation failed), every handle of ``scenario``: its grippers ``+`` (where the simulated
    ``vertices (T, V, 3)`` hold them, when given) and the vertices it holds in place ``x``; ``best_pts (T, M, 3)``
    the best fit's rollout (None: not drawn) with its legend text ``best_label``."""
    plt = _plt()
    from matplotlib.lines import Line2D  # heavy: loaded on the first figure only
    from matplotlib.ticker import MaxNLocator  # heavy: loaded on the first figure only
    fig, axes = plt.subplots(2, len(frames), figsize=(3.1 * len(frames) + 0.6, 6.9), squeeze=False)
    mc, pc, gc = ROLE_COLOURS["measured"], ROLE_COLOURS["posterior"], ROLE_COLOURS["gripper"]
    views = [(a, b, name, (f"{'xyz'[a]} [m]", f"{'xyz'[b]} [m]"))
             for a, b, name in view_planes(getattr(scenario, "view", "yz"))]
    tracks = handle_tracks(scenario, None if vertices is None else vertices[0], rope)
    pinned = [] if vertices is None else pinned_vertices(scenario, vertices[0], rope)
    for c, f in enumerate(frames):
        real = dense[f]
        for r, (a, b, view, lab) in enumerate(views):
            ax = axes[r, c]
            ax.scatter(real[:, a], real[:, b], s=4, color=mc, alpha=0.7, linewidths=0, label="measured")
            if sim_pts is not None:
                ax.scatter(sim_pts[f][:, a], sim_pts[f][:, b], s=4, color=pc, alpha=0.5, linewidths=0,
                           label="simulated at the posterior median")
            if best_pts is not None:
                ax.scatter(best_pts[f][:, a], best_pts[f][:, b], s=4, color=ROLE_COLOURS["best_fit"], alpha=0.45,
                           linewidths=0, label=best_label)
            for _, path in tracks:
                g = path[f]
                ax.plot(g[a], g[b], "+", color="white", ms=14, mew=4.5, zorder=4)
                ax.plot(g[a], g[b], "+", color=gc, ms=13, mew=2.2, zorder=5)
            for _, i in pinned:
                ax.plot(vertices[f, i, a], vertices[f, i, b], "x", color=gc, ms=10, mew=2.2, zorder=5)
            ax.set_aspect("equal", adjustable="datalim")
            ax.set_xlabel(lab[0], fontsize=FS_LABEL)
            ax.set_ylabel(f"{view}\n{lab[1]}" if c == 0 else lab[1], fontsize=FS_LABEL)
            ax.tick_params(labelsize=FS_TICK)
            ax.xaxis.set_major_locator(MaxNLocator(4))
            ax.grid(alpha=0.25)
            if r == 0:
                ax.set_title(f"frame {f}, t = {scenario.times[f]:.2f} s", fontsize=FS_SUB)
    dot = {"ls": "none", "marker": "o", "ms": 6}
    handles = [Line2D([], [], color=mc, label="measured", **dot)]
    if sim_pts is not None:
        handles.append(Line2D([], [], color=pc, label="simulated at the posterior median", **dot))
    if best_pts is not None:
        handles.append(Line2D([], [], color=ROLE_COLOURS["best_fit"], label=best_label, **dot))
    handles.append(Line2D([], [], color=gc, ls="none", marker="+", ms=10, mew=2, label=grip_label(len(tracks))))
    if pinned:
        handles.append(Line2D([], [], color=gc, ls="none", marker="x", ms=8, mew=2, label="held in place"))
    what = "the posterior median" + (" and the best fit" if best_pts is not None else "")
    frac = _header(fig, [(f"Measured vs simulated at {what}{status}", {"fontsize": FS_TITLE, "weight": "bold"}),
                         (title, {"fontsize": FS_SUB})])
    leg_h = 0.55 / fig.get_figheight()
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=FS_LEGEND + 1, frameon=False,
               bbox_to_anchor=(0.5, 0.0))
    _layout(fig, frac, leg_h)
    return fig


def frames_figure(rows: Sequence[tuple[str, np.ndarray, np.ndarray, np.ndarray]], frames: Sequence[int],
                  report: dict[str, Any], scenario_name: str, observer: str, status: str = "") -> Any:
    """Image fits: one row of frames per ``(label, images (T, H, W, 3) uint8, keypoints (T, K, 2) px,
    cloth masks (T, H, W) bool)`` in ``rows`` (the measured frames, then those rendered at the posterior median),
    each frame with its keypoints (cyan) and its mask's outline (yellow); ``report`` is the fit's report (its
    mask Chamfer goes in the headline), ``status`` says why a row is missing."""
    plt = _plt()
    fig, axes = plt.subplots(len(rows), len(frames), figsize=(2.8 * len(frames), 3.0 * len(rows) + 0.6),
                             squeeze=False)
    for r, (label, imgs, kp, m) in enumerate(rows):
        for c, f in enumerate(frames):
            ax = axes[r, c]
            ax.imshow(imgs[f])
            if m[f].any():
                ax.contour(m[f], levels=[0.5], colors="yellow", linewidths=0.7)
            ax.scatter(kp[f, :, 0], kp[f, :, 1], s=16, c="cyan", edgecolors="k", linewidths=0.5)
            ax.set_title(f"{label}, frame {f}", fontsize=FS_SUB)
            ax.axis("off")
    rep = report
    score = (f"mask Chamfer prior {rep['mask_chamfer_prior_px']:.2f} px → posterior "
             f"{rep['mask_chamfer_posterior_px']:.3f} px" if rep.get("mask_chamfer_posterior_px") is not None else "")
    frac = _header(fig, [(f"Measured vs rendered at the posterior median{status}", {"fontsize": FS_TITLE,
                                                                                     "weight": "bold"}),
                         (f"fit: {fit_label(rep)}, {scenario_name}; {observer} keypoints (cyan), "
                          f"HSV cloth mask (yellow)" + (f"; {score}" if score else ""), {"fontsize": FS_SUB})])
    _layout(fig, frac)
    return fig
