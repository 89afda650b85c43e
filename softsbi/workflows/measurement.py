"""Building the measurement a fit conditions on: real recordings or a hidden-parameter simulation."""
from __future__ import annotations

import json
import os
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import cv2
import numpy as np

from softsbi.core.arrays import read_npy
from softsbi.backends.scenario_build import unsupported
from softsbi.core.errors import DataError, ParameterError, SimulationFailed, SoftsbiWarning
from softsbi.core.types import Recording
from softsbi.core.types import Scenario
from softsbi.core.yamlfile import read_yaml
from softsbi.data.recording import META, RecordingMeta, is_recording, parse_meta, read_recording, write_recording
from softsbi.perception.images import load_frames
from softsbi.perception.pointcloud import (PointCloudObserver, effect_views, load_cloud_frames, rollout_arm_radius,
                                          rollout_clouds, rollout_min_z, seen_resampled)
from softsbi.plugins import registry
from softsbi.scenarios.builtin import FRAME_DT, lift_task, make_scenario
from softsbi.scenarios.cameras import scenario_camera
from softsbi.scenarios.catalog import load_scenario
from softsbi.scenarios.spec import (apply_transform, declared_size, load_scenario_data, spec_from_scenario,
                                   transform_matrix)
from softsbi.core.defaults import BACKEND, IMAGE_SIZE, SCENARIO
from softsbi.workflows.lock import check_out_dir

if TYPE_CHECKING:
    from softsbi.core.camera import Camera, RenderStyle

#: points per frame kept from a real cloud for the Chamfer metric
N_DENSE = 1000


#: the DiffCloud recordings' sensor model: points closer than this to the table are not seen (m).
#: Real depth clouds contain no cloth lying flat on the table (checked on all 10 DiffCloud
#: recordings). With the placement yaw inferred, fitting every frame without this sensor model lowers
#: lift_tan's total Chamfer further (3.35 vs 3.65 cm) but only by covering the early fragments with a
#: rotated cloth that then hangs crossed to the real one (frames 15-24: 4.77 vs 3.11 cm)
DIFFCLOUD_MIN_HEIGHT = 0.01


def rollout_space(sim: Any, scenario: Scenario, effects: Sequence[str] = ()) -> Any:
    """The :class:`~softsbi.core.types.ParamSpace` of a rollout of ``scenario`` on ``sim`` (a simulator instance)
    with ``effects``: the backend's parameters, then each effect's (:meth:`~softsbi.plugins.Registry.param_space`).

    Raises:
        ParameterError: the backend cannot run the scenario (its ``scenarios`` or ``features``).
        PluginNotFound: an unknown effect. PluginError: a plugin's code fails to declare its parameters, or two
            declare one name (one line naming the plugin and its file).
    """
    why = unsupported(sim, scenario)
    if why:
        raise ParameterError(why)
    return registry().param_space(sim, scenario, effects)


def default_values(space: Any, scenario: Any) -> dict[str, float]:
    """The parameters a single rollout takes when not given: the scenario's declared object size for ``scale``
    (``object.size``, a cloth's side, or ``object.length``, a rope's; when ``scale`` is a parameter), every other
    parameter at its prior midpoint. A fit infers ``scale`` over its prior instead (``--fix scale=...`` holds
    it at a size)."""
    values = space.midpoint()
    _, size = declared_size(scenario)
    if "scale" in values and size is not None and "mesh" not in (getattr(scenario, "object", None) or {}):
        values["scale"] = float(size)
    return values


