"""The animation and the rerun recording of ``softsbi view``: measured clouds against
posterior-predictive rollouts over time (the simulation is :mod:`softsbi.workflows.view`'s).

``view`` arguments are duck-typed run views (``path``, ``config``, ``effects``, ``scenario``
with ``times (T,)``, ``gripper (T, 3)`` m and ``table_z``, ``dense (T, P, 3)`` m).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from softsbi.core.errors import DependencyMissing
from softsbi.report.style import ROLE_COLOURS, _plt, grip_label, view_planes
from softsbi.scenarios.handles import handle_tracks, pinned_vertices

#: colours of the roles: the palette of every figure (:data:`softsbi.report.style.ROLE_COLOURS`)
COLOR_MEASURED = ROLE_COLOURS["measured"]
COLOR_POSTERIOR = ROLE_COLOURS["posterior"]
COLOR_GRIPPER = ROLE_COLOURS["gripper"]
COLOR_BEST = ROLE_COLOURS["best_fit"]
#: opacity of each posterior rollout in the GIF
ROLLOUT_ALPHA = 0.25

def _run_label(view: Any) -> str:
    name = Path(view.path).resolve().name
    src = view.record.observed_source
    src = Path(src).name if src and not src.startswith("simulated:") else src
    eff = " + " + "+".join(view.effects) if view.effects else ""
    return f"run '{name}' ({view.config.backend}{eff}" + (f"; measurement {src})" if src else ")")


def _edges(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Mesh edges ``(boundary (B, 2), interior (E, 2))``: boundary edges belong to one face only.
    For a rope (no faces) the consecutive vertices form the "boundary" and there is no interior."""
    if len(faces) == 0:
        return np.stack([np.arange(n_vertices - 1), np.arange(1, n_vertices)], 1), np.zeros((0, 2), int)
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), 1)
    uniq, count = np.unique(e, axis=0, return_counts=True)
    return uniq[count == 1], uniq[count > 1]


def _limits(arrays: list[np.ndarray], margin: float = 0.06) -> np.ndarray:
    """``(3, 2)`` axis limits (m) covering every point of ``arrays`` (each ``(..., 3)``)."""
    pts = np.concatenate([np.asarray(a, float).reshape(-1, 3) for a in arrays])
    pts = pts[np.isfinite(pts).all(1)]
    lo, hi = pts.min(0), pts.max(0)
    pad = margin * max(float((hi - lo).max()), 1e-3)
    return np.stack([lo - pad, hi + pad], 1)


# ----------------------------------------------------------------------------------------
# GIF


