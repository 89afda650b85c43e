"""Cross-simulator comparison: the same scenario and parameters rolled out on several engines.

The engines do not share units for every parameter (mujoco-flex ``bend`` is a bending rigidity in
N m, pybullet-fem ``bend`` a spring stiffness in N/m), so "the same parameters" means: values
given by name are used where the backend has that parameter and they lie inside its bounds;
every other parameter sits at that backend's prior midpoint - or, with ``match="unit"``, the same
*relative position* ``u`` in each backend's prior box (``theta`` is then read in unit-cube
coordinates). The report says which value each backend got.

Distance: per-frame bidirectional Chamfer (:func:`softsbi.core.metrics.chamfer_per_frame`,
Antonova et al. 2022, Sec. V) between area-weighted surface samples of the two meshes
(:func:`softsbi.perception.pointcloud.rollout_clouds`; points along the polyline for a rope).
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from ..core.errors import ParameterError
from ..core.metrics import chamfer_per_frame
from ..core.types import STATUS_NAMES, Scenario


def backend_theta(space, theta: Mapping[str, float], match: str = "physical") -> tuple[dict[str, float], dict[str, str]]:
    """Parameters for one backend: ``(values, source)`` with ``source[name]`` in
    ``{"given", "midpoint", "unit"}``.

    Raises:
        ParameterError: a given physical value is outside this backend's bounds; unknown ``match``.
    """
    if match not in ("physical", "unit"):
        raise ParameterError(f"match must be 'physical' or 'unit', got {match!r}")
    vals = space.midpoint()
    src = {n: "midpoint" for n in space.names}
    for n, v in theta.items():
        if n not in space.names:
            continue
        if match == "unit":
            if not 0.0 <= float(v) <= 1.0:
                raise ParameterError(f"with match='unit' the value of '{n}' is a prior position in [0, 1], got {v}")
            u = np.full(space.dim, 0.5)
            u[space.names.index(n)] = float(v)
            vals[n] = space.as_dict(space.from_unit(u))[n]
            src[n] = "unit"
        else:
            vals[n] = float(v)
            src[n] = "given"
    return space.check(vals), src


def compare_backends(scenario: Scenario, theta: Mapping[str, float] | None = None,
                     backends: Sequence[str] = ("mujoco-flex", "pybullet-fem"), out_dir: str | Path | None = None,
                     *, backend_options: Mapping[str, Mapping[str, Any]] | None = None, n_points: int = 500,
                     seed: int = 0, match: str = "physical") -> dict[str, Any]:
    """Roll ``scenario`` out on each backend at the same parameters and compare them frame by frame.

    Args:
        scenario: any scenario every backend can run (see :func:`softsbi.backends.scenarios.make_scenario`).
        theta: ``{name: value}``; see the module docstring (unset names: each backend's midpoint).
            A name that no backend has raises.
        backends: simulator plugin names (>= 2); the first is the reference of the Chamfer.
        out_dir: if given, writes ``compare.json`` and ``compare.png`` (side view of 4 frames,
            backends overlaid, plus the Chamfer curve) there.
        backend_options: ``{backend: {option: value}}`` constructor options (e.g. ``{"grid": 7}``).
        n_points: surface samples per frame for the Chamfer distance.
        seed: seeds the surface sampling (the engines are deterministic).
        match: ``"physical"`` or ``"unit"`` (see :func:`backend_theta`).

    Returns:
        ``{"scenario", "backends": {name: {"theta", "theta_source", "status", "reason", "wall_s",
        "n_vertices"}}, "times" (T,), "chamfer_m": {"a|b": (T,) list}, "mean_chamfer_m": {...},
        "files": [...]}``. Chamfer values are metres; null when a rollout failed.

    Raises:
        PluginNotFound: unknown backend. ValueError: a backend cannot run the scenario, fewer than
        two backends. ParameterError: unknown parameter name or value out of a backend's bounds.
    """
    from ..perception.pointcloud import rollout_clouds
    from ..plugins import registry

    if len(backends) < 2:
        raise ValueError(f"compare_backends needs at least two backends, got {list(backends)}")
    theta = dict(theta or {})
    reg = registry()
    sims = {}
    for b in backends:
        cls = reg.simulator(b)
        if scenario.name not in cls.scenarios:
            raise ValueError(f"backend '{b}' cannot run scenario '{scenario.name}'; it runs {list(cls.scenarios)}")
        sims[b] = cls(**dict((backend_options or {}).get(b, {})))
    known = set().union(*(s.param_space(scenario).names for s in sims.values()))
    unknown = [n for n in theta if n not in known]
    if unknown:
        raise ParameterError(f"unknown parameter(s) {unknown} for scenario '{scenario.name}'; valid parameters: "
                             f"{', '.join(sorted(known))}")
    report: dict[str, Any] = {"scenario": scenario.name, "match": match, "backends": {},
                              "times": scenario.times.tolist(), "chamfer_m": {}, "mean_chamfer_m": {}}
    rollouts = {}
    for b, sim in sims.items():
        space = sim.param_space(scenario)
        vals, src = backend_theta(space, theta, match)
        ro = sim.simulate(scenario, vals, seed=seed)
        rollouts[b] = ro
        report["backends"][b] = {"theta": vals, "units": {p.name: p.unit for p in space}, "theta_source": src,
                                 "status": STATUS_NAMES.get(ro.status, str(ro.status)), "reason": ro.reason,
                                 "wall_s": float(ro.info.get("wall_s", float("nan"))),
                                 "n_vertices": int(ro.vertices.shape[1])}
    ref = backends[0]
    rng = np.random.default_rng(seed)
    clouds = {b: rollout_clouds(ro, n_points, rng) if ro.ok else None for b, ro in rollouts.items()}
    for b in backends[1:]:
        key = f"{ref}|{b}"
        if clouds[ref] is None or clouds[b] is None:
            report["chamfer_m"][key] = None
            report["mean_chamfer_m"][key] = None
            continue
        ch = chamfer_per_frame(clouds[ref], clouds[b])
        report["chamfer_m"][key] = ch.tolist()
        report["mean_chamfer_m"][key] = float(ch.mean())
    report["files"] = []
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        png = compare_png(scenario, rollouts, report, out / "compare.png")
        report["files"] = [str(out / "compare.json"), str(png)]
        (out / "compare.json").write_text(json.dumps(report, indent=2))
    return report


def compare_png(scenario: Scenario, rollouts: Mapping[str, Any], report: Mapping[str, Any], path: str | Path) -> Path:
    """Side-by-side PNG: the side view (y-z for lift, x-z otherwise; top view x-y for the rope on
    the table) of 4 frames with every backend overlaid, and the per-frame Chamfer on the right.

    Colours: each engine one of :data:`softsbi.report.ENGINE_COLOURS` in backend order (first:
    sky blue, second: reddish purple), none of them a role colour of the fit figures; the gripper
    in its role colour (black ``+``). Matplotlib Agg, no display needed."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    from ..report import (
        DPI,
        ENGINE_COLOURS,
        FS_LABEL,
        FS_LEGEND,
        FS_SUB,
        FS_TICK,
        FS_TITLE,
        ROLE_COLOURS,
        _header,
    )

    T = scenario.n_frames
    frames = sorted({0, T // 3, 2 * T // 3, T - 1})
    ax_i = 1 if scenario.name == "lift" else 0
    top = scenario.name == "wind"  # the rope stays on the table: top view
    j = 1 if top else 2
    i = 0 if top else ax_i
    view = "top view" if top else "side view"
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
        ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(3))
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
