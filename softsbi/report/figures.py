"""PNG figures of a fit: Chamfer per round, posterior pair plot, real vs simulated clouds, and the
figures of ``check`` and ``compare``.

Every figure uses one palette, :data:`ROLE_COLOURS` (Okabe & Ito's colour-blind-safe colours plus
greys): a colour means the same *role* in every figure. Each ``plot_*`` function saves a PNG;
the matching ``*_figure`` function builds the :class:`matplotlib.figure.Figure` without saving it
(tests inspect it).
"""
from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from softsbi.core.metrics import describe_change
from softsbi.core.results import CheckResult, CompareResult, JointTest
from softsbi.report.text import phases_from, regions_from

#: one colour per role, in every figure of a fit, of ``check``, ``compare`` and ``compare-backends``.
#: Measured data is neutral grey, everything simulated is coloured; the prior is a light grey;
#: the truth (hidden parameters of a simulated measurement) is vermillion.
ROLE_COLOURS: dict[str, str] = {
    "measured": "#5a5a5a",     # dark grey: the measurement (real or simulated with hidden parameters)
    "posterior": "#0072B2",    # blue: posterior samples, rollouts at the posterior
    "prior": "#b0b0b0",        # light grey: the prior box / prior rollouts
    "truth": "#D55E00",        # vermillion: hidden true parameters
    "gripper": "#000000",      # black: the gripper's position
    "nominal": "#E69F00",      # orange: run A of ``compare`` (before, e.g. the nominal model)
    "with_effect": "#009E73",  # bluish green: run B of ``compare`` (after, e.g. with the effect)
    "best_fit": "#AA3377",     # purple (Paul Tol's colour-blind-safe scheme): the fit's best fit and its rollout
}
#: engines of ``compare-backends`` (no role: each engine is one simulation), in backend order:
#: sky blue, reddish purple, then brown and dark teal for a third and fourth engine.
ENGINE_COLOURS: tuple[str, ...] = ("#56B4E9", "#CC79A7", "#8C510A", "#01665E")

DPI = 120           # saved resolution of every figure
FS_TITLE = 11       # headline
FS_SUB = 9          # second headline line, axes titles
FS_LABEL = 9        # axis labels
FS_TICK = 8         # tick labels
FS_LEGEND = 8       # legends


def handle_tracks(scenario: Any, vertices0: np.ndarray | None = None,
                  rope: bool = False) -> list[tuple[str, np.ndarray]]:
    """``[(name, (T, 3) m)]``: every handle of ``scenario`` that follows a path (its grippers), the scenario's
    gripper first; a scenario built without handles gives its ``gripper`` path, named ``gripper``. With a
    rollout's frame-0 vertices ``vertices0 (N, 3)`` m, each path is shifted to start on its grasped vertex
    (:func:`grasped_vertex`), as the backends shift it; else it is drawn as commanded."""
    tracks = []
    for h in getattr(scenario, "handles", None) or []:
        if h.path is None:
            continue
        path = np.asarray(h.path, float)
        i = None if vertices0 is None else grasped_vertex(h.grasp, vertices0, rope)
        tracks.append((h.name, path if i is None else path + (vertices0[i] - path[0])))
    return tracks or [("gripper", np.asarray(scenario.gripper, float))]


def pinned_vertices(scenario: Any, vertices0: np.ndarray, rope: bool) -> list[tuple[str, int]]:
    """``[(name, vertex index)]`` of the pinned handles of ``scenario`` in a rollout whose frame-0 vertices are
    ``vertices0 (N, 3)`` m (:func:`grasped_vertex`; a grasp it does not locate is left out)."""
    out = []
    for h in getattr(scenario, "handles", None) or []:
        i = None if h.path is not None else grasped_vertex(h.grasp, vertices0, rope)
        if i is not None:
            out.append((h.name, i))
    return out