def load_recording(folder: str | Path, n_points: int = 64, n_dense: int = N_DENSE, seed: int = 0,
                   scenario: str | Path | Scenario | None = None) -> Recording:
    """A recording as a :class:`Recording` in its scenario's frame (metres).

    Args:
        folder: a recording directory (``recording.yaml`` + ``clouds/``, :mod:`softsbi.data.recording`;
            written by ``softsbi import diffcloud`` or ``softsbi simulate --out``), or a DiffCloud folder
            (``000.npy`` ... in the simulator frame with ``<task>_real2sim.yaml``; converted in memory by
            the importer, :func:`diffcloud_recording`).
        n_points: K, points per frame of the observed state.
        n_dense: points per frame kept for the Chamfer metric (subsampled without replacement when
            the frame has that many, any ``P_t`` otherwise).
        seed: seeds the subsampling.
        scenario: replaces the recording's own scenario (name, file or :class:`Scenario`).

    Returns:
        Recording with ``x (T, 1+K, 3)``, ``dense (T, n_dense, 3)``, ``truth`` for simulated ones, and the
        recording's sensor model as its fit defaults (``min_height``, ``frames``).

    Raises:
        DataError: missing/malformed folder, files or fields (one line naming the file, field and fix);
            a frame count or times that disagree with the scenario's frames.
    """
    folder = Path(folder)
    if is_recording(folder):
        data = read_recording(folder)
        meta, clouds, base = data.meta, data.clouds, folder
    else:
        if folder.is_dir() and not any(f.stem.isdigit() for f in folder.glob("*.npy")) and \
                any(f.stem.isdigit() for f in folder.glob("*.png")):
            raise DataError(f"'{folder}' holds image frames (000.png ...), not point clouds; fit them with an image "
                            f"observer (--observer heatmap|transporter --extractor PATH.pt)")
        meta, clouds = diffcloud_recording(folder, scenario if isinstance(scenario, (str, Path)) else None)
        meta, base = parse_meta(meta, str(folder)), folder
        m = meta.transform.as_matrix()
        clouds = [c @ m[:3, :3].T + m[:3, 3] for c in clouds]
    return recording_from_meta(meta, clouds, base, n_points=n_points, n_dense=n_dense, seed=seed,
                               scenario=scenario, source=str(folder))


def recording_scenario(folder: str | Path) -> Scenario:
    """The scenario of a recording directory (from its ``recording.yaml``; the clouds are not read) or of a
    DiffCloud lift folder (derived from its data, as :func:`load_recording` derives it).

    Raises:
        DataError: ``folder`` is neither (one line saying what is accepted), or its scenario is invalid.
    """
    folder = Path(folder)
    if is_recording(folder):
        return scenario_of(parse_meta(read_yaml(folder / META), str(folder / META)), folder, str(folder))
    if not (any(folder.glob("*_real2sim.yaml")) and any(f.stem.isdigit() for f in folder.glob("*.npy"))):
        inside = sorted(p.name for p in folder.iterdir() if p.is_dir() and (is_recording(p) or any(p.glob("0*.npy"))))
        raise DataError(f"'{folder}' is neither a recording directory (no recording.yaml) nor a DiffCloud recording "
                        f"folder (no <task>_real2sim.yaml with 000.npy ...)"
                        + (f"; it holds recordings ({', '.join(inside[:3])}{', ...' if len(inside) > 3 else ''}): "
                           f"give one of them" if inside else "; give a scenario name (`softsbi scenarios` lists "
                                                              "them), a scenario file (.yaml) or a recording directory"))
    return load_recording(folder, n_points=8, n_dense=8).scenario


def scenario_of(meta: RecordingMeta, base: Path, source: str,
                override: str | Path | Scenario | None = None) -> Scenario:
    """The scenario a recording's ``scenario`` entry names (or ``override``: a name, file or
    :class:`Scenario`), with the recording's ``frames_of_reference`` replacing the scenario's transforms
    (the recording's own calibration).

    Raises:
        DataError: an unknown name or an invalid scenario file / inline scenario.
    """
    frames = {k: v.as_matrix() for k, v in meta.frames_of_reference.items()}
    if override is not None:
        return override if isinstance(override, Scenario) else load_scenario(override, frames)
    ref = meta.scenario
    if ref.inline is not None:
        return load_scenario_data(ref.inline, f"{source}/recording.yaml: scenario.inline", base, frames)
    if ref.file is not None:
        f = Path(ref.file).expanduser()
        return load_scenario(f if f.is_absolute() else base / f, frames)
    return load_scenario(ref.name, frames)


