"""The figures of the engines and scenarios themselves: ``compare-backends`` (engines side by side at the same
parameters), ``simulate``'s preview of one rollout and a measured frame over a scenario (``examples/lift_overlay.py``).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from softsbi.core.errors import ShapeError
from softsbi.report.style import (DPI, ENGINE_COLOURS, FS_LABEL, FS_LEGEND, FS_SUB, FS_TICK, FS_TITLE, ROLE_COLOURS,
                                   _header, _plt, grip_label, save_figure, view_planes)
from softsbi.scenarios.handles import handle_tracks, pinned_vertices
from softsbi.scenarios.spec import obstacles


def plot_compare_backends(scenario: Any, rollouts: Mapping[str, Any], report: Mapping[str, Any],
                          path: str | Path) -> Path:
    """Side-by-side PNG: the scenario's view (:attr:`~softsbi.core.types.Scenario.view`: a side view x-z or
    y-z, or the top view x-y) of 4 frames with every backend overlaid, and the per-frame Chamfer on the right.

    Colours: each engine one of :data:`softsbi.report.ENGINE_COLOURS` in backend order (first:
    sky blue, second: reddish purple), none of them a role colour of the fit figures; the gripper
    in its role colour (black ``+``). Matplotlib Agg, no display needed."""
    plt = _plt()
    from matplotlib.lines import Line2D  # heavy: loaded on the first figure only
    from matplotlib.ticker import MaxNLocator  # heavy: loaded on the first figure only

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


def plot_rollout_preview(ro: Any, path: str | Path, title: str, scenario: Any = None,
                         effects: Mapping[str, Mapping[str, tuple[float, str]]] | None = None) -> Path:
    """The rest pose from above (x-y, m) with a grid cloth's corners 0-3 (``ro.info["corners"]``) and every
    handle labelled by name, then the scenario's view (:attr:`~softsbi.core.types.Scenario.view`: a side view x-z or
    y-z, or the top view x-y; y-z without a scenario) of a rollout's vertices at four frames, at one pair of limits,
    with every handle of
    ``scenario`` (its grippers ``+`` and the vertices it holds in place ``x``; without a scenario the rollout's
    gripper) and its obstacles (boxes and cylinders, named in the legend below the panels), in the palette's
    posterior, gripper and obstacle colours; under the title, the effects switched on with their values (``effects``:
    effect name -> ``{parameter: (value, unit)}``, :func:`effects_line`) (``softsbi simulate``'s ``preview.png``)."""
    return save_figure(rollout_preview_figure(ro, title, scenario, effects), Path(path))


def effects_line(effects: Mapping[str, Mapping[str, tuple[float, str]]] | None) -> str:
    """The effects a rollout has switched on, with their values: ``"with snag: snag_k = 6 N/m"`` (several joined by
    ``"; "``), or ``"no effect switched on"``. ``effects``: effect name -> ``{parameter: (value, unit)}``."""
    if not effects:
        return "no effect switched on"
    return "; ".join(f"with {e}" + (": " if ps else "") + ", ".join(
        f"{n} = {v:.3g}" + ("" if u in ("1", "") else f" {u}") for n, (v, u) in ps.items())
        for e, ps in effects.items())


def rollout_preview_figure(ro: Any, title: str, scenario: Any = None,
                           effects: Mapping[str, Mapping[str, tuple[float, str]]] | None = None) -> Any:
    """Figure of :func:`plot_rollout_preview`."""
    plt = _plt()
    T = len(ro.times)
    frames = sorted({0, T // 3, 2 * T // 3, T - 1})
    rope = len(ro.faces) == 0
    tracks = (handle_tracks(scenario, ro.vertices[0], rope) if scenario is not None
              else [("gripper", np.asarray(ro.gripper, float))])
    pinned = pinned_vertices(scenario, ro.vertices[0], rope) if scenario is not None else []
    blocks = obstacles(scenario) if scenario is not None else []
    table_z = float(scenario.table_z) if scenario is not None else 0.0
    fig, axes = plt.subplots(1, len(frames) + 1, figsize=(3 * len(frames) + 4, 3.6), squeeze=False,
                             gridspec_kw={"width_ratios": [4 / 3] + [1] * len(frames)})
    _rest_from_above(axes[0, 0], ro, tracks, pinned, [obstacle_outline(o, 0, 1, table_z) for o in blocks])
    a, b, name = view_planes(scenario.view if scenario is not None else "yz")[0]
    outlines = [obstacle_outline(o, a, b, table_z) for o in blocks]
    # one pair of limits for every frame, so that motion shows as motion (a drag along the table included)
    pts = np.concatenate([ro.vertices[f][:, [a, b]] for f in frames] + [p[frames][:, [a, b]] for _, p in tracks]
                         + outlines)
    pts = pts[np.isfinite(pts).all(1)]
    mid, half = (pts.min(0) + pts.max(0)) / 2, 0.53 * max(float((pts.max(0) - pts.min(0)).max()), 1e-3)
    for ax, f in zip(axes[0, 1:], frames):
        for o, poly in zip(blocks, outlines):
            _fill_obstacle(ax, poly, obstacle_name(o) if ax is axes[0, 1] else None)
        v = ro.vertices[f]
        ax.scatter(v[:, a], v[:, b], s=4, color=ROLE_COLOURS["posterior"], label="simulated vertices", zorder=3)
        for k, (_, p) in enumerate(tracks):
            ax.plot(p[f, a], p[f, b], "+", color=ROLE_COLOURS["gripper"], ms=10, mew=2,
                    label=grip_label(len(tracks)) if k == 0 else None, zorder=4)
        for k, (_, i) in enumerate(pinned):
            ax.plot(v[i, a], v[i, b], "x", color=ROLE_COLOURS["gripper"], ms=8, mew=2,
                    label="held in place" if k == 0 else None, zorder=4)
        ax.set_title(f"frame {f}, t = {ro.times[f]:.2f} s ({name})", fontsize=FS_SUB)
        ax.set_xlabel(f"{'xyz'[a]} [m]", fontsize=FS_LABEL)
        ax.set_ylabel(f"{'xyz'[b]} [m]", fontsize=FS_LABEL)
        ax.tick_params(labelsize=FS_TICK)
        ax.set_xlim(mid[0] - half, mid[0] + half)  # a square view, equal aspect
        ax.set_ylim(mid[1] - half, mid[1] + half)
        ax.set_aspect("equal", adjustable="box")
    handles, labels = axes[0, 1].get_legend_handles_labels()  # below the panels, clear of the data
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=FS_LEGEND + 1, frameon=False)
    frac = _header(fig, [(title, {"fontsize": FS_TITLE}), (effects_line(effects), {"fontsize": FS_SUB})])
    fig.tight_layout(rect=(0, 0.35 / fig.get_figheight(), 1, 1 - frac))
    return fig


def obstacle_name(o: Mapping[str, Any]) -> str:
    """An obstacle's legend text: its name and type (``"block (box)"``), or its type alone."""
    return f"{o['name']} ({o['type']})" if o.get("name") else str(o["type"])


def obstacle_outline(o: Mapping[str, Any], a: int, b: int, table_z: float) -> np.ndarray:
    """The outline ``(K, 2)`` m of a scenario obstacle (:func:`~softsbi.scenarios.spec.obstacles`: a box
    with ``centre`` [x, y, z], ``half_size`` and ``yaw`` deg about z; a cylinder standing on the table at ``table_z``
    with ``centre`` [x, y], ``radius`` and ``height``) seen along the third axis of the plane of axes ``a``, ``b``
    (0-2 = x, y, z): from above (0, 1) a box's rotated rectangle or a cylinder's circle, from a side the rectangle it
    covers."""
    top = (a, b) == (0, 1)
    if o["type"] == "cylinder":
        c, r, h = np.asarray(o["centre"], float), float(o["radius"]), float(o["height"])
        if top:
            phi = np.linspace(0, 2 * np.pi, 49)
            return c + r * np.stack([np.cos(phi), np.sin(phi)], 1)
        lo = np.array([c[a] - r, table_z])
        hi = np.array([c[a] + r, table_z + h])
    else:
        c, hs = np.asarray(o["centre"], float), np.asarray(o["half_size"], float)
        yaw = np.radians(float(o.get("yaw", 0.0)))
        rot = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
        signs = np.array([[-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1], [-1, -1, -1], [1, -1, -1], [1, 1, -1],
                          [-1, 1, -1]], float)
        corners = (c + (signs * hs) @ rot.T)[:, [a, b]]
        if top:
            return corners[:4]
        lo, hi = corners.min(0), corners.max(0)
    return np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])


