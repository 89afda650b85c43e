"""Cross-simulator comparison: the same scenario at the same *physical* parameters on several engines.

Shared physical parameters have one name, unit and meaning on every backend (so that one value means
the same cloth on each: ``bend`` N m, ``stretch`` N/m, ``friction``, ``scale`` m, ``mass`` kg/m^2, see
:func:`softsbi.backends.common.cloth_material_params`; each backend maps them to its own knobs).
:func:`shared_space` is the box every backend honours: the parameters all backends have with the
same unit, bounds intersected. By default every backend gets the *shared prior midpoint* (the
centre of that box, geometric for log parameters); values given by name override it. Engine-only
knobs (e.g. ``pb_rope_bend``, or mujoco-flex's rope ``young`` in Pa) sit at that backend's own
prior midpoint. With ``match="unit"`` ``theta`` is read in unit-cube coordinates of each backend's
own prior instead. The report says which value each backend got and where it came from.

Distance: per-frame bidirectional Chamfer (:func:`softsbi.core.metrics.chamfer_per_frame`,
Antonova et al. 2022, Sec. V) between area-weighted surface samples of the two meshes
(:func:`softsbi.perception.pointcloud.rollout_clouds`; points along the polyline for a rope).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from softsbi.backends.scenario_build import unsupported
from softsbi.core.errors import ParameterError
from softsbi.core.metrics import chamfer_per_frame
from softsbi.core.results import check_result_path, write_json_atomic
from softsbi.core.types import STATUS_NAMES, Param, ParamSpace, Scenario
from softsbi.perception.pointcloud import rollout_clouds
from softsbi.plugins import registry
from softsbi.report import plot_compare_backends
from softsbi.core.defaults import COMPARED_BACKENDS


def shared_space(spaces: Sequence[ParamSpace]) -> ParamSpace:
    """The shared physical parameter box of several backends' spaces: the parameters every space has with
    the same unit (and log flag), bounds intersected (first space's order).

    Raises:
        ParameterError: a shared parameter's bounds do not overlap between backends.
    """
    first, rest = spaces[0], spaces[1:]
    out = []
    for p in first:
        others = [s[p.name] for s in rest if p.name in s.names]
        if len(others) != len(rest) or any(o.unit != p.unit or o.log != p.log for o in others):
            continue
        lo, hi = max([p.low] + [o.low for o in others]), min([p.high] + [o.high for o in others])
        if not lo < hi:
            raise ParameterError(f"parameter '{p.name}' has no common range across backends "
                                 f"({[(q.low, q.high) for q in [p] + others]})")
        out.append(Param(p.name, lo, hi, p.unit, log=p.log, description=p.description))
    return ParamSpace(out)


def backend_theta(space, theta: Mapping[str, float], match: str = "physical",
                  shared: Mapping[str, float] | None = None) -> tuple[dict[str, float], dict[str, str]]:
    """Parameters for one backend: ``(values, source)`` with ``source[name]`` in
    ``{"given", "shared-midpoint", "midpoint", "unit"}``; ``shared``: the shared prior midpoint
    (:func:`shared_space`), used for the names it has unless given.

    Raises:
        ParameterError: a given physical value is outside this backend's bounds; unknown ``match``.
    """
    if match not in ("physical", "unit"):
        raise ParameterError(f"match must be 'physical' or 'unit', got {match!r}")
    vals = space.midpoint()
    src = {n: "midpoint" for n in space.names}
    if match == "physical":
        for n, v in (shared or {}).items():
            if n in vals:
                vals[n], src[n] = float(v), "shared-midpoint"
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
    return space.check(vals, within="limits"), src


def compare_backends(scenario: Scenario, theta: Mapping[str, float] | None = None,
                     backends: Sequence[str] = COMPARED_BACKENDS, out_dir: str | Path | None = None,
                     *, backend_options: Mapping[str, Mapping[str, Any]] | None = None, n_points: int = 500,
                     seed: int = 0, match: str = "physical") -> dict[str, Any]:
    """Roll ``scenario`` out on each backend at the same parameters and compare them frame by frame.

    Args:
        scenario: any scenario every backend can run (see :func:`softsbi.scenarios.builtin.make_scenario`).
        theta: ``{name: value}``; see the module docstring (unset names: the shared prior midpoint,
            engine-only ones each backend's own midpoint). A name that no backend has raises.
        backends: simulator plugin names (>= 2); the first is the reference of the Chamfer.
        out_dir: if given, writes ``compare.json`` and ``compare.png`` (side view of 4 frames,
            backends overlaid, plus the Chamfer curve) there.
        backend_options: ``{backend: {option: value}}`` constructor options (e.g. ``{"grid": 7}``).
        n_points: surface samples per frame for the Chamfer distance.
        seed: seeds the surface sampling (the engines are deterministic).
        match: ``"physical"`` or ``"unit"`` (see :func:`backend_theta`).

    Returns:
        ``{"scenario", "shared_params": [names], "shared_midpoint": {...}, "backends": {name: {"theta",
        "theta_source", "status", "reason", "wall_s", "n_vertices"}}, "times" (T,), "chamfer_m":
        {"a|b": (T,) list}, "mean_chamfer_m": {...}, "max_chamfer_m": {...}, "files": [...]}``. Chamfer values are metres; null when a rollout failed.

    Raises:
        PluginNotFound: unknown backend. ValueError: a backend cannot run the scenario, fewer than
        two backends. ParameterError: unknown parameter name or value out of a backend's bounds.
        ResultUnwritable: a folder stands at ``compare.json`` or ``compare.png`` (before simulating).
    """
    if len(backends) < 2:
        raise ValueError(f"compare_backends needs at least two backends, got {list(backends)}")
    for name in ("compare.json", "compare.png") if out_dir is not None else ():
        check_result_path(Path(out_dir) / name)
    theta = dict(theta or {})
    reg = registry()
    sims = {}
    for b in backends:
        cls = reg.simulator(b)
        why = unsupported(cls, scenario)
        if why:
            raise ValueError(why)
        sims[b] = cls(**dict((backend_options or {}).get(b, {})))
    known = set().union(*(s.param_space(scenario).names for s in sims.values()))
    unknown = [n for n in theta if n not in known]
    if unknown:
        raise ParameterError(f"unknown parameter(s) {unknown} for scenario '{scenario.name}'; valid parameters: "
                             f"{', '.join(sorted(known))}")
    spaces = {b: s.param_space(scenario) for b, s in sims.items()}
    shared = shared_space(list(spaces.values()))
    mid = shared.midpoint()
    report: dict[str, Any] = {"scenario": scenario.name, "match": match, "backends": {},
                              "shared_params": shared.names, "shared_midpoint": mid,
                              "times": scenario.times.tolist(), "chamfer_m": {}, "mean_chamfer_m": {},
                              "max_chamfer_m": {}}
    rollouts = {}
    for b, sim in sims.items():
        space = spaces[b]
        vals, src = backend_theta(space, theta, match, mid)
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
            report["max_chamfer_m"][key] = None
            continue
        ch = chamfer_per_frame(clouds[ref], clouds[b])
        report["chamfer_m"][key] = ch.tolist()
        report["mean_chamfer_m"][key] = float(ch.mean())
        report["max_chamfer_m"][key] = float(ch.max())
    report["files"] = []
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        png = plot_compare_backends(scenario, rollouts, report, out / "compare.png")
        report["files"] = [str(out / "compare.json"), str(png)]
        write_json_atomic(out / "compare.json", report)
    return report