def recording_from_meta(meta: RecordingMeta, clouds: Sequence[np.ndarray], base: Path, n_points: int = 64,
                        n_dense: int = N_DENSE, seed: int = 0, scenario: str | Path | Scenario | None = None,
                        source: str = "") -> Recording:
    """Build the :class:`Recording` of validated recording metadata (``recording.yaml``, :func:`parse_meta`) and
    clouds ``(P_t, 3)`` m (scenario frame).

    Raises:
        DataError: the number of clouds or their times disagree with the scenario's frames.
    """
    sc = scenario_of(meta, base, source, scenario)
    times = np.asarray(meta.times, dtype=float)
    if len(clouds) != sc.n_frames:
        raise DataError(f"{source}: the recording has {len(clouds)} frames but scenario '{sc.name}' has "
                        f"{sc.n_frames}; make the scenario's frames match the recording (frames.count / times)")
    if np.abs(times - sc.times).max() > 1e-6:
        k = int(np.argmax(np.abs(times - sc.times)))
        raise DataError(f"{source}: frame {k} is at t = {times[k]:g} s in the recording but {sc.times[k]:g} s in "
                        f"scenario '{sc.name}'; make the scenario's frames match the recording's times")
    check_reach(clouds, sc, source)
    check_table(clouds, sc, source)
    rng = np.random.default_rng(seed)
    obs = PointCloudObserver(n_points).observe_clouds(list(clouds), sc.gripper, sc.times, rng, source=source)
    dense = np.stack([c[rng.choice(len(c), size=n_dense, replace=len(c) < n_dense)] for c in clouds])
    return Recording(scenario=sc, x=obs.state(), dense=dense, source=source, truth=meta.truth,
                     min_height=meta.sensor.min_height, frames=meta.sensor.frames)


#: how far (in object extents: a cloth's diagonal, a rope's length) a frame's points may lie from the nearest
#: gripper, by their median: a held object lies within one extent of its grasp; the real DiffCloud lifts reach
#: 1.01 (lift_redblack2, calibration offsets), so five leaves room and still catches a cloud in the wrong frame or
#: unit (millimetres, a shifted origin)
PLAUSIBLE_REACH = 5.0


def check_reach(clouds: Sequence[np.ndarray], scenario: Scenario, source: str) -> None:
    """Refuse clouds that cannot be the scenario's object: a frame whose points' median distance to the
    nearest gripper (the handles that follow a path) exceeds :data:`PLAUSIBLE_REACH` object extents. Objects
    of unknown extent are not checked.

    Raises:
        DataError: naming the frame, the distance and the fix (the recording's transform and units).
    """
    kind, size = declared_size(scenario)
    extent = size if kind == "rope" else (float(size) * np.sqrt(2) if size else None)
    if not extent:
        return
    paths = [np.asarray(h.path, float) for h in scenario.handles if h.path is not None] or [scenario.gripper]
    for t, c in enumerate(clouds):
        d = min(float(np.median(np.linalg.norm(np.asarray(c, float) - p[t], axis=1))) for p in paths)
        if d > PLAUSIBLE_REACH * extent:
            raise DataError(f"{source}: frame {t}'s points lie {d:.3g} m from the gripper (median), more than "
                            f"{PLAUSIBLE_REACH:g} times the object's extent ({extent:.2f} m): the cloud is not in the frame "
                            f"of scenario '{scenario.name}'; check the recording's transform and that its units are "
                            f"metres")


#: how far below the table (m) a recording's highest point may lie before :func:`check_table` warns: a few times a
#: depth sensor's noise on a table-top point
BELOW_TABLE = 0.02


def check_table(clouds: Sequence[np.ndarray], scenario: Scenario, source: str) -> None:
    """Warn (:class:`~softsbi.core.errors.SoftsbiWarning`, one line) when every point of every frame lies more than
    :data:`BELOW_TABLE` m below the scenario's table: the object rests on the table, so the recording's transform
    or units (or the scenario's ``world.table_z``) are likely wrong."""
    top = max(float(np.asarray(c, float)[:, 2].max()) for c in clouds)
    if top < scenario.table_z - BELOW_TABLE:
        warnings.warn(SoftsbiWarning(
            f"{source}: every point lies below the table (highest {top:.3g} m, table at {scenario.table_z:.3g} m "
            f"in scenario '{scenario.name}'): check the recording's transform (its z axis and origin) and units, "
            f"or the scenario's world.table_z"), stacklevel=2)


# ---------------------------------------------------------------------------------------------
# DiffCloud folders (an importer, not the format)
# ---------------------------------------------------------------------------------------------
def _diffcloud_task(folder: Path) -> tuple[str, Path]:
    ymls = sorted(folder.glob("*_real2sim.yaml"))
    if not ymls:
        raise DataError(f"'{folder}' holds no <task>_real2sim.yaml; a DiffCloud recording folder (such as "
                        f"../shared/data/diffcloud_lift/lift_tan) has one, or give a recording directory "
                        f"(recording.yaml)")
    return ymls[0].name[: -len("_real2sim.yaml")], ymls[0]