def draw_gif(view: Any, rollouts: list[Any], ch: np.ndarray, path: Path, fps: float,
              dpi: int = 90, best: dict[str, Any] | None = None) -> Path:
    """The GIF of ``softsbi view`` (:func:`softsbi.workflows.view.write_animation`); ``rollouts``: the posterior
    rollouts (job results with ``vertices (T, N, 3)`` m and ``faces (F, 3)``, ``F = 0`` for a rope); ``view``: the
    run (``path``, ``config.backend``, ``record.observed_source``, ``effects``, ``scenario``, ``dense``);
    ``best``: the fit's best fit
    (``vertices (T, N, 3)`` m, ``faces``, ``chamfer (T,)`` m, ``label``), drawn in its own colour, or None."""
    from matplotlib.animation import PillowWriter  # heavy: loaded on the first figure only
    from matplotlib.collections import LineCollection  # heavy: loaded on the first figure only
    from matplotlib.lines import Line2D  # heavy: loaded on the first figure only


    plt = _plt()
    dense = view.dense
    sc = view.scenario
    times = sc.times
    T = len(dense)
    v0, rope = rollouts[0].vertices[0], len(rollouts[0].faces) == 0  # where the first rollout's handles hold
    grips = [p for _, p in handle_tracks(sc, v0, rope)]
    pinned = pinned_vertices(sc, v0, rope)
    lim = _limits([dense, *grips] + [r.vertices for r in rollouts] + ([best["vertices"]] if best else []))
    lim[2, 0] = min(lim[2, 0], sc.table_z - 0.01)
    best_edges = _edges(np.asarray(best["faces"], int), best["vertices"].shape[1])[0] if best else None
    views = [((a, b), f"{name} ({'xyz'[a]}-{'xyz'[b]})") for a, b, name in view_planes(getattr(sc, "view", "yz"))]
    ratios = panel_ratios([(lim[a, 1] - lim[a, 0]) / (lim[b, 1] - lim[b, 0]) for (a, b), _ in views])

    fig = plt.figure(figsize=(11, 6.8))
    gs = fig.add_gridspec(2, 2, width_ratios=ratios, height_ratios=[3.2, 1], hspace=0.42, wspace=0.22,
                          left=0.07, right=0.98, top=0.83, bottom=0.09)
    axes = [fig.add_subplot(gs[0, 0]), fig.add_subplot(gs[0, 1])]
    ax_err = fig.add_subplot(gs[1, :])
    names = "xyz"
    edges = [_edges(r.faces, r.vertices.shape[1]) for r in rollouts]
    meas_art, roll_art, grip_art = [], [], []
    for ax, ((a, b), title) in zip(axes, views):
        ax.set_xlim(*lim[a])
        ax.set_ylim(*lim[b])
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel(f"{names[a]} [m]")
        ax.set_ylabel(f"{names[b]} [m]")
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.25)
        ax.tick_params(labelsize=8)
        if b == 2:
            ax.axhline(sc.table_z, color="0.6", lw=1, ls="--", zorder=0)
            ax.text(lim[a, 0], sc.table_z, " table", ha="left", va="top", fontsize=7, color="0.45")
        for grip in grips:
            ax.plot(grip[:, a], grip[:, b], color=COLOR_GRIPPER, lw=1.2, ls="--", alpha=0.5, zorder=1)
        lcs = []
        for _ in rollouts:  # outline clearly, inner mesh edges faintly
            outer = LineCollection([], colors=COLOR_POSTERIOR, alpha=ROLLOUT_ALPHA * 2, linewidths=1.3, zorder=2)
            inner = LineCollection([], colors=COLOR_POSTERIOR, alpha=ROLLOUT_ALPHA * 0.6, linewidths=0.6, zorder=2)
            ax.add_collection(outer)
            ax.add_collection(inner)
            lcs.append((outer, inner))
        if best is not None:  # the best fit's outline, over the posterior rollouts
            lcs.append((ax.add_collection(LineCollection([], colors=COLOR_BEST, alpha=0.9, linewidths=1.6,
                                                         zorder=2.5)), None))
        m = ax.scatter(dense[0][:, a], dense[0][:, b], s=4, color=COLOR_MEASURED, alpha=0.6, lw=0, zorder=3)
        g, = ax.plot(*_handle_xy(grips, pinned, rollouts, 0, a, b)[0], "+", color=COLOR_GRIPPER, ms=14, mew=2.5,
                     ls="none", zorder=5)
        h, = ax.plot(*_handle_xy(grips, pinned, rollouts, 0, a, b)[1], "x", color=COLOR_GRIPPER, ms=10, mew=2.5,
                     ls="none", zorder=5)
        meas_art.append(m)
        roll_art.append(lcs)
        grip_art.append((g, h))

    cm = ch * 100
    mean_cm = cm.mean(0)
    for row in cm:
        ax_err.plot(times, row, color=COLOR_POSTERIOR, alpha=ROLLOUT_ALPHA, lw=1)
    ax_err.plot(times, mean_cm, color=COLOR_POSTERIOR, lw=2)
    if best is not None:
        ax_err.plot(times, np.asarray(best["chamfer"]) * 100, color=COLOR_BEST, lw=1.6)
    vline = ax_err.axvline(times[0], color="0.3", lw=1, ls=":")
    dot, = ax_err.plot([times[0]], [mean_cm[0]], "o", color=COLOR_POSTERIOR, mec="k", ms=7, zorder=5)
    pad = 0.015 * (times[-1] - times[0]) if T > 1 else 0.5
    ax_err.set_xlim(times[0] - pad, times[-1] + pad)
    ax_err.set_ylim(0, max(float(np.nanmax(np.concatenate([cm.ravel()] + ([np.asarray(best["chamfer"]) * 100]
                                                                          if best else [])))) * 1.12, 0.1))
    ax_err.set_xlabel("time [s]")
    ax_err.set_ylabel("Chamfer [cm]")
    ax_err.set_title(f"Chamfer distance of the posterior rollouts to the measured cloud (thin: each rollout, "
                     f"thick: mean; over all frames {mean_cm.mean():.2f} cm)", fontsize=9)
    ax_err.grid(alpha=0.3)
    ax_err.tick_params(labelsize=8)

    handles = [Line2D([], [], ls="", marker="o", ms=5, color=COLOR_MEASURED, label="measured cloud"),
               Line2D([], [], color=COLOR_POSTERIOR, alpha=ROLLOUT_ALPHA * 2, lw=1.5,
                      label=f"{len(rollouts)} posterior-predictive rollouts (outline + mesh)"),
               Line2D([], [], ls="--", marker="+", ms=12, mew=2.5, color=COLOR_GRIPPER,
                      label=f"{grip_label(len(grips))} and {'its path' if len(grips) == 1 else 'their paths'}")]
    if pinned:
        handles.append(Line2D([], [], ls="none", marker="x", ms=9, mew=2.5, color=COLOR_GRIPPER,
                              label="held in place (first rollout)"))
    if best is not None:
        handles.insert(2, Line2D([], [], color=COLOR_BEST, lw=1.6, label=best["label"]))
    fig.legend(handles=handles, loc="upper center", ncol=len(handles), fontsize=9 if best is None else 8,
               frameon=False, bbox_to_anchor=(0.5, 0.915))
    label = _run_label(view)
    title = fig.suptitle("", fontsize=11, y=0.985)

    def update(k: int):
        for ax_i, ((a, b), _) in enumerate(views):
            meas_art[ax_i].set_offsets(dense[k][:, [a, b]])
            for (outer, inner), r, (e_out, e_in) in zip(roll_art[ax_i], rollouts, edges):
                v = r.vertices[k][:, [a, b]]
                outer.set_segments(v[e_out])
                inner.set_segments(v[e_in])
            if best is not None:
                roll_art[ax_i][-1][0].set_segments(best["vertices"][k][:, [a, b]][best_edges])
            moving, held = _handle_xy(grips, pinned, rollouts, k, a, b)
            grip_art[ax_i][0].set_data(*moving)
            grip_art[ax_i][1].set_data(*held)
        vline.set_xdata([times[k], times[k]])
        dot.set_data([times[k]], [mean_cm[k]])
        title.set_text(f"{label}\nframe {k} (of 0-{T - 1}),  t = {times[k]:.2f} s,  "
                       f"Chamfer {mean_cm[k]:.2f} cm (mean of {len(rollouts)} rollouts)")

    # the writer driven directly (not FuncAnimation.save, which draws every frame twice)
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = PillowWriter(fps=fps)
    try:
        with writer.saving(fig, str(path), dpi):
            for k in range(T):
                update(k)
                writer.grab_frame()
    finally:
        plt.close(fig)
    return path