def grasped_vertex(grasp: Mapping[str, Any], vertices0: np.ndarray, rope: bool) -> int | None:
    """The vertex a handle's ``grasp`` holds in a rollout with frame-0 vertices ``vertices0 (N, 3)`` m: a mesh
    ``vertex``, a rope ``end``, the vertex nearest a ``point``, a ``corner`` of a square grid
    (:func:`~softsbi.backends.common.grid_corners`); None when the rollout does not show which."""
    from softsbi.backends.common import grid_corners
    N = len(vertices0)
    n = int(round(N ** 0.5))
    kind, v = next(iter(grasp.items()))
    if kind == "vertex":
        i = int(v)
    elif kind == "end" and rope:
        i = 0 if int(v) == 0 else N - 1
    elif kind == "point":
        i = int(np.argmin(np.linalg.norm(vertices0 - np.asarray(v, float), axis=1)))
    elif kind == "corner" and not rope and n * n == N:
        i = grid_corners(n)[int(v)]
    else:
        return None
    return i if 0 <= i < N else None


def grip_label(n: int) -> str:
    """Legend text of ``n`` moving handles."""
    return "gripper" if n == 1 else f"{n} grippers"


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _save(fig: Any, path: Path, dpi: int = DPI) -> Path:
    fig.savefig(path, dpi=dpi)
    _plt().close(fig)
    return Path(path)


def _unit(u: str) -> str:
    """Unit text for an axis label: ``N*m`` -> ``N·m``, ``kg/m^2`` -> ``kg/m²``, ``1`` -> ``-``."""
    if u in ("1", ""):
        return "-"
    return u.replace("*", "·").replace("^2", "²").replace("^3", "³")


def _source(s: Any) -> str:
    """Short name of a measurement source: the folder/file name of a path, else the text itself."""
    s = str(s or "")
    return Path(s).name if "/" in s or "\\" in s else s


def fit_label(report: dict[str, Any]) -> str:
    """What a fit fitted: ``"mujoco-flex + wind"`` or ``"mujoco-flex (nominal)"``."""
    eff = list(report.get("effects") or [])
    backend = report.get("backend", "?")
    return f"{backend} + {' + '.join(eff)}" if eff else f"{backend} (nominal)"


def _header(fig: Any, lines: Sequence[tuple[str, dict[str, Any]]], pad_px: float = 6.0) -> float:
    """Write ``lines`` (text, text properties) centred at the top of ``fig``, each wrapped so that it
    fits the figure's width; returns the fraction of the figure height they take (for
    ``tight_layout(rect=(0, 0, 1, 1 - frac))``)."""
    renderer = fig.canvas.get_renderer()
    W, H = fig.bbox.width, fig.bbox.height
    y = H - pad_px
    for text, props in lines:
        if not text:
            continue
        props = {"fontsize": FS_SUB, **props}
        t = fig.text(0.5, y / H, text, ha="center", va="top", **props)
        chars = max(20, int(0.98 * W / (0.62 * props["fontsize"] * fig.dpi / 72)))
        while True:
            t.set_text("\n".join(textwrap.fill(p, chars) for p in text.split("\n")))
            bb = t.get_window_extent(renderer)
            if bb.width <= 0.97 * W or chars <= 20:
                break
            chars = int(chars * 0.9)
        y = bb.y0 - 3.0
    return min(0.5, (H - y + pad_px) / H)


def _layout(fig: Any, top_frac: float = 0.0, bottom_frac: float = 0.0) -> None:
    fig.tight_layout(rect=(0, bottom_frac, 1, 1 - top_frac), pad=0.6)


# ----------------------------------------------------------------------------------------
# fit figures


