"""Engine-independent scenario construction for the cloth *lift* task (DiffCloud data).

The lift frame
--------------
softsbi's **lift frame** is DiffCloud's ARCSim simulator frame multiplied by the scale
``s`` (0.35 m per simulator unit): metres, z up, same axes and origin as the simulator frame.
Real robot-frame points (metres) map into it with the per-recording transform of
``lift_real2sim.yaml`` exactly as DiffCloud's post-processing does
(``real/post_proc/plot_pcls.py::real2sim_transf``, see ``shared/data/README.md``)::

    p_sim  = (((p_real + c) - t) / s) @ Rz(a)      # Rz from scipy, row vectors
    p_lift = p_sim * s

with ``a = z_rotation`` (deg), ``t = translation``, ``s = scale``, ``c = compensation_factor``.
The recorded clouds ``NNN.npy`` are already in the simulator frame, so ``p_lift = cloud * s``.

Table height (``Scenario.table_z``)
-----------------------------------
The table plane of DiffCloud's ``plane.obj`` is at ``z = 0.157065`` simulator units. It matches
the recordings whose compensation is ``c_z = -0.02`` (navy, paper, polka, tan: their lowest
cloud points sit at 0.157). Mapped back to the robot frame with ``c_z = -0.02`` this is the
physical table at ``z_real = 0.157065 * 0.35 + 0.02 = 0.07497 m``. For any recording the table
then lies at ``table_z = z_real + c_z - t_z`` (metres, lift frame) - the exact same transform
applied to the table. For tan2 / redblack / redblack2 (``c_z = 0``) this gives 0.2142
simulator units, where their lowest cloud points are (0.214); see :func:`table_height`.
The unit tests check this against the 1st percentile of every recording's cloud z.

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
from softsbi.core.errors import DataError, ShapeError
from softsbi.core.types import Param, Scenario

#: metres per ARCSim simulator unit (``scale`` of every lift_real2sim.yaml)
SIM_SCALE = 0.35
#: ARCSim table plane height of plane.obj, simulator units
PLANE_Z_SIM = 0.157065
#: compensation z of the recordings whose table is exactly at plane.obj (navy/paper/polka/tan)
PLANE_REFERENCE_CZ = -0.02
#: physical table height in the robot base frame, metres (plane.obj mapped back with c_z = -0.02)
TABLE_Z_REAL = PLANE_Z_SIM * SIM_SCALE - PLANE_REFERENCE_CZ
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

#: default lift_real2sim.yaml (shared/data/diffcloud_lift/lift_real2sim.yaml)
DEFAULT_TRANSFORM: dict[str, Any] = {"z_rotation": 90.0, "translation": [0.67, 0.15, 0.0], "scale": 0.35,
                                     "compensation_factor": [-0.02, 0.0, 0.0]}
#: the real robot's shoulder in its base frame (m): where the visual arm of rendered lift images stands
ROBOT_BASE_REAL = (0.0, 0.0, 0.33)
#: first and last rows of lift_traj.npy (robot frame, m): the only recorded numbers the default uses
_TRAJ_START = (0.56344985, 0.15072625, 0.07796145)
_TRAJ_END = (0.75582497, 0.15036571, 0.38734047)


# --------------------------------------------------------------------------------------------
# transforms
# --------------------------------------------------------------------------------------------
def _rz(a_deg: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    return Rotation.from_euler("z", float(a_deg), degrees=True).as_matrix()


def _check_cfg(cfg: Mapping[str, Any]) -> dict[str, Any]:
    try:
        out = {"z_rotation": float(cfg["z_rotation"]),
               "translation": np.asarray(cfg["translation"], dtype=float).reshape(3),
               "scale": float(cfg["scale"]),
               "compensation_factor": np.asarray(cfg["compensation_factor"], dtype=float).reshape(3)}
    except (KeyError, TypeError, ValueError) as exc:
        raise DataError(f"real2sim transform needs z_rotation, translation (3), scale and "
                        f"compensation_factor (3); got {dict(cfg)!r} ({exc})") from exc
    if not out["scale"] > 0:
        raise DataError(f"real2sim transform scale must be > 0, got {out['scale']}")
    return out


def recording_transform(recording_dir: str | Path) -> dict[str, Any]:
    """Read the real->simulator transform of a recording (or of a folder holding the default).

    Args:
        recording_dir: a recording folder (``.../diffcloud_lift/lift_tan``) containing
            ``lift_real2sim.yaml``, or the ``diffcloud_lift`` folder itself (default yaml).

    Returns:
        ``{"z_rotation": deg, "translation": (3,) m, "scale": m/unit, "compensation_factor": (3,) m}``
        (arrays are NumPy float64).

    Raises:
        DataError: the yaml is missing or malformed.
    """
    from softsbi.core.yamlfile import read_yaml
    path = Path(recording_dir) / "lift_real2sim.yaml"
    if not path.is_file():
        raise DataError(f"no lift_real2sim.yaml in {recording_dir}; expected a DiffCloud lift recording "
                        f"folder such as shared/data/diffcloud_lift/lift_tan")
    cfg = read_yaml(path, "fix that line (the file holds z_rotation, translation, scale and compensation_factor)")
    if not isinstance(cfg, Mapping):
        raise DataError(f"{path} is not a mapping")
    return _check_cfg(cfg)


def real_to_sim(p_real: np.ndarray, cfg: Mapping[str, Any]) -> np.ndarray:
    """Robot-frame points ``(..., 3)`` m -> DiffCloud simulator frame ``(..., 3)`` sim units.

    ``p_sim = (((p_real + c) - t) / s) @ Rz(a)`` (DiffCloud ``real2sim_transf``).
    """
    c = _check_cfg(cfg)
    p = np.asarray(p_real, dtype=float)
    if p.shape[-1] != 3:
        raise ShapeError(f"points must be (..., 3), got {p.shape}")
    return (((p + c["compensation_factor"]) - c["translation"]) / c["scale"]) @ _rz(c["z_rotation"])


def real_to_lift_frame(p_real: np.ndarray, cfg: Mapping[str, Any]) -> np.ndarray:
    """Robot-frame points ``(..., 3)`` m -> softsbi lift frame ``(..., 3)`` m (= sim frame x s)."""
    return real_to_sim(p_real, cfg) * _check_cfg(cfg)["scale"]


def lift_frame_to_real(p_lift: np.ndarray, cfg: Mapping[str, Any]) -> np.ndarray:
    """Inverse of :func:`real_to_lift_frame`: ``p_real = (p_sim @ Rz(a).T) * s + t - c``."""
    c = _check_cfg(cfg)
    p_sim = np.asarray(p_lift, dtype=float) / c["scale"]
    return (p_sim @ _rz(c["z_rotation"]).T) * c["scale"] + c["translation"] - c["compensation_factor"]


def sim_units_to_metres(points: np.ndarray, cfg: Mapping[str, Any] | None = None) -> np.ndarray:
    """DiffCloud simulator-frame points ``(..., 3)`` -> lift frame ``(..., 3)`` m (multiply by ``s``).

    ``cfg`` defaults to :data:`DEFAULT_TRANSFORM` (s = 0.35 m per unit, same for every recording).
    """
    s = _check_cfg(cfg or DEFAULT_TRANSFORM)["scale"]
    return np.asarray(points, dtype=float) * s


def table_height(cfg: Mapping[str, Any]) -> float:
    """Table top in the lift frame (m) for a recording's transform.

    The physical table is at :data:`TABLE_Z_REAL` in the robot frame (plane.obj's 0.157065 sim
    units mapped back with the reference ``c_z = -0.02``); mapped forward with ``cfg`` this is
    ``TABLE_Z_REAL + c_z - t_z`` (the z-rotation leaves z alone).
    """
    c = _check_cfg(cfg)
    return float(TABLE_Z_REAL + c["compensation_factor"][2] - c["translation"][2])


def load_recording(recording: str | Path, frames: range | None = None) -> np.ndarray:
    """The recorded clouds of a lift recording in the lift frame, metres.

    Args:
        recording: folder with ``000.npy``...``024.npy`` (simulator frame, (3500, 3) each).
        frames: which frame indices (default: all files present, in order).

    Returns:
        ``(T, P, 3)`` float64 metres (each cloud x ``scale``). No validation beyond shape
        and finiteness; the perception loader adds the rest.

    Raises:
        DataError: no frames, unequal sizes, non-finite values.
    """
    rec = Path(recording)
    files = sorted(rec.glob("[0-9][0-9][0-9].npy"))
    if frames is not None:
        files = [rec / f"{i:03d}.npy" for i in frames]
    if not files or not all(f.is_file() for f in files):
        raise DataError(f"no frames NNN.npy found in {rec}")
    s = recording_transform(rec)["scale"]
    clouds = [read_npy(f, "frame", "re-export it as a (P, 3) float .npy") for f in files]
    if any(c.ndim != 2 or c.shape[1] != 3 or c.shape != clouds[0].shape for c in clouds):
        raise DataError(f"frames of {rec} must all be (P, 3) of equal size")
    out = np.stack(clouds).astype(float) * s
    if not np.all(np.isfinite(out)):
        raise DataError(f"non-finite values in the frames of {rec}")
    return out


def estimate_grasp_offset(recording: str | Path, commanded: np.ndarray,
                          frames: range = range(18, 25), top_fraction: float = 0.01) -> np.ndarray:
    """Offset ``(3,)`` m from the commanded gripper path to the real grasped corner.

    In the last frames the grasped corner is the highest part of the hanging cloth; the median
    of the top ``top_fraction`` of (unique) cloud points minus the commanded position, averaged
    over ``frames``. ``commanded`` is ``(25, 3)`` in the lift frame (recorded frame indices).
    """
    s = recording_transform(recording)["scale"]
    offs = []
    for i in frames:
        f = np.unique(read_npy(Path(recording) / f"{i:03d}.npy", "frame"), axis=0) * s
        top = f[f[:, 2] >= np.quantile(f[:, 2], 1.0 - top_fraction)]
        offs.append(np.median(top, axis=0) - commanded[i])
    return np.mean(offs, axis=0)


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
        cfg = _check_cfg(DEFAULT_TRANSFORM)
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
    from softsbi.scenarios.spec import _read_yaml, camera_dicts, parse_spec
    path = Path(__file__).parent / "files" / f"{name}.yaml"
    spec = parse_spec(_read_yaml(path), str(path))
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
    from softsbi.core.errors import closest
    from softsbi.scenarios.catalog import current_name
    if recording is None and not kwargs:
        from softsbi.scenarios.catalog import load_scenario
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