#: the second panel of the GIF is at least this share of the first's width, however flat the first's data (a side
#: view of a cloth dragged along the table is a thin strip: the top view beside it must not be a thumbnail)
MIN_SECOND_PANEL = 0.5


def panel_ratios(aspects: list[float]) -> list[float]:
    """The widths of the GIF's two panels of one height, from the width / height of their data (``aspects``: the
    scenario's view first): in proportion to them for equal aspect, floored at 0.4, the second panel kept between
    :data:`MIN_SECOND_PANEL` of the first's width and the first's width (the scenario's view is never the smaller
    one)."""
    first = max(aspects[0], 0.4)
    return [first, min(max(aspects[1], 0.4, MIN_SECOND_PANEL * first), first)]


def _handle_xy(grips: list[np.ndarray], pinned: list[tuple[str, int]], rollouts: list[Any], k: int,
               a: int, b: int) -> tuple[tuple[list[float], list[float]], tuple[list[float], list[float]]]:
    """Frame ``k``'s handle positions on axes ``a``, ``b``: the grippers ``(xs, ys)`` and the vertices held in
    place (in the first rollout) ``(xs, ys)``."""
    held = [rollouts[0].vertices[k][i] for _, i in pinned]
    return ([float(g[k, a]) for g in grips], [float(g[k, b]) for g in grips]), \
        ([float(p[a]) for p in held], [float(p[b]) for p in held])


def import_rerun():
    try:
        import rerun as rr  # optional dependency (softsbi[rerun])
    except ImportError as exc:
        raise DependencyMissing(f"writing a rerun recording (.rrd) needs the rerun SDK, which is not installed "
                                f"({exc}); install it with: pip install \"softsbi[view]\" (or pip install "
                                f"rerun-sdk)") from exc
    return rr


def _rgba(spec: str, alpha: float = 1.0) -> list[int]:
    from matplotlib.colors import to_rgba  # heavy: loaded on the first figure only
    r, g, b, _ = to_rgba(spec)
    return [round(255 * c) for c in (r, g, b, alpha)]