def write_fit_plots(out_dir: Path, result: Any, meas: Any, cfg: Any, samples: np.ndarray,
                    observer_options: dict[str, Any] | None = None) -> list[Path]:
    """Write ``chamfer_rounds.png``, ``posterior_pairs.png`` and ``clouds.png`` (``frames.png`` for
    image fits) into ``out_dir``.

    Args:
        result: :class:`~softsbi.workflows.fit.FitResult`. meas: the measurement.
        samples: ``(S, D)`` final-posterior samples, physical units.
        observer_options: the fit's observer constructor options (image fits draw its keypoints).
    """
    rep = result.report
    subtitle = f"fit: {fit_label(rep)}; measurement: {_source(rep.get('observed'))}"
    paths = [plot_chamfer_rounds(out_dir / "chamfer_rounds.png", rep),
             plot_pairs(out_dir / "posterior_pairs.png", result.param_space, samples, meas.truth, subtitle=subtitle)]
    image_fit = rep.get("metric") == "mask_chamfer_px"
    name = "frames.png" if image_fit else "clouds.png"
    try:
        if image_fit:
            paths.append(plot_frames(out_dir / name, result, meas, cfg, observer_options=observer_options))
        else:
            paths.append(plot_clouds(out_dir / name, result, meas, cfg))
    except Exception as exc:  # noqa: BLE001 - a failed preview must not lose the fit
        (out_dir / name.replace(".png", "_error.txt")).write_text(f"could not draw {name}: {exc}\n")
    return paths


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
                         (f"measurement: {_source(report.get('observed'))}", {"fontsize": FS_SUB})])
    _layout(fig, frac)
    return fig


def plot_chamfer_rounds(path: Path, report: dict[str, Any]) -> Path:
    """Mean Chamfer of rollouts at prior samples (band), of each later round's rollouts (drawn from
    the proposal the previous round's posterior gives: that posterior for ``proposal="corrected"``,
    the truncated prior for ``"truncated"``, which is wider) and of the posterior predictive (the
    fit's ``n_eval`` rollouts at final-posterior samples, the reported number): 3-D Chamfer in cm,
    or for image fits the mask Chamfer in px. Titled with what was fitted (backend + effects) and,
    below, the measurement."""
    return _save(chamfer_rounds_figure(report), path)


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
        from matplotlib.ticker import MaxNLocator
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
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch, Rectangle
    from matplotlib.ticker import FixedFormatter, FixedLocator, NullLocator

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
    from softsbi.inference.contraction import INFORMED_MAX_RATIO, contraction
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
    return _save(pairs_figure(space, samples, truth, subtitle), path)


def clouds_figure(scenario: Any, dense: np.ndarray, sim_pts: np.ndarray | None, frames: Sequence[int],
                  title: str = "", status: str = "", vertices: np.ndarray | None = None, rope: bool = False,
                  best_pts: np.ndarray | None = None, best_label: str = "") -> Any:
    """Figure of :func:`plot_clouds`: ``dense (T, N, 3)`` measured, ``sim_pts (T, M, 3)`` simulated
    (None: the simulation failed), every handle of ``scenario``: its grippers ``+`` (where the simulated
    ``vertices (T, V, 3)`` hold them, when given) and the vertices it holds in place ``x``; ``best_pts (T, M, 3)``
    the best fit's rollout (None: not drawn) with its legend text ``best_label``."""
    plt = _plt()
    from matplotlib.ticker import MaxNLocator
    fig, axes = plt.subplots(2, len(frames), figsize=(3.1 * len(frames) + 0.6, 6.9), squeeze=False)
    mc, pc, gc = ROLE_COLOURS["measured"], ROLE_COLOURS["posterior"], ROLE_COLOURS["gripper"]
    views = [(1, 2, "side view", ("y [m]", "z [m]")), (0, 1, "top view", ("x [m]", "y [m]"))]
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
    from matplotlib.lines import Line2D
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


def best_fit_clouds(store: Any, report: Mapping[str, Any], n: int = 800) -> tuple[np.ndarray | None, str]:
    """The best fit's stored rollout (``report["best_fit"]``, the run store's ``best_fit`` group) as surface
    clouds ``(T, n, 3)`` m and its legend text; ``(None, "")`` when the run stored none."""
    from softsbi.core.types import Rollout
    from softsbi.perception.pointcloud import rollout_clouds
    best = report.get("best_fit") or {}
    if not best.get("rollout") or not store.has("best_fit"):
        return None, ""
    a, _ = store.read_group("best_fit")
    if "vertices" not in a:
        return None, ""
    ro = Rollout(times=np.arange(len(a["vertices"]), dtype=float), gripper=a["gripper"], vertices=a["vertices"],
                 faces=np.asarray(a["faces"], int))
    value = best.get("chamfer_m")
    what = f"best fit ({best['source']}{'' if value is None else f', Chamfer {value * 100:.2f} cm'})"
    return rollout_clouds(ro, n, np.random.default_rng(1)), what


