"""Engine-independent scenario construction for the cloth *lift* task (DiffCloud data).

The lift frame and the table height: :mod:`softsbi.scenarios.diffcloud` (a recording's real -> simulator
transform).

Gripper path (``Scenario.gripper``)
-----------------------------------
``lift_traj.npy`` (25 commanded end-effector positions, robot frame) mapped into the lift frame.
The commanded end-effector point is *not* where the cloth corner is: in the last frames (the
corner is then the cloud's highest point) the top 1 % of the cloud sits at a constant offset
from the mapped path - (-5.7, -2.4, -0.3) cm for navy/paper/polka/tan (spread 0.2 cm over frames
18-24), about (-3, 0, -4.5) cm for tan2/redblack*. With ``grasp_offset="data"`` (the default)
the horizontal part of this per-recording offset is added to the whole path, so the simulated
corner follows the real corner; the vertical part is only recorded in ``options`` (applying it
would put the start below the table). Cross-check: for lift_tan the offset-corrected start
(-1.0, 10.2) cm equals DiffCloud's own placement of the grasped node (node 13 of
``cloth_diamond_flat.obj`` at (0.07, 10.7) cm in the lift frame) within 1.2 cm, while the
commanded start (5.0, 12.7) cm is 5 cm away.
``grasp_offset="none"`` keeps the commanded path.

Cloth geometry (``Scenario.object``)
------------------------------------
From DiffCloud's ARCSim scene ``arcsim_lift_demo_diamond25.json``: the cloth is
``cloth_diamond_flat.obj``, a 7x7-vertex square rotated by 45 deg in the simulator frame, the
handle on node 13 (0-based; the corner at (0.002, 0.304) sim units, the diamond's +y tip).
Its diagonal is 1.1220 sim units, i.e. side ``1.1220 / sqrt(2) * 0.35 = 0.2777 m``
(:data:`NOMINAL_SIZE`), and the diagonal from the grasped corner to the opposite corner
(0.002, -0.818) points along ``(0, -1)`` (:data:`NOMINAL_DIRECTION`) - the direction in which
the gripper also moves back. The grasped corner is placed under the gripper's start
(``corner = gripper[0, :2]``). The last real frames agree: the hanging sheet spans about
0.35-0.36 m across x (its horizontal diagonal), i.e. a side of about 0.25-0.28 m.

Placement (``yaw``)
-------------------
DiffCloud's diamond is *its* placement; the real cloths were laid by hand and their diagonal
from the grasped corner does not point along ``(0, -1)``. Measured on the early frames (cloth still on
the table, 20 prior draws of the other parameters): rotating the diagonal by +30 deg lowers the
lift_tan Chamfer of frames 0-9 from 5.67 to 2.58 cm, lift_tan2 prefers -20 deg (4.18 -> 3.47 cm)
and lift_navy +45 deg (9.78 -> 6.89 cm). Scenarios built from a recording therefore carry
``object["yaw_bounds"] = YAW_BOUNDS`` (deg), and the backends then add a parameter ``yaw``: the
rotation of the cloth's diagonal about the grasped corner, counter-clockwise seen from above,
relative to ``object["direction"]`` (:func:`placed_direction`). The built-in default keeps the
nominal placement (no ``yaw``); any cloth scenario can opt in by setting ``yaw_bounds``.
The early frames alone overstate the rotation: they show only raised fragments of the cloth (the
flat parts are below the recording's crop plane), and a cloth rotated to cover them then hangs
crossed to the real one in frames 15-24. ``softsbi fit``'s default (hanging frames inform the
posterior) infers lift_tan's yaw at about +6 to +9 deg.

Timing
------
The real timing is not in the files. We assume DiffCloud's: 25 frames 0.04 s apart, 1 s in
total (``frame_time`` of the ARCSim scene), so ``times = arange(n_frames) * frame_dt``. With
ARCSim's gravity of 30 units/s^2 = 10.5 m/s^2 this is ordinary gravity in metres. When
``n_frames != 25`` the recorded path is resampled (linear) over the same normalised progress.

Built-in default (``lift_scenario(None)``)
------------------------------------------
Needs no data files: the commanded start/end points of ``lift_traj.npy`` mapped with the
default ``lift_real2sim.yaml`` (stored here as constants), joined by a smooth analytic curve
(a straight segment with a delayed smoothstep easing fitted to
the recorded profile - within 0.8 cm of it), with the table from the same default
convention (``c_z = 0`` -> ``table_z = 0.07497 m``) and no data-derived grasp offset.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from softsbi.core.arrays import read_npy
from softsbi.core.errors import DataError, closest
from softsbi.core.types import Param, Scenario
# a DiffCloud recording's transforms and clouds (softsbi.scenarios.diffcloud), importable from here too
from softsbi.scenarios.diffcloud import (DEFAULT_TRANSFORM, PLANE_REFERENCE_CZ, PLANE_Z_SIM, SIM_SCALE,  # noqa: F401
                                         TABLE_Z_REAL, check_transform, estimate_grasp_offset, lift_frame_to_real,
                                         load_recording, real_to_lift_frame, real_to_sim, recording_transform,
                                         sim_units_to_metres, table_height)
from softsbi.scenarios.catalog import current_name, load_scenario
from softsbi.scenarios.schema import parse_spec, read_scenario_yaml
from softsbi.scenarios.spec import camera_dicts

#: ARCSim cloth (cloth_diamond_flat.obj): diagonal 1.12203 sim units -> side in metres
NOMINAL_SIZE = 1.122032 / np.sqrt(2.0) * SIM_SCALE
#: unit vector from the grasped corner (node 13) to the opposite corner, lift frame
NOMINAL_DIRECTION = (0.0, -1.0)
#: the ARCSim grasped corner (node 13) in the lift frame, metres
ARCSIM_CORNER = (0.002075 * SIM_SCALE, 0.304429 * SIM_SCALE)
#: DiffCloud's frame spacing (ARCSim frame_time), s
FRAME_DT = 0.04
#: prior bounds (deg) of the cloth's placement yaw about the grasped corner for real recordings
YAW_BOUNDS = (-45.0, 45.0)
N_FRAMES = 25

#: the real robot's shoulder in its base frame (m): where the visual arm of rendered lift images stands
ROBOT_BASE_REAL = (0.0, 0.0, 0.33)
#: first and last rows of lift_traj.npy (robot frame, m): the only recorded numbers the default uses
_TRAJ_START = (0.56344985, 0.15072625, 0.07796145)
_TRAJ_END = (0.75582497, 0.15036571, 0.38734047)


# --------------------------------------------------------------------------------------------
# scenarios
# --------------------------------------------------------------------------------------------
def placed_direction(scenario: Scenario, theta: Mapping[str, float] | None = None) -> np.ndarray:
    """Unit vector ``(2,)`` of the cloth's diagonal from the grasped corner, in the world/lift frame.

    ``object["direction"]`` (default ``(0, -1)``) rotated counter-clockwise (seen from above) by
    ``theta["yaw"]`` degrees when the parameter is present (see "Placement" in the module docstring).

    Raises:
        DataError: a zero-length ``object["direction"]``.
    """
    d = np.asarray(scenario.object.get("direction", NOMINAL_DIRECTION), dtype=float)
    n = float(np.linalg.norm(d))
    if not n > 0:
        raise DataError(f"scenario object 'direction' must be a non-zero 2-vector, got {d.tolist()}")
    d = d / n
    yaw = float((theta or {}).get("yaw", 0.0))
    if yaw:
        a = np.deg2rad(yaw)
        d = np.array([np.cos(a) * d[0] - np.sin(a) * d[1], np.sin(a) * d[0] + np.cos(a) * d[1]])
    return d


def placement_params(scenario: Scenario) -> list[Param]:
    """The placement parameter ``yaw`` [deg] if ``scenario.object`` has ``"yaw_bounds"``, else ``[]``.

    Raises:
        DataError: ``yaw_bounds`` is not two increasing finite numbers.
    """
    b = scenario.object.get("yaw_bounds")
    if b is None:
        return []
    try:
        lo, hi = (float(v) for v in b)
    except (TypeError, ValueError) as exc:
        raise DataError(f"scenario object 'yaw_bounds' must be [low, high] in degrees, got {b!r}") from exc
    if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
        raise DataError(f"scenario object 'yaw_bounds' must be increasing finite degrees, got {b!r}")
    return [Param("yaw", lo, hi, "deg", description="cloth placement: rotation of its diagonal about the "
                  "grasped corner, counter-clockwise from above, relative to the scenario's direction")]


def _resample(path: np.ndarray, n_frames: int) -> np.ndarray:
    if n_frames == len(path):
        return path.copy()
    src = np.linspace(0.0, 1.0, len(path))
    dst = np.linspace(0.0, 1.0, n_frames)
    return np.stack([np.interp(dst, src, path[:, k]) for k in range(3)], axis=1)


def default_gripper_path(n_frames: int = N_FRAMES) -> np.ndarray:
    """Analytic approximation of the recorded lift, lift frame (default transform), ``(n_frames, 3)`` m.

    The recorded path is a straight segment (horizontal and vertical progress agree to 0.1 %);
    progress ``u = t / T in [0, 1]`` is eased by :func:`_ease` (delayed smoothstep). Start and
    end are the mapped first/last commanded points; within 0.8 cm of the full recorded path.
    """
    if n_frames < 2:
        raise ValueError(f"n_frames must be >= 2, got {n_frames}")
    a = real_to_lift_frame(np.asarray(_TRAJ_START), DEFAULT_TRANSFORM)
    b = real_to_lift_frame(np.asarray(_TRAJ_END), DEFAULT_TRANSFORM)
    u = np.linspace(0.0, 1.0, n_frames)
    h = _ease(u)
    out = a + h[:, None] * (b - a)
    return out


def _ease(u: np.ndarray) -> np.ndarray:
    """Smooth 0->1 easing of the recorded lift's progress: a smoothstep ``3w^2 - 2w^3`` that starts
    after a delay of 4 % of the duration (the recorded path does not move between its first two
    frames), ``w = clip((u - 0.04) / 0.96, 0, 1)``. Max deviation from the recorded path: 0.8 cm."""
    w = np.clip((np.asarray(u, dtype=float) - _EASE_DELAY) / (1.0 - _EASE_DELAY), 0.0, 1.0)
    return w * w * (3.0 - 2.0 * w)


_EASE_DELAY = 0.04


def lift_scenario(recording: str | Path | None = None, n_frames: int = N_FRAMES, frame_dt: float = FRAME_DT,
                  grasp_offset: str = "data") -> Scenario:
    """The cloth-lift scenario, in the lift frame (metres, z up; see the module docstring).

    Args:
        recording: a DiffCloud recording folder (``.../diffcloud_lift/lift_tan``; its parent holds
            ``lift_traj.npy``), or None for the built-in default that needs no files.
        n_frames: number of recorded frames ``T`` (the path is resampled if != 25).
        frame_dt: seconds between frames (DiffCloud's 0.04 s assumed; the real timing is unknown).
        grasp_offset: ``"data"`` (shift the path horizontally by the offset between commanded
            end effector and real grasped corner estimated from the recording) or ``"none"``.
            Ignored for the built-in default.

    Returns:
        :class:`Scenario` named ``"lift"``: ``times (T,)`` s, ``gripper (T, 3)`` m, ``table_z`` m,
        ``object = {"kind": "cloth", "size", "corner", "direction", "grasp": "corner"}`` (plus
        ``"yaw_bounds"`` (deg) for a recording: its placement is inferred) and
        ``options`` with the provenance (recording, transform, offsets).

    Raises:
        DataError: recording folder / files missing or malformed.
        ValueError: ``n_frames < 2``, ``frame_dt <= 0`` or an unknown ``grasp_offset``.
    """
    if n_frames < 2:
        raise ValueError(f"n_frames must be >= 2, got {n_frames}")
    if not frame_dt > 0:
        raise ValueError(f"frame_dt must be > 0, got {frame_dt}")
    if grasp_offset not in ("data", "none"):
        raise ValueError(f"grasp_offset must be 'data' or 'none', got {grasp_offset!r}")
    times = np.arange(n_frames) * float(frame_dt)
    options: dict[str, Any] = {"timing": f"assumed DiffCloud timing: frames {frame_dt} s apart",
                               "frame": "lift frame = DiffCloud simulator frame x 0.35 m"}
    if recording is None:
        gripper = default_gripper_path(n_frames)
        cfg = check_transform(DEFAULT_TRANSFORM)
        table_z = table_height(cfg)
        options.update(source="built-in default (analytic path, default lift_real2sim.yaml)")
    else:
        rec = Path(recording)
        if not rec.is_dir():
            raise DataError(f"recording folder {rec} does not exist")
        traj_file = rec.parent / "lift_traj.npy"
        if not traj_file.is_file():
            raise DataError(f"{traj_file} not found: lift_traj.npy must be in the recording's parent folder")
        traj = read_npy(traj_file, "gripper path", "save the (T, 3) path in metres with numpy.save")
        if traj.ndim != 2 or traj.shape[1] != 3:
            raise DataError(f"{traj_file} must be (T, 3), got {traj.shape}")
        cfg = recording_transform(rec)
        commanded = real_to_lift_frame(traj, cfg)
        table_z = table_height(cfg)
        offset = np.zeros(3)
        if (rec / "024.npy").is_file() and len(commanded) == N_FRAMES:
            est = estimate_grasp_offset(rec, commanded)
            options["grasp_offset_estimate"] = est.tolist()
            if grasp_offset == "data":
                offset[:2] = est[:2]
        elif grasp_offset == "data":
            options["grasp_offset_note"] = "no frames to estimate the grasp offset from; commanded path used"
        gripper = _resample(commanded + offset, n_frames)
        options.update(source=str(rec), recording=rec.name, grasp_offset_applied=offset.tolist(),
                       transform={k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in cfg.items()})
    obj = {"kind": "cloth", "size": float(NOMINAL_SIZE), "corner": [float(gripper[0, 0]), float(gripper[0, 1])],
           "direction": [float(NOMINAL_DIRECTION[0]), float(NOMINAL_DIRECTION[1])], "grasp": "corner"}
    if recording is not None:  # the real placement is unknown: infer its yaw (module docstring)
        obj["yaw_bounds"] = [float(YAW_BOUNDS[0]), float(YAW_BOUNDS[1])]
    options["robot_base"] = real_to_lift_frame(np.asarray(ROBOT_BASE_REAL), cfg).tolist()
    return Scenario(name="lift", times=times, gripper=gripper, table_z=float(table_z), object=obj,
                    options=options, **declared("lift"))


#: how far (m) the recording's commanded path may depart from a translation of the task's before a recording keeps
#: its own lift (a calibration that rotates or scales, not one of DiffCloud's compensation offsets); float round-off
#: of the two mappings is ~1e-16 m
TRANSLATION_TOLERANCE = 1e-9


def lift_task(recording: str | Path, n_frames: int = N_FRAMES,
              frame_dt: float = FRAME_DT) -> tuple[Scenario, np.ndarray]:
    """The lift task that every DiffCloud lift recording of the rig shares, and where ``recording`` lies in it.

    The recordings follow one commanded path (the parent folder's ``lift_traj.npy``). They differ by their
    calibration (``lift_real2sim.yaml``'s ``compensation_factor``: a translation) and by where the gripper held
    the cloth (the horizontal grasp offset, :func:`~softsbi.scenarios.diffcloud.estimate_grasp_offset`). Both move
    the whole scene rigidly, and the simulation is invariant under such a move: the table is a horizontal plane,
    gravity points along -z and the sensor's height cut is measured from the table. So both belong to the
    recording (its transform), not to the task, and recordings of the task share simulations and trained models.

    The task's frame is the commanded path under :data:`DEFAULT_TRANSFORM` with no grasp offset. Of the
    recording, the scenario holds only its folder as ``options["source"]``, the provenance that a task's identity
    and the simulation bank's keys leave out (:data:`~softsbi.workflows.fit.config.SCENARIO_PROVENANCE`).

    Args:
        recording: a DiffCloud lift recording folder (as :func:`lift_scenario`).
        n_frames, frame_dt: as :func:`lift_scenario`.

    Returns:
        ``(scenario, translation)``: the task's :class:`Scenario` (``lift``, with ``yaw_bounds``) and the
        translation ``(3,)`` m that carries points of the recording's own lift frame (:func:`lift_scenario` of
        it, grasp offset applied) into the task's frame. When the recording's calibration is not a translation of
        the default one (more than :data:`TRANSLATION_TOLERANCE` apart), the recording's own lift and a zero
        translation.

    Raises:
        DataError, ValueError: as :func:`lift_scenario`.
    """
    own = lift_scenario(recording, n_frames, frame_dt)
    traj = read_npy(Path(recording).parent / "lift_traj.npy", "gripper path")
    path = real_to_lift_frame(traj, DEFAULT_TRANSFORM)
    moved = path - real_to_lift_frame(traj, recording_transform(recording))
    if np.abs(moved - moved[0]).max() > TRANSLATION_TOLERANCE:
        return own, np.zeros(3)
    gripper = _resample(path, n_frames)  # computed, not shifted: the same bits for every recording
    shift = gripper[0] - own.gripper[0]
    obj = {**own.object, "corner": [float(gripper[0, 0]), float(gripper[0, 1])]}
    options = {k: own.options[k] for k in ("timing", "frame")}
    options.update(source=own.options["source"], transform=dict(DEFAULT_TRANSFORM),
                   robot_base=real_to_lift_frame(np.asarray(ROBOT_BASE_REAL), DEFAULT_TRANSFORM).tolist())
    task = Scenario(name="lift", times=own.times, gripper=gripper, table_z=float(table_height(DEFAULT_TRANSFORM)),
                    object=obj, options=options, **declared("lift"))
    return task, shift


# --------------------------------------------------------------------------------------------
# overlay
# --------------------------------------------------------------------------------------------
# --------------------------------------------------------------------------------------------
# the other scenarios of the paper: wipe, winding, fling (synthetic, engine-independent)
# --------------------------------------------------------------------------------------------
#: scenario names :func:`make_scenario` builds
SCENARIOS = ("lift", "wipe", "winding", "fling")

#: table height of the synthetic scenarios (world frame, m)
SYNTH_TABLE_Z = 0.0


def _keyframe_path(key_t: np.ndarray, key_p: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Piecewise path through keyframes ``key_p (K, 3)`` at ``key_t (K,)`` s, sampled at ``times``.

    Each segment is eased with a smoothstep ``3w^2 - 2w^3`` so the gripper starts and stops every
    segment at zero velocity (no velocity jumps for the engines to absorb).
    """
    out = np.empty((len(times), 3))
    for k, t in enumerate(times):
        i = int(np.clip(np.searchsorted(key_t, t, side="right") - 1, 0, len(key_t) - 2))
        w = float(np.clip((t - key_t[i]) / (key_t[i + 1] - key_t[i]), 0.0, 1.0))
        w = w * w * (3.0 - 2.0 * w)
        out[k] = key_p[i] + w * (key_p[i + 1] - key_p[i])
    return out


def wipe_scenario(n_frames: int = 31, duration: float = 1.5, size: float = 0.30, drag: float = 0.30,
                  sweep: float = 0.15) -> Scenario:
    """A thick cloth dragged across the table by one corner (BayesSim-RKHS *wiping*, Antonova et al. 2022).

    Geometry (world frame, metres, table top at z = 0): a square cloth of side ``size`` lies flat
    with its grasped corner at the origin and its diagonal along ``direction = (-1, 0)`` (the
    cloth trails behind the gripper). Gripper path, smoothstep-eased keyframes:

    * 0 -> 13 % of ``duration``: the corner is lifted 2 cm (the hand closes on the cloth);
    * -> 73 %: dragged ``drag`` m along +x at 2 cm height (the wipe stroke);
    * -> 100 %: a sideways sweep of ``sweep`` m along +y (the end of a wiping curve).

    "Thick" is a property of the fabric, i.e. of the parameters (upper part of the bend and mass
    priors), not of the geometry; the backends use their usual cloth priors.

    Returns:
        :class:`Scenario` ``"wipe"`` with ``times (n_frames,)`` s, ``gripper (n_frames, 3)`` m,
        ``object = {"kind": "cloth", "size", "corner", "direction", "grasp": "corner"}``.

    Raises:
        ValueError: ``n_frames < 2`` or non-positive sizes / duration.
    """
    _check_synth(n_frames, duration, size)
    times = np.linspace(0.0, duration, n_frames)
    h = 0.02
    key_t = np.array([0.0, 0.13, 0.73, 1.0]) * duration
    key_p = np.array([[0, 0, 0], [0, 0, h], [drag, 0, h], [drag, sweep, h]], dtype=float)
    key_p[:, 2] += SYNTH_TABLE_Z
    obj = {"kind": "cloth", "size": float(size), "corner": [0.0, 0.0], "direction": [-1.0, 0.0],
           "grasp": "corner", "fabric": "thick"}
    gripper = _keyframe_path(key_t, key_p, times)
    # the visual arm: 0.45 m beyond the stroke's far end along the drag direction +x (the cloth trails away
    # from the robot, as in the real wiping images), 0.5 m above the table
    base = [float(gripper[:, 0].max() + 0.45), float(gripper[:, 1].mean()), SYNTH_TABLE_Z + 0.5]
    return Scenario(name="wipe", times=times, gripper=gripper, table_z=SYNTH_TABLE_Z,
                    object=obj, options={"source": "synthetic wipe (softsbi.scenarios.builtin.wipe_scenario)",
                                         "frame": "world, table top at z = 0", "robot_base": base},
                    **declared("wipe"))


def fling_scenario(n_frames: int = 36, duration: float = 1.4, size: float = 0.28) -> Scenario:
    """A cloth flung up by one corner, lowered onto the table and dragged over it (paper's *fling*).

    Geometry (world frame, m, table top z = 0): square cloth of side ``size`` flat on the table,
    grasped corner at the origin, diagonal along ``direction = (-1, 0)``. Keyframes (fraction of
    ``duration``: position relative to the corner), smoothstep-eased:

    * 0.00: (0, 0, 0) start;   0.25: (-0.05, 0, 0.35) swing up and slightly back (the cloth hangs);
    * 0.43: (0.10, 0, 0.40) fling forward at the top (the cloth unfurls ahead);
    * 0.68: (0.25, 0, 0.06) lower it onto the table;   1.00: (0.45, 0, 0.02) drag it along +x.

    Returns:
        :class:`Scenario` ``"fling"``; ``object`` as in :func:`wipe_scenario`.

    Raises:
        ValueError: ``n_frames < 2`` or non-positive size / duration.
    """
    _check_synth(n_frames, duration, size)
    times = np.linspace(0.0, duration, n_frames)
    key_t = np.array([0.0, 0.25, 0.43, 0.68, 1.0]) * duration
    key_p = np.array([[0, 0, 0], [-0.05, 0, 0.35], [0.10, 0, 0.40], [0.25, 0, 0.06], [0.45, 0, 0.02]])
    key_p[:, 2] += SYNTH_TABLE_Z
    obj = {"kind": "cloth", "size": float(size), "corner": [0.0, 0.0], "direction": [-1.0, 0.0], "grasp": "corner"}
    return Scenario(name="fling", times=times, gripper=_keyframe_path(key_t, key_p, times), table_z=SYNTH_TABLE_Z,
                    object=obj, options={"source": "synthetic fling (softsbi.scenarios.builtin.fling_scenario)",
                                         "frame": "world, table top at z = 0"}, **declared("fling"))


def winding_scenario(n_frames: int = 26, duration: float = 2.0, length: float = 0.40, turns: float = 1.25,
                     spool_radius: float = 0.03, spool_height: float = 0.08, rope_radius: float = 0.004) -> Scenario:
    """A flexible rope wound onto a spool (a fixed rigid cylinder), partly occluded by it (paper's *winding*).

    Geometry (world frame, m, table top z = 0): a vertical rigid cylinder (``spool``: centre (0, 0),
    radius ``spool_radius``, height ``spool_height``) stands on the table. The rope (``length`` m,
    cross-section radius ``rope_radius``) lies straight on the table, tangent to a circle of radius
    ``rho = spool_radius + 3 * rope_radius`` around the spool: its grasped end (vertex 0) at
    ``(rho, 0)``, the rest along ``direction = (0, -1)``. The gripper carries the grasped end
    counter-clockwise around the spool on that circle, ``turns`` turns at constant angular speed
    (after a smoothstep start-up over the first 10 %), at the rope's height; the trailing rope is
    pulled against the cylinder and wraps around it.

    Occlusion: the spool hides the part of the rope behind it from any camera; its geometry is in
    ``object["spool"]`` so observers can remove occluded points. The backends return *all*
    vertices.

    Returns:
        :class:`Scenario` ``"winding"`` with ``object = {"kind": "rope", "length", "radius", "start",
        "direction", "grasp": "end", "spool": {"centre", "radius", "height"}}``.

    Raises:
        ValueError: ``n_frames < 2`` or non-positive sizes / duration.
    """
    _check_synth(n_frames, duration, length)
    if not (spool_radius > 0 and spool_height > 0 and rope_radius > 0):
        raise ValueError("spool_radius, spool_height and rope_radius must be > 0")
    times = np.linspace(0.0, duration, n_frames)
    rho = spool_radius + 3.0 * rope_radius
    u = times / duration
    # angle: smoothstep start-up over 10 % of the duration, then constant angular speed
    ramp = 0.1
    w = np.where(u < ramp, u * u / (2 * ramp), u - ramp / 2) / (1 - ramp / 2)
    phi = 2 * np.pi * turns * w
    z = SYNTH_TABLE_Z + rope_radius
    gripper = np.stack([rho * np.cos(phi), rho * np.sin(phi), np.full_like(phi, z)], axis=1)
    obj = {"kind": "rope", "length": float(length), "radius": float(rope_radius), "start": [float(rho), 0.0],
           "direction": [0.0, -1.0], "grasp": "end",
           "spool": {"centre": [0.0, 0.0], "radius": float(spool_radius), "height": float(spool_height)}}
    return Scenario(name="winding", times=times, gripper=gripper, table_z=SYNTH_TABLE_Z, object=obj,
                    options={"source": "synthetic winding (softsbi.scenarios.builtin.winding_scenario)",
                             "frame": "world, table top at z = 0", "occluder": "object['spool']"},
                    **declared("winding"))


def declared(name: str) -> dict[str, Any]:
    """What the built-in scenario file ``files/<name>.yaml`` declares for seeing the scenario, ``cameras`` and
    ``view`` (:class:`Scenario` fields), so the reference constructors here render and draw it as the file
    does."""
    path = Path(__file__).parent / "files" / f"{name}.yaml"
    spec = parse_spec(read_scenario_yaml(path), str(path))
    return {"cameras": camera_dicts(spec.cameras), "view": spec.view}


def _check_synth(n_frames: int, duration: float, size: float) -> None:
    if n_frames < 2:
        raise ValueError(f"n_frames must be >= 2, got {n_frames}")
    if not duration > 0 or not size > 0:
        raise ValueError(f"duration and size must be > 0, got {duration} and {size}")


def make_scenario(name: str, recording: str | Path | None = None, **kwargs: Any) -> Scenario:
    """Build a scenario by name. Without ``recording`` or ``kwargs`` this is the scenario file of that
    name (:func:`softsbi.scenarios.catalog.load_scenario`: built-in files, plugins, or a file path);
    ``lift`` with a DiffCloud ``recording`` folder, or any built-in with constructor ``kwargs`` (e.g.
    ``n_frames``), uses the reference constructors here (:func:`lift_scenario`, :func:`wipe_scenario`,
    :func:`winding_scenario`, :func:`fling_scenario`; the built-in files equal their defaults). An old name
    (:data:`~softsbi.scenarios.catalog.RENAMED`) builds the scenario it was renamed to, with a ``FutureWarning``.

    Raises:
        ValueError: unknown name (the message lists the valid ones), or a recording given for a
            synthetic scenario.
        DataError: lift recording missing or malformed; an invalid scenario file.
    """
    if recording is None and not kwargs:
        try:
            return load_scenario(name)
        except DataError as exc:
            if str(exc).startswith("unknown scenario"):
                raise ValueError(str(exc)) from None
            raise
    name = current_name(name)
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario '{name}'.{closest(name, SCENARIOS)} Valid scenarios: "
                         f"{', '.join(SCENARIOS)}")
    if name == "lift":
        return lift_scenario(recording, **kwargs)
    if recording is not None:
        raise ValueError(f"scenario '{name}' is synthetic and takes no recording (only 'lift' has real recordings)")
    return {"wipe": wipe_scenario, "winding": winding_scenario, "fling": fling_scenario}[name](**kwargs)