def _vertex_normals(v: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals ``(N, 3)`` of one mesh frame ``v (N, 3)``."""
    fn = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, faces[:, k], fn)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(norm > 0, n / np.maximum(norm, 1e-12), np.array([0.0, 0.0, 1.0]))


def log_rrd(rr: Any, view: Any, rollouts: list[Any], ch: np.ndarray, path: Path,
            best: dict[str, Any] | None = None) -> Path:
    """The rerun recording of ``softsbi view`` (:func:`softsbi.workflows.view.write_rerun`); ``best`` as in
    :func:`draw_gif`: logged as ``world/best_fit`` and ``error/best_fit_cm``."""
    import rerun.blueprint as rrb  # optional dependency (softsbi[rerun])

    sc = view.scenario
    dense = view.dense
    T = len(dense)
    mean_cm = ch.mean(0) * 100
    lim = _limits([dense, sc.gripper] + [r.vertices for r in rollouts])
    path.parent.mkdir(parents=True, exist_ok=True)
    blueprint = rrb.Blueprint(
        rrb.Vertical(rrb.Spatial3DView(origin="/world", name="measured vs posterior rollouts"),
                     rrb.TimeSeriesView(origin="/error", name="Chamfer to the measurement [cm]"),
                     row_shares=[3, 1]),
        collapse_panels=True)
    rec = rr.RecordingStream("softsbi_view")
    rec.set_log_time_enabled(False)
    rec.save(str(path), default_blueprint=blueprint)
    try:
        rec.send_recording_name(_run_label(view))
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        centre = [(lim[0, 0] + lim[0, 1]) / 2, (lim[1, 0] + lim[1, 1]) / 2, sc.table_z]
        half = [(lim[0, 1] - lim[0, 0]) / 2, (lim[1, 1] - lim[1, 0]) / 2, 0.0]
        rec.log("world/table", rr.Boxes3D(centers=[centre], half_sizes=[half], colors=[[160, 160, 160]]), static=True)
        rec.log("world/gripper_path", rr.LineStrips3D([sc.gripper], colors=[_rgba(COLOR_GRIPPER, 0.5)],
                                                      radii=0.001), static=True)
        rec.log("error/chamfer_cm", rr.SeriesLines(colors=[_rgba(COLOR_POSTERIOR)[:3]],
                                                   names=["mean Chamfer of posterior rollouts [cm]"]), static=True)
        if best is not None:
            rec.log("error/best_fit_cm", rr.SeriesLines(colors=[_rgba(COLOR_BEST)[:3]], names=[best["label"]]),
                    static=True)
        for i, r in enumerate(rollouts):
            rec.log(f"error/rollouts/{i}", rr.SeriesLines(colors=[_rgba(COLOR_POSTERIOR)[:3]], widths=0.5,
                                                          names=[f"rollout {i} (posterior sample {r.sample})"]),
                    static=True)
        meas_col = _rgba(COLOR_MEASURED)
        post_col = _rgba(COLOR_POSTERIOR, 0.5)
        for k in range(T):
            rec.set_time("time", duration=float(sc.times[k]))
            rec.log("world/measured", rr.Points3D(dense[k], colors=[meas_col], radii=0.002))
            rec.log("world/gripper", rr.Points3D([sc.gripper[k]], colors=[_rgba(COLOR_GRIPPER)], radii=0.008))
            for i, r in enumerate(rollouts):
                v = r.vertices[k]
                if len(r.faces):
                    rec.log(f"world/posterior/{i}",
                            rr.Mesh3D(vertex_positions=v, triangle_indices=r.faces,
                                      vertex_normals=_vertex_normals(v, r.faces), albedo_factor=post_col))
                else:  # a rope: its centre line
                    rec.log(f"world/posterior/{i}", rr.LineStrips3D([v], colors=[post_col], radii=0.003))
                rec.log(f"error/rollouts/{i}", rr.Scalars(float(ch[i, k] * 100)))
            rec.log("error/chamfer_cm", rr.Scalars(float(mean_cm[k])))
            if best is not None:
                v, faces = best["vertices"][k], np.asarray(best["faces"], int)
                rec.log("world/best_fit", rr.Mesh3D(vertex_positions=v, triangle_indices=faces,
                                                    vertex_normals=_vertex_normals(v, faces),
                                                    albedo_factor=_rgba(COLOR_BEST, 0.8)) if len(faces) else
                        rr.LineStrips3D([v], colors=[_rgba(COLOR_BEST)], radii=0.003))
                if np.isfinite(best["chamfer"][k]):
                    rec.log("error/best_fit_cm", rr.Scalars(float(best["chamfer"][k] * 100)))
        rec.flush()
    finally:
        rec.disconnect()  # closes the file and writes its footer
    return path


