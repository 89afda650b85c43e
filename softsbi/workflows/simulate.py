"""``softsbi simulate``: one rollout at given parameters, written to a folder.

``OUT/rollout.zarr`` (times s, gripper m, vertices m, faces; attributes: backend, scenario, theta,
status, reason), ``OUT/preview.png`` (the rest pose from above with corners 0-3 and the handles labelled, then
four frames in the scenario's view, side or top (``view:``), with the scenario's obstacles and the effects switched on
and their values), a recording directory in the same folder (``OUT/recording.yaml`` + ``OUT/clouds/NNN.npy``, :mod:`softsbi.data.recording`: surface samples of
every frame, the scenario inline, the hidden ``truth`` and ``effects``; ``softsbi fit --observed OUT``
reads it) and, when rendering,
``OUT/frames/000.png ...`` with ``truth.json`` (a measurement for ``fit --observer heatmap|transporter``).
"""
from __future__ import annotations

import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import zarr

from softsbi.core.errors import EffectFault, SimulationFailed, SoftsbiError
from softsbi.core.results import write_json_atomic
from softsbi.perception.images import save_frames
from softsbi.plugins import check_options, registry
from softsbi.report import plot_rollout_preview
from softsbi.data.recording import write_recording
from softsbi.perception.pointcloud import rollout_clouds
from softsbi.scenarios.builtin import make_scenario
from softsbi.scenarios.spec import spec_from_scenario
from softsbi.scenarios.cameras import scenario_camera
from softsbi.core.defaults import BACKEND, SCENARIO
from softsbi.workflows.fit.jobs import failure_reason
from softsbi.workflows.lock import check_out_dir
from softsbi.workflows.measurement import default_values, rollout_space


#: points per frame of the recording ``softsbi simulate`` writes
CLOUD_POINTS = 2000
#: default cap on the memory of rendered frames held at once (GB); override with ``render_memory_gb``
RENDER_MEMORY_GB = 4.0
#: peak bytes per rendered pixel and frame: 8 stored (rgb 3 x uint8, depth float32, segmentation uint8) plus
#: the copies made while rendering and saving: a lift's peak memory over a plain simulation, divided by its pixels
#: x frames, lies between 10.6 and 12.8 B from 1024 to 5000 px
BYTES_PER_PIXEL = 11


def render_memory_bytes(size: int, frames: int) -> int:
    """Peak memory of rendering one rollout, bytes: ``(frames + 2) * size**2 * BYTES_PER_PIXEL`` (the
    frames kept, plus two frames of off-screen buffers), with the per-pixel cost measured on mujoco-flex
    (see :data:`BYTES_PER_PIXEL`)."""
    return int((frames + 2) * size * size * BYTES_PER_PIXEL)


def check_render_memory(size: int, frames: int, cap_gb: float) -> int:
    """Refuse a render whose frames would exceed ``cap_gb`` GB (one line with the fix); returns the estimate.

    Raises:
        SoftsbiError: ``size`` < 1, or the estimate exceeds the cap.
    """
    if size < 1:
        raise SoftsbiError(f"--render {size}: the image size must be a positive number of pixels (e.g. 256)")
    need = render_memory_bytes(size, frames)
    if need > cap_gb * 1e9:
        fits = int((cap_gb * 1e9 / ((frames + 2) * BYTES_PER_PIXEL)) ** 0.5)
        raise SoftsbiError(f"--render {size} would hold about {need / 1e9:.1f} GB of frames ({frames} frames of "
                           f"{size}x{size} px), over the {cap_gb:g} GB cap: use "
                           f"--render {fits} or less, or raise the cap with --render-memory-gb "
                           f"{need / 1e9 * 1.2:.0f}")
    return need