def plot_clouds(path: Path, result: Any, meas: Any, cfg: Any, frames: tuple[int, ...] | None = None) -> Path:
    """Measured (grey) vs simulated at the posterior median (blue) clouds and the best fit's stored rollout
    (purple, :func:`best_fit_clouds`): side view and top view."""
    from softsbi.perception.pointcloud import rollout_clouds
    from softsbi.plugins import registry

    theta = dict(result.report["posterior_median"])
    theta.update(cfg.fixed)
    sim = registry().simulator(cfg.backend)(**cfg.backend_options)
    ro = sim.simulate(meas.scenario, theta, effects=cfg.effects, seed=0)
    T = meas.scenario.n_frames
    frames = frames or tuple(sorted({0, T // 3, 2 * T // 3, T - 1}))
    sim_pts = rollout_clouds(ro, 800, np.random.default_rng(0)) if ro.ok else None
    status = "" if ro.ok else f" (simulation failed: {ro.reason})"
    title = f"fit: {fit_label(result.report)}; measurement: {_source(result.report.get('observed'))}"
    best_pts, best_label = best_fit_clouds(result.store, result.report)
    return _save(clouds_figure(meas.scenario, meas.dense, sim_pts, frames, title, status,
                               ro.vertices if ro.ok else None, len(ro.faces) == 0, best_pts, best_label), path)


def plot_frames(path: Path, result: Any, meas: Any, cfg: Any, frames: tuple[int, ...] | None = None,
                observer_options: dict[str, Any] | None = None) -> Path:
    """Image fits: measured frames (top) and frames rendered at the posterior median (bottom), with
    the extractor's keypoints (cyan) and the HSV cloth-mask outline (yellow) of each."""
    from softsbi.perception.masks import hsv_mask
    from softsbi.plugins import registry

    plt = _plt()
    theta = dict(result.report["posterior_median"])
    theta.update(cfg.fixed)
    obs = registry().observer(cfg.observer)(**dict(observer_options or {}))
    sim = registry().simulator(cfg.backend)(**cfg.backend_options)
    ro = sim.simulate_images(meas.scenario, theta, camera=obs.camera, style=obs.style, effects=cfg.effects, seed=0)
    T = meas.scenario.n_frames
    frames = frames or tuple(sorted({0, T // 3, 2 * T // 3, T - 1}))
    rows = [("measured", meas.images)] + ([("posterior median", ro.rgb)] if ro.ok else [])
    fig, axes = plt.subplots(len(rows), len(frames), figsize=(2.8 * len(frames), 3.0 * len(rows) + 0.6),
                             squeeze=False)
    for r, (label, imgs) in enumerate(rows):
        kp = obs.observe_images(imgs, meas.scenario.gripper, meas.scenario.times).points
        m = hsv_mask(imgs)
        for c, f in enumerate(frames):
            ax = axes[r, c]
            ax.imshow(imgs[f])
            if m[f].any():
                ax.contour(m[f], levels=[0.5], colors="yellow", linewidths=0.7)
            ax.scatter(kp[f, :, 0], kp[f, :, 1], s=16, c="cyan", edgecolors="k", linewidths=0.5)
            ax.set_title(f"{label}, frame {f}", fontsize=FS_SUB)
            ax.axis("off")
    status = "" if ro.ok else f" (posterior simulation failed: {ro.reason})"
    rep = result.report
    score = (f"mask Chamfer prior {rep['mask_chamfer_prior_px']:.2f} px → posterior "
             f"{rep['mask_chamfer_posterior_px']:.3f} px" if rep.get("mask_chamfer_posterior_px") is not None else "")
    frac = _header(fig, [(f"Measured vs rendered at the posterior median{status}", {"fontsize": FS_TITLE,
                                                                                     "weight": "bold"}),
                         (f"fit: {fit_label(rep)}, {meas.scenario.name}; {cfg.observer} keypoints (cyan), "
                          f"HSV cloth mask (yellow)" + (f"; {score}" if score else ""), {"fontsize": FS_SUB})])
    _layout(fig, frac)
    return _save(fig, path)


# ----------------------------------------------------------------------------------------
# check and compare


def short_p(test: JointTest) -> str:
    """A joint test's Monte-Carlo p-value with its resolution, short: ``p ≤ 2/201`` or ``p = 0.4 (30 sims)``."""
    n = test.n_null
    if test.p_value <= test.resolution:
        return f"p ≤ {test.tests}/{n + 1}"
    return f"p = {test.p_value:.2g} ({n} sims)"


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
    return name.replace(" (at the grasp)", " grasp").replace(" (farthest from the grasp)", " farthest")


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
    cmap = plt.get_cmap("magma").copy()
    cmap.set_bad("0.75")  # regions the fit's sensor model never sees: grey, not a perfect match
    fitted = np.zeros(len(reg), bool)
    fitted[list(out.metric_frames) if out.metric_frames is not None else slice(None)] = True
    # the colour scale follows the fitted frames (frames outside them, e.g. a real recording's cloth on the
    # table, can be ten times worse and would leave the fitted part black)
    vals = reg[fitted][compared[fitted]]
    vmax = float(np.max(vals)) if vals.size else None
    im = ax.imshow(np.ma.masked_where(~compared, reg).T, aspect="auto", origin="lower", cmap=cmap, vmin=0,
                   vmax=vmax, extent=[t[0] - dt, t[-1] + dt, 0.5, reg.shape[1] + 0.5])
    for ph in phases[1:]:
        ax.axvline(ph.t_s[0] - dt, color="white", lw=1, ls="--", alpha=0.8)
    ax.set_yticks(range(1, reg.shape[1] + 1))
    ax.set_yticklabels([_region_short(n) for n in out.regions], fontsize=FS_TICK)
    ax.set_xlabel("time [s]", fontsize=FS_LABEL)
    ax.set_ylabel(f"region of the object (R1 nearest {regions_from(out)})", fontsize=FS_LABEL)
    ax.tick_params(labelsize=FS_TICK)
    ax.set_title("Error per region of the cloth (dashed: phase boundaries"
                 + ("; grey: not seen by the sensor model)" if not compared.all() else ")"), fontsize=FS_SUB)
    cb = fig.colorbar(im, ax=ax, fraction=0.046)
    cb.set_label("mean error [cm]" + (" (scale: fitted frames)" if not fitted.all() else ""), fontsize=FS_LABEL)
    cb.ax.tick_params(labelsize=FS_TICK)
    frac = _header(fig, [(check_headline(out), {"fontsize": FS_TITLE, "weight": "bold"}),
                         (f"Posterior predictive check of {_source(out.run)}: {out.n_rollouts} "
                          f"rollouts at posterior samples" + (f"; worst region {out.worst_regions[0]}"
                                                              if out.worst_regions else ""),
                          {"fontsize": FS_SUB})])
    _layout(fig, frac)
    return fig


def plot_check(path: Path, out: CheckResult) -> Path:
    """Chamfer per frame with its posterior band and phases, and heatmap (frame x region); the
    headline gives the verdict (mean error, worst phase, misspecification p-value)."""
    return _save(check_figure(out), path)


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
    ax.set_xlabel("region of the cloth (R1 at the grasp ... farthest)", fontsize=FS_LABEL)
    ax.set_ylabel("mean error [cm]", fontsize=FS_LABEL)
    ax.legend(fontsize=FS_LEGEND, loc="best")
    ax.grid(alpha=0.3, axis="y")
    ax.set_title("Error per region of the cloth", fontsize=FS_SUB)
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
    return _save(compare_figure(res), path)


def plot_compare_backends(scenario: Any, rollouts: Mapping[str, Any], report: Mapping[str, Any],
                          path: str | Path) -> Path:
    """Side-by-side PNG: the scenario's view (:attr:`~softsbi.core.types.Scenario.view`: a side view x-z or
    y-z, or the top view x-y) of 4 frames with every backend overlaid, and the per-frame Chamfer on the right.

    Colours: each engine one of :data:`softsbi.report.ENGINE_COLOURS` in backend order (first:
    sky blue, second: reddish purple), none of them a role colour of the fit figures; the gripper
    in its role colour (black ``+``). Matplotlib Agg, no display needed."""
    plt = _plt()
    from matplotlib.lines import Line2D
    from matplotlib.ticker import MaxNLocator

    T = scenario.n_frames
    frames = sorted({0, T // 3, 2 * T // 3, T - 1})
    i, j = ("xyz".index(a) for a in scenario.view)  # the plane the scenario file declares (view:)
    view = "top view" if scenario.view == "xy" else "side view"
    names = list(rollouts)
    colours = {b: ENGINE_COLOURS[k % len(ENGINE_COLOURS)] for k, b in enumerate(names)}
    fig, axes = plt.subplots(1, len(frames) + 1, figsize=(3.0 * len(frames) + 3.6, 4.3),
                             gridspec_kw={"width_ratios": [1] * len(frames) + [1.15]})
    for ax, f in zip(axes, frames):
        for b, ro in rollouts.items():
            if ro.vertices is None or len(ro.vertices) <= f:
                continue
            v = ro.vertices[f]
            ax.scatter(v[:, i], v[:, j], s=10, color=colours[b], alpha=0.75, linewidths=0)
        g = scenario.gripper[f]
        ax.plot(g[i], g[j], "+", color="white", ms=13, mew=4, zorder=4)
        ax.plot(g[i], g[j], "+", color=ROLE_COLOURS["gripper"], ms=12, mew=2, zorder=5)
        ax.set_title(f"t = {scenario.times[f]:.2f} s", fontsize=FS_SUB)
        ax.set_xlabel("xyz"[i] + " [m]", fontsize=FS_LABEL)
        ax.set_ylabel(f"{view}: " + "xyz"[j] + " [m]" if ax is axes[0] else "xyz"[j] + " [m]", fontsize=FS_LABEL)
        ax.tick_params(labelsize=FS_TICK)
        ax.xaxis.set_major_locator(MaxNLocator(3))
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.25)
    ax = axes[-1]
    pairs = [(k, ch) for k, ch in report["chamfer_m"].items() if ch is not None]
    for key, ch in pairs:
        other = key.split("|", 1)[1]
        ax.plot(scenario.times, np.asarray(ch) * 100, lw=2, marker="o", ms=3,
                color="0.2" if len(pairs) == 1 else colours.get(other, "0.2"), label=key.replace("|", " vs "))
    ax.set_xlabel("time [s]", fontsize=FS_LABEL)
    ax.set_ylabel("Chamfer between engines [cm]", fontsize=FS_LABEL)
    ax.tick_params(labelsize=FS_TICK)
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.set_title("per-frame Chamfer", fontsize=FS_SUB)
    if pairs:
        ax.legend(fontsize=FS_LEGEND, loc="upper left")
    else:
        ax.text(0.5, 0.5, "no Chamfer:\na rollout failed", ha="center", va="center", transform=ax.transAxes,
                fontsize=FS_LABEL)
    handles = [Line2D([], [], ls="none", marker="o", ms=6, color=colours[b],
                      label=b + ("" if rollouts[b].ok else f" (failed: {report['backends'][b]['reason']})"))
               for b in names]
    handles.append(Line2D([], [], ls="none", marker="+", ms=10, mew=2, color=ROLE_COLOURS["gripper"], label="gripper"))
    means = [f"{k.replace('|', ' vs ')} {v * 100:.2f} cm" for k, v in report["mean_chamfer_m"].items() if v is not None]
    frac = _header(fig, [(f"{scenario.name}: {' vs '.join(names)} at the same parameters", {"fontsize": FS_TITLE,
                                                                                             "weight": "bold"}),
                         ("mean Chamfer " + "; ".join(means) if means else "", {"fontsize": FS_SUB})])
    leg_h = 0.45 / fig.get_figheight()
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=FS_LEGEND + 1, frameon=False,
               bbox_to_anchor=(0.5, 0.0))
    fig.tight_layout(rect=(0, leg_h, 1, 1 - frac), pad=0.6)
    path = Path(path)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def plot_rollout_preview(ro: Any, path: str | Path, title: str, scenario: Any = None) -> Path:
    """The rest pose from above (x-y, m) with a grid cloth's corners 0-3 (``ro.info["corners"]``) and every
    handle labelled by name, then side views (y-z, m) of a rollout's vertices at four frames, with every handle of
    ``scenario`` (its grippers ``+`` and the vertices it holds in place ``x``; without a scenario the rollout's
    gripper), in the palette's posterior and gripper colours (``softsbi simulate``'s ``preview.png``)."""
    return _save(rollout_preview_figure(ro, title, scenario), Path(path))


def rollout_preview_figure(ro: Any, title: str, scenario: Any = None) -> Any:
    """Figure of :func:`plot_rollout_preview`."""
    plt = _plt()
    T = len(ro.times)
    frames = sorted({0, T // 3, 2 * T // 3, T - 1})
    rope = len(ro.faces) == 0
    tracks = (handle_tracks(scenario, ro.vertices[0], rope) if scenario is not None
              else [("gripper", np.asarray(ro.gripper, float))])
    pinned = pinned_vertices(scenario, ro.vertices[0], rope) if scenario is not None else []
    fig, axes = plt.subplots(1, len(frames) + 1, figsize=(3 * len(frames) + 4, 3.4), squeeze=False,
                             gridspec_kw={"width_ratios": [4 / 3] + [1] * len(frames)})
    _rest_from_above(axes[0, 0], ro, tracks, pinned)
    for ax, f in zip(axes[0, 1:], frames):
        v = ro.vertices[f]
        ax.scatter(v[:, 1], v[:, 2], s=4, color=ROLE_COLOURS["posterior"], label="simulated vertices")
        for k, (_, p) in enumerate(tracks):
            ax.plot(p[f, 1], p[f, 2], "+", color=ROLE_COLOURS["gripper"], ms=10, mew=2,
                    label=grip_label(len(tracks)) if k == 0 else None)
        for k, (_, i) in enumerate(pinned):
            ax.plot(v[i, 1], v[i, 2], "x", color=ROLE_COLOURS["gripper"], ms=8, mew=2,
                    label="held in place" if k == 0 else None)
        ax.set_title(f"t = {ro.times[f]:.2f} s (side view)", fontsize=FS_SUB)
        ax.set_xlabel("y [m]", fontsize=FS_LABEL)
        ax.set_ylabel("z [m]", fontsize=FS_LABEL)
        ax.tick_params(labelsize=FS_TICK)
        ax.set_aspect("equal", adjustable="datalim")
    axes[0, 1].legend(fontsize=FS_LEGEND, loc="upper left")
    fig.suptitle(title, fontsize=FS_TITLE)
    fig.tight_layout()
    return fig


#: room around the cloth in the preview's view from above, for the corner and handle labels (fraction of its size)
PREVIEW_LABEL_ROOM = 0.45


def _rest_from_above(ax: Any, ro: Any, tracks: list[tuple[str, np.ndarray]], pinned: list[tuple[str, int]]) -> None:
    """The first frame's vertices from above (x-y), each corner (``corner k``) and handle (its name) labelled
    beside its vertex, away from the cloth's centre: where a scenario file's corners and handles end up."""
    v = np.asarray(ro.vertices[0], float)
    ax.scatter(v[:, 0], v[:, 1], s=4, color=ROLE_COLOURS["posterior"])
    names: dict[int, list[str]] = {}
    for k, i in enumerate((getattr(ro, "info", None) or {}).get("corners") or []):
        names.setdefault(int(i), []).append(f"corner {k}")
        ax.plot(v[i, 0], v[i, 1], "o", mfc="none", color="0.25", ms=7, mew=1.2)
    for name, p in tracks:
        i = int(np.argmin(np.linalg.norm(v - p[0], axis=1)))
        names.setdefault(i, []).append(name)
        ax.plot(p[0, 0], p[0, 1], "+", color=ROLE_COLOURS["gripper"], ms=10, mew=2)
    for name, i in pinned:
        names.setdefault(int(i), []).append(name)
        ax.plot(v[i, 0], v[i, 1], "x", color=ROLE_COLOURS["gripper"], ms=8, mew=2)
    centre = v[:, :2].mean(0)
    for i, labels in names.items():
        d = v[i, :2] - centre
        d = d / (np.linalg.norm(d) or 1.0)
        ax.annotate(", ".join(labels), v[i, :2], xytext=tuple(10 * d), textcoords="offset points",
                    fontsize=FS_TICK, ha="left" if d[0] >= 0 else "right", va="bottom" if d[1] >= 0 else "top")
    ax.set_title("rest pose from above", fontsize=FS_SUB)
    ax.set_xlabel("x [m]", fontsize=FS_LABEL)
    ax.set_ylabel("y [m]", fontsize=FS_LABEL)
    ax.tick_params(labelsize=FS_TICK)
    lo, hi = v[:, :2].min(0), v[:, :2].max(0)
    half = 0.5 * float(max(hi - lo)) * (1 + 2 * PREVIEW_LABEL_ROOM)  # a square view, room for the labels
    mid = (lo + hi) / 2
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_aspect("equal", adjustable="box")


def plot_scenario_overlay(scenario: Any, rollout: Any, real_points: np.ndarray, path: str | Path,
                          frame: int = 0, title: str | None = None) -> Path:
    """Top and side view (m) of a measured frame against the simulated cloth and the gripper path,
    in the palette's measured and posterior colours (``examples/lift_overlay.py``).

    Args:
        scenario: the lift scenario (lift frame, m).
        rollout: a :class:`~softsbi.core.types.Rollout` (its ``vertices[frame]`` are drawn), or None.
        real_points: ``(P, 3)`` m, the measured cloud of the same frame in the lift frame.
        path: output PNG file (its folder is created).
        frame: which frame to draw. title: optional figure title.

    Raises:
        ShapeError: ``real_points`` is not ``(P, 3)``.
    """
    from softsbi.core.errors import ShapeError

    real = np.asarray(real_points, dtype=float)
    if real.ndim != 2 or real.shape[1] != 3:
        raise ShapeError(f"real_points must be (P, 3), got {real.shape}")
    plt = _plt()
    g = scenario.gripper
    fig, axes = plt.subplots(1, 2, figsize=(12, 5.5))
    for ax, (i, j), lab in ((axes[0], (0, 1), ("x [m]", "y [m]")), (axes[1], (1, 2), ("y [m]", "z [m]"))):
        ax.scatter(real[:, i], real[:, j], s=2, color=ROLE_COLOURS["measured"], alpha=0.5,
                   label=f"measured frame {frame}")
        if rollout is not None:
            v = np.asarray(rollout.vertices[frame])
            ax.scatter(v[:, i], v[:, j], s=10, color=ROLE_COLOURS["posterior"], label=f"simulated frame {frame}")
        ax.plot(g[:, i], g[:, j], "-", color=ROLE_COLOURS["gripper"], lw=1, label="gripper path")
        ax.plot(g[frame, i], g[frame, j], "+", color=ROLE_COLOURS["gripper"], ms=10, mew=2)
        if j == 2:
            ax.axhline(scenario.table_z, color=ROLE_COLOURS["prior"], ls="--", lw=1, label="table")
        ax.set_xlabel(lab[0], fontsize=FS_LABEL)
        ax.set_ylabel(lab[1], fontsize=FS_LABEL)
        ax.set_aspect("equal")
        ax.grid(alpha=0.3)
    axes[0].set_title("top view", fontsize=FS_SUB)
    axes[1].set_title("side view", fontsize=FS_SUB)
    axes[1].legend(loc="upper right", fontsize=FS_LEGEND)
    fig.suptitle(title or f"{scenario.options.get('recording', scenario.name)}: frame {frame}", fontsize=FS_TITLE)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return _save(fig, path)