def diffcloud_recording(folder: str | Path, scenario: str | Path | None = None
                        ) -> tuple[dict[str, Any], list[np.ndarray]]:
    """Convert a DiffCloud recording folder into recording metadata and clouds (nothing written).

    The clouds stay in DiffCloud's simulator frame; ``transform`` is ``diag(s, s, s, 1)`` (``s`` = the
    real2sim ``scale``, 0.35 m per unit) into the scenario frame (metres). ``frames_of_reference.robot``
    is the folder's ``<task>_real2sim.yaml`` (DiffCloud convention), so a scenario whose paths are in
    the ``robot`` frame uses this recording's calibration. A lift without ``scenario`` adds its translation
    into the shared lift task to both (below). Times: DiffCloud's 0.04 s frames (assumed:
    the real timing is not in the files). Sensor: :data:`DIFFCLOUD_MIN_HEIGHT`, ``frames: auto``.

    Scenario: ``scenario`` (a name or file) when given; otherwise ``lift`` folders get the lift task that every
    lift recording of the rig shares (:func:`softsbi.scenarios.builtin.lift_task`: the parent's
    ``lift_traj.npy``), written inline, and the recording's calibration offset and grasp offset (estimated
    from the clouds) become a translation in its ``transform`` and ``frames_of_reference.robot``, so that its
    recordings share one simulation bank and one stored task; other tasks need ``scenario``.

    Raises:
        DataError: not a DiffCloud folder, malformed frames or yaml, a frame count that disagrees with
            the lift path, another task without ``scenario``.
    """
    folder = Path(folder)
    clouds = load_cloud_frames(folder)
    task, yml = _diffcloud_task(folder)
    cfg = read_yaml(yml, "fix that line (the file holds z_rotation, translation, scale and compensation_factor)")
    if not isinstance(cfg, Mapping) or not {"z_rotation", "translation", "scale"} <= set(cfg):
        raise DataError(f"{yml} must hold z_rotation, translation, scale and compensation_factor")
    dc = {"z_rotation": float(cfg["z_rotation"]), "translation": [float(v) for v in cfg["translation"]],
          "scale": float(cfg["scale"]),
          "compensation_factor": [float(v) for v in cfg.get("compensation_factor", (0, 0, 0))]}
    s = dc["scale"]
    meta: dict[str, Any] = {
        "format": "softsbi-recording/1", "units": {"length": "m", "time": "s"},
        "times": (np.arange(len(clouds)) * FRAME_DT).tolist(),
        "transform": {"matrix": [[s, 0.0, 0.0, 0.0], [0.0, s, 0.0, 0.0], [0.0, 0.0, s, 0.0], [0.0, 0.0, 0.0, 1.0]]},
        "frames_of_reference": {"robot": {"diffcloud": dc}},
        "sensor": {"kind": "depth point cloud (overhead + side RealSense, robot masked out)",
                   "min_height": DIFFCLOUD_MIN_HEIGHT, "frames": "auto"},
        "source": f"DiffCloud {task} recording {folder.name} (priyasundaresan/diffcloud_real2sim), {folder}"}
    if scenario is not None:
        p = Path(scenario)
        meta["scenario"] = {"file": str(p.resolve())} if p.suffix in (".yaml", ".yml") or p.exists() else \
            {"name": str(scenario)}
        _check_recorded_path(folder, task, scenario, dc)
        return meta, clouds
    if task != "lift":
        raise DataError(f"'{folder}' is a DiffCloud '{task}' recording: give its scenario file (e.g. "
                        f"--scenario examples/{task}.yaml); only lift folders derive their scenario from the data")
    try:
        sc, shift = lift_task(folder)
    except FileNotFoundError as exc:
        raise DataError(f"cannot build the lift scenario for '{folder}': {exc}. The recording's parent "
                        f"folder must hold lift_traj.npy") from exc
    if len(clouds) != sc.n_frames:
        raise DataError(f"'{folder}' has {len(clouds)} frames but the lift gripper path has {sc.n_frames}; "
                        f"every recorded frame needs a gripper pose (add or remove frames so the counts match)")
    # the calibration's compensation and the grasp offset are the recording's: a translation into the shared task
    move = np.eye(4)
    move[:3, 3] = shift
    meta["transform"] = {"matrix": (move @ np.asarray(meta["transform"]["matrix"])).tolist()}
    meta["frames_of_reference"] = {"robot": {"matrix": (move @ transform_matrix({"diffcloud": dc})).tolist()}}
    meta["source"] += (f"; moved by ({', '.join(f'{100 * v:+.2f}' for v in shift)}) cm into the lift task "
                       f"(calibration offset and grasp offset estimated from the clouds)")
    meta["times"] = sc.times.tolist()
    meta["scenario"] = {"inline": spec_from_scenario(sc, "DiffCloud lift (lift_traj.npy), shared by the rig's "
                                                         "recordings")}
    return meta, clouds