def simulate_to_folder(out: str | Path, backend: str = BACKEND, scenario: str | Path = SCENARIO,
                       recording: str | Path | None = None, theta: Mapping[str, float] | None = None,
                       effects: Sequence[str] = (), backend_options: Mapping[str, Any] | None = None,
                       render: int | None = None,
                       render_memory_gb: float = RENDER_MEMORY_GB, cloud_points: int = CLOUD_POINTS,
                       seed: int = 0, overwrite: bool = False) -> dict[str, Any]:
    """Roll ``scenario`` out at ``theta`` (physical units; unset parameters: :func:`default_values`, the
    scenario's object size and the prior midpoint) and write it into ``out``.

    Args:
        scenario: a scenario name (``softsbi scenarios``) or scenario file path.
        cloud_points: points per frame of the written recording (area-weighted surface samples).
        seed: seeds the surface sampling.
        render: also render every frame through the scenario's built-in overhead camera at this
            square size (px).
        render_memory_gb: cap on the estimated memory of the rendered frames
            (:func:`render_memory_bytes`), GB; a larger request is refused before simulating.
        overwrite: ``out`` may hold files (an earlier simulation): they are replaced by this one's. Without it
            a non-empty ``out`` is refused, so one folder never mixes two simulations.

    Everything is written into a hidden sibling folder that replaces ``out`` once complete: a failure
    (a full disk, an interrupt) leaves ``out`` as it was and no partial folder.

    Returns:
        ``{"backend", "scenario", "theta", "status", "reason", "frames", "vertices", "wall_s", "rollout",
        "preview", "recording", "frames_dir"}``: the last three are paths, or None when not written (no preview
        nor recording of a failed rollout, no ``frames_dir`` unless rendered).

    Raises:
        SoftsbiError: unknown scenario; PluginNotFound: unknown backend or effect; PluginError: a broken effect, or a
        simulator that cannot be made (:meth:`~softsbi.plugins.manager.Registry.create`; ParameterError: its options
        refused);
        ParameterError: a scenario the backend cannot run (its ``scenarios``/``features``);
        SimulationFailed: the simulation raised (a plugin's fault such as an effect's non-finite force or
            observation, named); EnvironmentFault: the machine cannot simulate;
        ParameterError: unknown parameter or a value outside its physical limits (not its prior: a widened prior is simulated); RenderingUnavailable: no OpenGL;
        SoftsbiError: ``render`` or ``render_memory_gb`` not positive, or the frames would exceed
            ``render_memory_gb``; ``out`` is a file, or a non-empty folder without ``overwrite``.
    """
    out = Path(out)
    check_out_folder(out, overwrite)
    if not render_memory_gb > 0:
        raise SoftsbiError(f"--render-memory-gb {render_memory_gb}: the cap must be a positive number of GB "
                           f"(default {RENDER_MEMORY_GB:g})")
    try:
        sc = make_scenario(str(scenario), recording)
    except ValueError as exc:
        raise SoftsbiError(str(exc)) from None
    reg = registry()
    what = f"simulator '{backend}' (--backend-opt)"
    check_options(reg.simulator(backend), dict(backend_options or {}), what)
    sim = reg.create("simulator", backend, dict(backend_options or {}), what)
    space = rollout_space(sim, sc, effects)
    values = default_values(space, sc)
    values.update(dict(theta or {}))
    values = space.check(values, within="limits")
    if render is not None:
        check_render_memory(render, len(sc.times), render_memory_gb)
    t0 = time.perf_counter()
    try:
        if render:
            ro = sim.simulate_images(sc, values, camera=scenario_camera(sc, render), effects=list(effects))
        else:
            ro = sim.simulate(sc, values, effects=list(effects))
    except Exception as exc:  # noqa: BLE001 - a failed simulation, as a fit stores it (a plugin's fault named)
        reason = failure_reason(exc, backend)
        if isinstance(exc, EffectFault):  # its message names the effect and the fix
            raise SimulationFailed(f"the simulation failed: {exc}; nothing was written") from None
        raise SimulationFailed(f"the simulation failed ({reason}); nothing was written; change the parameters "
                               f"(--theta), the backend options or the scenario") from None
    dt = time.perf_counter() - t0
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        doc = _write_rollout(tmp, out, ro, sc, backend, scenario, values, effects, render, cloud_points, seed, dt,
                             {e: {q.name: (values[q.name], q.unit) for q in reg.effect(e)().param_space()}
                              for e in effects})
        if out.exists():  # --overwrite (checked above): the old contents go once the new ones are complete
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return doc


def check_out_folder(out: Path, overwrite: bool) -> None:
    """Refuse an output folder that is a file or cannot be written, or that holds files unless ``overwrite``.

    Raises:
        SoftsbiError: one line naming the folder and the fix (:func:`~softsbi.workflows.lock.check_out_dir`).
    """
    check_out_dir(out)
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise SoftsbiError(f"--out '{out}' is not empty; choose a new folder, or pass --overwrite to replace its "
                           f"contents with this simulation")


def _write_rollout(out: Path, final: Path, ro: Any, sc: Any, backend: str, scenario: str | Path, values: dict[str, float],
                   effects: Sequence[str], render: int | None, cloud_points: int, seed: int,
                   dt: float, shown: Mapping[str, Mapping[str, tuple[float, str]]]) -> dict[str, Any]:
    """Write one rollout's files into the (new, empty) folder ``out``; returns the command's summary, whose paths
    name the ``final`` folder ``out`` becomes. ``shown``: each effect's parameters with their values and units, for
    the preview."""
    g = zarr.open_group(str(out / "rollout.zarr"), mode="w")
    g.attrs.update({"backend": backend, "scenario": sc.to_json(), "theta": values, "status": int(ro.status),
                    "reason": ro.reason})
    for name, arr, units in (("times", ro.times, "s"), ("gripper", ro.gripper, "m"), ("vertices", ro.vertices, "m"),
                             ("faces", ro.faces, "1")):
        a = g.create_array(name, shape=arr.shape, dtype=arr.dtype, attributes={"units": units})
        a[...] = arr
    doc: dict[str, Any] = {"backend": backend, "scenario": str(scenario), "theta": values, "status": int(ro.status),
                           "reason": ro.reason, "frames": len(ro.times), "vertices": int(ro.vertices.shape[1]),
                           "wall_s": dt, "rollout": str(final / "rollout.zarr"), "preview": None, "recording": None,
                           "frames_dir": None}
    if ro.ok:
        plot_rollout_preview(ro, out / "preview.png", f"{backend} {sc.name}", sc, shown)
        doc["preview"] = str(final / "preview.png")
        clouds = rollout_clouds(ro, int(cloud_points), np.random.default_rng(seed))
        meta = {"scenario": {"inline": spec_from_scenario(sc)}, "times": ro.times.tolist(),
                "transform": {"matrix": np.eye(4).tolist()},
                "sensor": {"kind": f"surface samples of the simulated mesh ({cloud_points} per frame)",
                           "frames": "all"},
                "truth": values, "effects": list(effects),
                "source": f"simulated:{backend}" + (f"+{'+'.join(effects)}" if effects else "")}
        write_recording(out, meta, list(clouds), images=ro.rgb if render else None, overwrite=True)
        doc["recording"] = str(final)
    if ro.ok and render:
        save_frames(ro.rgb, out / "frames")
        write_json_atomic(out / "frames" / "truth.json", values)
        doc["frames_dir"] = str(final / "frames")
    return doc
