"""DiffCloud's *lift* recordings in softsbi's lift frame: a recording's real -> simulator transform
(``lift_real2sim.yaml``), the table height it implies, and its clouds in metres.

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
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from softsbi.core.arrays import read_npy
from softsbi.core.errors import DataError, ShapeError
from softsbi.core.yamlfile import read_yaml

#: metres per ARCSim simulator unit (``scale`` of every lift_real2sim.yaml)
SIM_SCALE = 0.35
#: ARCSim table plane height of plane.obj, simulator units
PLANE_Z_SIM = 0.157065
#: compensation z of the recordings whose table is exactly at plane.obj (navy/paper/polka/tan)
PLANE_REFERENCE_CZ = -0.02
#: physical table height in the robot base frame, metres (plane.obj mapped back with c_z = -0.02)
TABLE_Z_REAL = PLANE_Z_SIM * SIM_SCALE - PLANE_REFERENCE_CZ
#: default lift_real2sim.yaml (shared/data/diffcloud_lift/lift_real2sim.yaml)
DEFAULT_TRANSFORM: dict[str, Any] = {"z_rotation": 90.0, "translation": [0.67, 0.15, 0.0], "scale": 0.35,
                                     "compensation_factor": [-0.02, 0.0, 0.0]}


def _rz(a_deg: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation  # heavy (scipy): loaded only to map real points
    return Rotation.from_euler("z", float(a_deg), degrees=True).as_matrix()


def check_transform(cfg: Mapping[str, Any]) -> dict[str, Any]:
    """A real -> simulator transform checked and as arrays: ``{"z_rotation": deg, "translation": (3,) m,
    "scale": m/unit, "compensation_factor": (3,) m}``.

    Raises:
        DataError: a key is missing or malformed, or the scale is not positive.
    """
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
    path = Path(recording_dir) / "lift_real2sim.yaml"
    if not path.is_file():
        raise DataError(f"no lift_real2sim.yaml in {recording_dir}; expected a DiffCloud lift recording "
                        f"folder such as shared/data/diffcloud_lift/lift_tan")
    cfg = read_yaml(path, "fix that line (the file holds z_rotation, translation, scale and compensation_factor)")
    if not isinstance(cfg, Mapping):
        raise DataError(f"{path} is not a mapping")
    return check_transform(cfg)


def real_to_sim(p_real: np.ndarray, cfg: Mapping[str, Any]) -> np.ndarray:
    """Robot-frame points ``(..., 3)`` m -> DiffCloud simulator frame ``(..., 3)`` sim units.

    ``p_sim = (((p_real + c) - t) / s) @ Rz(a)`` (DiffCloud ``real2sim_transf``).
    """
    c = check_transform(cfg)
    p = np.asarray(p_real, dtype=float)
    if p.shape[-1] != 3:
        raise ShapeError(f"points must be (..., 3), got {p.shape}")
    return (((p + c["compensation_factor"]) - c["translation"]) / c["scale"]) @ _rz(c["z_rotation"])


def real_to_lift_frame(p_real: np.ndarray, cfg: Mapping[str, Any]) -> np.ndarray:
    """Robot-frame points ``(..., 3)`` m -> softsbi lift frame ``(..., 3)`` m (= sim frame x s)."""
    return real_to_sim(p_real, cfg) * check_transform(cfg)["scale"]


def lift_frame_to_real(p_lift: np.ndarray, cfg: Mapping[str, Any]) -> np.ndarray:
    """Inverse of :func:`real_to_lift_frame`: ``p_real = (p_sim @ Rz(a).T) * s + t - c``."""
    c = check_transform(cfg)
    p_sim = np.asarray(p_lift, dtype=float) / c["scale"]
    return (p_sim @ _rz(c["z_rotation"]).T) * c["scale"] + c["translation"] - c["compensation_factor"]


def sim_units_to_metres(points: np.ndarray, cfg: Mapping[str, Any] | None = None) -> np.ndarray:
    """DiffCloud simulator-frame points ``(..., 3)`` -> lift frame ``(..., 3)`` m (multiply by ``s``).

    ``cfg`` defaults to :data:`DEFAULT_TRANSFORM` (s = 0.35 m per unit, same for every recording).
    """
    s = check_transform(cfg or DEFAULT_TRANSFORM)["scale"]
    return np.asarray(points, dtype=float) * s


def table_height(cfg: Mapping[str, Any]) -> float:
    """Table top in the lift frame (m) for a recording's transform.

    The physical table is at :data:`TABLE_Z_REAL` in the robot frame (plane.obj's 0.157065 sim
    units mapped back with the reference ``c_z = -0.02``); mapped forward with ``cfg`` this is
    ``TABLE_Z_REAL + c_z - t_z`` (the z-rotation leaves z alone).
    """
    c = check_transform(cfg)
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