#: how far (as a share of the recorded gripper path's largest displacement) a scenario's gripper path may depart
#: from the path a DiffCloud recording's robot followed (``<task>_traj.npy``), both from their starts: the
#: built-in lift's keyframes follow lift_traj.npy within 2% (7.7 mm of 0.37 m); a fold's path departs from a
#: lift's by 150%
PATH_TOLERANCE = 0.1


def _check_recorded_path(folder: Path, task: str, scenario: str | Path, real2sim: Mapping[str, Any]) -> None:
    """Refuse a scenario whose gripper does not follow the path the recording's robot followed (the task's
    ``<task>_traj.npy`` beside the recording, robot frame, mapped with the recording's ``real2sim``); nothing
    to check without that file or when the frame counts differ (the recording's loading names those).

    Raises:
        DataError: the paths' displacements from their starts differ by more than :data:`PATH_TOLERANCE` of
            the recorded one's largest.
    """
    traj_file = folder.parent / f"{task}_traj.npy"
    if not traj_file.is_file():
        return
    m = transform_matrix({"diffcloud": dict(real2sim)})
    sc = load_scenario(scenario, {"robot": m})
    traj = apply_transform(m, read_npy(traj_file, "gripper path"))
    if traj.shape != sc.gripper.shape:
        return
    moved = np.linalg.norm(traj - traj[0], axis=1).max()
    off = np.linalg.norm((sc.gripper - sc.gripper[0]) - (traj - traj[0]), axis=1).max()
    if off > PATH_TOLERANCE * moved:
        raise DataError(f"'{folder}' is a DiffCloud {task} recording, but the gripper of scenario '{sc.name}' "
                        f"({scenario}) does not follow its robot's path ({traj_file.name}): they part by up to "
                        f"{off:.2f} m; give the scenario this recording was made in"
                        + (" (a lift folder needs no --scenario)" if task == "lift" else ""))


def diffcloud_calibration(folder: str | Path) -> dict[str, Any] | None:
    """The RealSense calibration beside a DiffCloud recording (``calib_<camera>/`` in its parent folder:
    ``intrinsics.npy`` ``(fx, fy, cx, cy)`` px and ``tcr.npy``, the 3x4 camera -> robot-base transform, m),
    or None when there is none."""
    cams = {}
    for d in sorted(Path(folder).parent.glob("calib_*")):
        if (d / "intrinsics.npy").is_file() and (d / "tcr.npy").is_file():
            k = read_npy(d / "intrinsics.npy", "camera intrinsics").astype(float).ravel()
            cams[d.name[len("calib_"):]] = {
                "intrinsics": {"fx": float(k[0]), "fy": float(k[1]), "cx": float(k[2]), "cy": float(k[3])},
                "robot_from_camera": read_npy(d / "tcr.npy", "camera extrinsics").astype(float).tolist(),
                "source": str(d)}
    if not cams:
        return None
    return {"frame": "robot", "note": "robot_from_camera maps camera-frame points (m) into the robot base frame "
                                      "(DiffCloud's tcr.npy); frames_of_reference.robot maps those into the "
                                      "scenario frame", "cameras": cams}