def _fill_obstacle(ax: Any, poly: np.ndarray, label: str | None) -> None:
    """Draw one obstacle's outline (:func:`obstacle_outline`) filled in the palette's obstacle colour."""
    ax.fill(poly[:, 0], poly[:, 1], facecolor=ROLE_COLOURS["obstacle"], alpha=0.45,
            edgecolor=ROLE_COLOURS["obstacle"], lw=1.2, label=label, zorder=1)


#: room around the cloth in the preview's view from above, for the corner and handle labels (fraction of its size)
PREVIEW_LABEL_ROOM = 0.45


def _rest_from_above(ax: Any, ro: Any, tracks: list[tuple[str, np.ndarray]], pinned: list[tuple[str, int]],
                     outlines: Sequence[np.ndarray] = ()) -> None:
    """The first frame's vertices from above (x-y), each corner (``corner k``) and handle (its name) labelled
    beside its vertex, away from the cloth's centre: where a scenario file's corners and handles end up; the
    obstacles' ``outlines`` from above (:func:`obstacle_outline`) behind them."""
    v = np.asarray(ro.vertices[0], float)
    for poly in outlines:
        _fill_obstacle(ax, poly, None)
    ax.scatter(v[:, 0], v[:, 1], s=4, color=ROLE_COLOURS["posterior"], zorder=3)
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
    near = np.concatenate([v[:, :2], *outlines])
    lo, hi = near.min(0), near.max(0)
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
    return save_figure(fig, path)