def import_diffcloud(src: str | Path, dst: str | Path, scenario: str | Path | None = None) -> list[Path]:
    """``softsbi import diffcloud``: convert DiffCloud recordings into recording directories.

    Args:
        src: one recording folder (``.../diffcloud_lift/lift_tan``) or a folder of them
            (``.../diffcloud_fold``): each subfolder holding ``NNN.npy`` and ``<task>_real2sim.yaml``.
        dst: for one recording, its new directory; for a folder, the parent of one directory per recording.
        scenario: the scenario (name or file) of every recording; needed for tasks other than lift
            (:func:`diffcloud_recording`).

    Returns:
        the written recording directories.

    Raises:
        DataError: no DiffCloud recording in ``src`` (or ``src`` is already a recording), an existing non-empty
            destination, anything
            :func:`diffcloud_recording` raises. Everything is converted before anything is written.
        RunDirError: a destination that is a file or cannot be written (before anything is converted).
    """
    src, dst = Path(src), Path(dst)
    if not src.is_dir():
        raise DataError(f"'{src}' {'is a file' if src.exists() else 'does not exist'}; give a DiffCloud recording "
                        f"folder or a folder of them")
    if is_recording(src):
        raise DataError(f"'{src}' is already a softsbi recording (it holds recording.yaml): nothing to import; fit it "
                        f"directly with `softsbi fit --observed {src} --out RUN`")
    if sorted(src.glob("*_real2sim.yaml")) and any(f.stem.isdigit() for f in src.glob("*.npy")):
        pairs = [(src, dst)]
    else:
        pairs = [(d, dst / d.name) for d in sorted(src.iterdir())
                 if d.is_dir() and any(f.stem.isdigit() for f in d.glob("*.npy"))]
        if not pairs:
            raise DataError(f"'{src}' holds no DiffCloud recording (folders with 000.npy ... and "
                            f"<task>_real2sim.yaml)")
    for _, out in pairs:  # the destinations first: nothing is converted for a destination that cannot take it
        check_out_dir(out, "destination", "choose a writable destination")
        if out.exists() and any(out.iterdir()):
            raise DataError(f"'{out}' exists and is not empty; choose a new destination or remove it")
    converted = [(d, out, *diffcloud_recording(d, scenario)) for d, out in pairs]
    written = []
    for d, out, meta, clouds in converted:
        if "file" in meta["scenario"]:  # relative to the recording, so the pair can move together
            meta["scenario"]["file"] = os.path.relpath(meta["scenario"]["file"], out.resolve())
        written.append(write_recording(out, meta, clouds, calibration=diffcloud_calibration(d)))
    return written


def simulate_recording(backend: str = BACKEND, scenario: Scenario | str | Path = SCENARIO,
                         truth: Mapping[str, float] | None = None, backend_options: Mapping | None = None,
                         effects: Sequence[str] = (), n_points: int = 64, n_dense: int = N_DENSE, noise: float = 0.0,
                         seed: int = 12345) -> Recording:
    """A synthetic measurement: ``scenario`` simulated at hidden parameters ``truth``.

    Args:
        backend: simulator plugin name.
        scenario: a :class:`Scenario`, or a built-in scenario's name or a scenario file's path.
        truth: hidden values of the backend's parameters and those of ``effects`` (hidden effects make a
            measurement the nominal model cannot explain); a parameter not given takes the value ``softsbi
            simulate`` gives it (:func:`default_values`: ``scale`` at the scenario's
            object size, the others at their prior midpoint). The recording's ``truth`` holds every value used.
        noise: Gaussian noise std (m) added to the observed points.

    Raises:
        SimulationFailed: the hidden-parameter simulation itself failed. ParameterError: a value of ``truth`` outside
            its physical limits, or a name that is not a parameter. PluginNotFound: unknown backend or effect.
    """
    if not isinstance(scenario, Scenario):
        scenario = make_scenario(str(scenario))
    reg = registry()
    sim = reg.simulator(backend)(**dict(backend_options or {}))
    space = rollout_space(sim, scenario, effects)
    values = {**default_values(space, scenario), **dict(truth or {})}
    truth = space.check(values, within="limits")
    ro = sim.simulate(scenario, dict(truth), effects=list(effects), seed=seed)
    if not ro.ok:
        raise SimulationFailed(f"the measurement simulation failed: {ro.reason}")
    rng = np.random.default_rng(seed)
    obs = PointCloudObserver(n_points, noise=noise).observe(ro, rng)
    dense = rollout_clouds(ro, n_dense, rng)
    if rollout_arm_radius(ro) is not None:
        # a hidden arm mask hides the cloth near the gripper: n_dense seen points of a 4x denser sample per frame, so
        # that the seen surface is sampled as the metric samples it, no point repeated (redrawn only if too few)
        seen = effect_views(rollout_clouds(ro, 4 * n_dense, rng), ro)
        dense = np.stack([v[:n_dense] if len(v) >= n_dense else v[rng.integers(len(v), size=n_dense)] for v in seen])
    effect_z = rollout_min_z(ro)
    if effect_z is not None:  # a hidden sensor effect hides points (table-unseen): the seen ones, redrawn
        dense = np.stack([seen_resampled(c, effect_z, rng) for c in dense])
    if noise > 0:
        dense = dense + rng.normal(0, noise, dense.shape)
    src = f"simulated:{backend}" + (f"+{'+'.join(effects)}" if effects else "")
    return Recording(scenario=scenario, x=obs.state(), dense=dense, source=src, truth=dict(truth))


def load_image_recording(folder: str | Path, scenario: str | Path | Scenario | None = "wipe", size: int = IMAGE_SIZE,
                           camera: "Camera | None" = None) -> Recording:
    """A folder of RGB frames (real or rendered) as a :class:`Recording` for image observers.

    The gripper path is the scenario's (the robot's commanded path, as for the real lift): the
    frames only add what the camera saw.

    Args:
        folder: ``000.png, 001.png, ...`` (or ``.jpg``), one frame per scenario frame; or a recording
            directory with ``images/`` (its scenario, calibration and truth are used).
        scenario: the task (name, file or :class:`Scenario`) the frames were recorded in; None: the
            recording directory's own (``lift`` for a plain folder of frames).
        size: square size of the scenario's camera when ``camera`` is None; frames are
            resized to the camera's size.

    Returns:
        Recording with ``images (T, H, W, 3)`` uint8, ``x = None`` (the observer builds it from the
        frames), ``dense = None``, ``truth`` from ``folder/truth.json`` when present (rendered
        measurements written by ``softsbi simulate --render``).

    Raises:
        DataError: see :func:`~softsbi.perception.images.load_frames`; a frame count different from
            the scenario's.
    """
    if is_recording(folder):
        data = read_recording(folder)
        if data.images is None:
            raise DataError(f"recording '{folder}' has no images/ (000.png ...); image observers need one RGB frame "
                            f"per frame (`softsbi simulate --render SIZE --out DIR` writes them)")
        sc = scenario_of(data.meta, Path(folder), str(folder), scenario)
        cam = camera or scenario_camera(sc, size)
        images = np.stack([im if im.shape[:2] == (cam.height, cam.width) else
                           cv2.resize(im, (cam.width, cam.height), interpolation=cv2.INTER_AREA) for im in data.images])
        if len(images) != sc.n_frames:
            raise DataError(f"'{folder}' has {len(images)} frames but scenario '{sc.name}' records {sc.n_frames}; "
                            f"give one frame per scenario frame")
        return Recording(scenario=sc, x=None, dense=None, source=str(folder), truth=data.meta.truth, images=images)
    scenario = "lift" if scenario is None else scenario
    sc = make_scenario(str(scenario)) if isinstance(scenario, (str, Path)) else scenario
    cam = camera or scenario_camera(sc, size)
    images = load_frames(folder, size=(cam.width, cam.height))
    if len(images) != sc.n_frames:
        raise DataError(f"'{folder}' has {len(images)} frames but scenario '{sc.name}' records {sc.n_frames}; "
                        f"give one frame per scenario frame")
    truth_file = Path(folder) / "truth.json"
    truth = json.loads(truth_file.read_text()) if truth_file.is_file() else None
    return Recording(scenario=sc, x=None, dense=None, source=str(folder), truth=truth, images=images)


def render_recording(backend: str, scenario: Scenario, truth: Mapping[str, float], size: int = 128,
                       camera: "Camera | None" = None, style: "RenderStyle | None" = None,
                       backend_options: Mapping | None = None, effects: Sequence[str] = (),
                       n_dense: int = N_DENSE, seed: int = 12345) -> Recording:
    """A rendered measurement: ``scenario`` simulated at hidden parameters ``truth`` and rendered.

    Returns:
        Recording with ``images (T, H, W, 3)`` uint8 and also ``dense (T, n_dense, 3)`` m (the
        3-D truth, for reference), ``truth``.

    Raises:
        SimulationFailed: the hidden-parameter simulation failed.
    """
    cam = camera or scenario_camera(scenario, size)
    sim = registry().simulator(backend)(**dict(backend_options or {}))
    ro = sim.simulate_images(scenario, dict(truth), camera=cam, style=style, effects=list(effects), seed=seed)
    if not ro.ok:
        raise SimulationFailed(f"the measurement simulation failed: {ro.reason}")
    dense = rollout_clouds(ro, n_dense, np.random.default_rng(seed))
    src = f"rendered:{backend}" + (f"+{'+'.join(effects)}" if effects else "")
    return Recording(scenario=scenario, x=None, dense=dense, source=src, truth=dict(truth), images=ro.rgb)
