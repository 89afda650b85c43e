"""Recording directories: the format of what a fit is fitted to (docs/design.md, "Scenarios and recordings are data").

A recording directory::

    recording.yaml          # below
    clouds/000.npy ...      # one (P_t, 3) float point cloud per frame, any P_t, recording frame, metres
    images/000.png ...      # optional RGB frames
    depth/000.npy ...       # optional (H, W) depth images, metres
    calibration.yaml        # optional camera calibration (free-form, read into RecordingData.extras)

``recording.yaml`` (``format: softsbi-recording/1``)::

    format: softsbi-recording/1
    scenario: {name: lift}            # or {file: fold.yaml} (relative to this folder) or {inline: {...}};
                                      #   shorthand: scenario: lift, scenario: fold.yaml
    units: {length: m, time: s}
    times: [0.0, 0.04, ...]           # one per frame, s
    transform: {matrix: [[1, 0, 0, 0], ...]}    # recording frame -> scenario frame (required), or
                                                # {diffcloud: {z_rotation, translation, scale, compensation_factor}}
    frames_of_reference:              # optional: named frames of the scenario's paths -> scenario frame
      robot: {diffcloud: {...}}       #   (this recording's calibration replaces the scenario file's)
    sensor: {kind: depth point cloud, min_height: 0.01, frames: auto}
    truth: {bend: 1e-4, ...}          # simulated recordings: the hidden parameters, and
    effects: [wind]                   #   the effects switched on
    source: "DiffCloud lift_tan (priyasundaresan/diffcloud_real2sim)"

:func:`read_recording` checks everything and gives one line naming the file, the field and the fix;
:func:`write_recording` checks before writing, so a bad recording leaves nothing behind.
This layer knows no scenario: :func:`softsbi.workflows.measurement.load_recording` builds the
:class:`~softsbi.core.types.Recording` (scenario, observed state) from what is read here.
"""
from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Mapping, Optional, Sequence, Union

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from softsbi.core.arrays import read_npy
from softsbi.core.errors import DataError
from softsbi.core.yamlfile import read_yaml
from softsbi.data.frames import load_frames, numbered_files, save_frames
from softsbi.data.validation import short_repr, validation_line

FORMAT = "softsbi-recording/1"
META = "recording.yaml"
EXAMPLE = "softsbi/data/recording.py (module docstring)"
#: what to write for a required field a hand-written recording.yaml lacks
MISSING_HINTS = {
    "format": f"format: {FORMAT}",
    "scenario": "the task, e.g. scenario: lift (a name) or scenario: my_task.yaml (a file beside recording.yaml)",
    "times": "one time per frame in s, e.g. times: [0.0, 0.04, 0.08, ...]",
    "transform": "the map of the clouds into the scenario frame, e.g. transform: {matrix: [[1, 0, 0, 0], "
                 "[0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]} when they are already in it",
}


class _Strict(BaseModel):
    """Every field of the format: no unknown field, no NaN or infinite number."""
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class ScenarioRef(_Strict):
    """Exactly one of a scenario ``name`` (built-in or plugin), ``file`` (relative to the recording
    folder) or ``inline`` scenario mapping (the scenario file format). A plain string is shorthand:
    ``scenario: lift`` is ``{name: lift}``, ``scenario: my_task.yaml`` (ending in ``.yaml``/``.yml``) is
    ``{file: my_task.yaml}``."""
    name: Optional[str] = Field(None, description="a built-in or plugin scenario (`softsbi scenarios`)")
    file: Optional[str] = Field(None, description="a scenario file, relative to the recording folder")
    inline: Optional[dict[str, Any]] = Field(None, description="the scenario file's mapping itself")

    @model_validator(mode="before")
    @classmethod
    def _shorthand(cls, data: Any) -> Any:
        if isinstance(data, str):
            return {"file": data} if data.lower().endswith((".yaml", ".yml")) else {"name": data}
        return data

    @model_validator(mode="after")
    def _one(self) -> "ScenarioRef":
        if sum(x is not None for x in (self.name, self.file, self.inline)) != 1:
            raise ValueError("give exactly one of name, file or inline")
        return self


class DiffCloudTransform(_Strict):
    """DiffCloud's real2sim fields (``<task>_real2sim.yaml``): ``p -> (p + c - t) @ Rz(a)`` in metres."""
    z_rotation: float = Field(description="a, deg about z")
    translation: tuple[float, float, float] = Field(description="t, m")
    scale: float = Field(gt=0, description="DiffCloud's units per m (cancels in the scenario frame)")
    compensation_factor: tuple[float, float, float] = Field((0.0, 0.0, 0.0), description="c, m")


class Transform(_Strict):
    """A 4x4 ``matrix`` (column vectors, metres) or DiffCloud's real2sim fields; maps into the scenario frame."""
    matrix: Optional[list[list[float]]] = Field(None, description="4x4, last row [0, 0, 0, 1]")
    diffcloud: Optional[DiffCloudTransform] = Field(None, description="DiffCloud's real2sim fields")

    @model_validator(mode="after")
    def _one(self) -> "Transform":
        if (self.matrix is None) == (self.diffcloud is None):
            raise ValueError("give exactly one of 'matrix' (4x4) or 'diffcloud'")
        if self.matrix is not None:
            m = np.asarray(self.matrix, dtype=float)
            if m.shape != (4, 4) or not np.allclose(m[3], [0, 0, 0, 1]):
                raise ValueError("matrix must be 4x4 with last row [0, 0, 0, 1]")
        return self

    def as_matrix(self) -> np.ndarray:
        """4x4 homogeneous matrix; DiffCloud: ``p -> (p + c - t) @ Rz(a)`` (rows; metres, the scale cancels)."""
        if self.matrix is not None:
            return np.asarray(self.matrix, dtype=float)
        from scipy.spatial.transform import Rotation  # heavy (scipy): loaded only for a diffcloud transform
        d = self.diffcloud
        rz = Rotation.from_euler("z", float(d.z_rotation), degrees=True).as_matrix()
        m = np.eye(4)
        m[:3, :3] = rz.T
        m[:3, 3] = rz.T @ (np.asarray(d.compensation_factor) - np.asarray(d.translation))
        return m


class Units(_Strict):
    """The units of the files (only SI is read)."""
    length: Literal["m"] = Field("m", description="clouds and depth images in metres")
    time: Literal["s"] = Field("s", description="times in seconds")


class Sensor(_Strict):
    """The sensor model a fit uses by default: points within ``min_height`` m of the table are not seen
    (None: all are); ``frames`` that inform the posterior (``auto``, ``all`` or indices)."""
    kind: str = Field("point cloud", description="what recorded the clouds (a label)")
    min_height: Optional[float] = Field(None, ge=0, description="m: points this close to the table are not seen, in "
                                                                "simulation and recording alike (None: all are)")
    frames: Union[Literal["auto", "all"], list[int]] = Field("all", description="frames that inform the posterior: "
                                                                                "auto (the gripper at least 10 cm "
                                                                                "above the table), all, or indices")


class RecordingMeta(_Strict):
    """``recording.yaml``: what the clouds are and how they map into the scenario."""
    format: Literal["softsbi-recording/1"] = Field(description="the format and its version")
    scenario: ScenarioRef = Field(description="the task: a name, a file or inline (a plain string: name, or file "
                                              "if it ends in .yaml)")
    units: Units = Field(default_factory=Units, description="the files' units")
    times: list[float] = Field(min_length=1, description="one time per frame, s, strictly increasing")
    transform: Transform = Field(description="the clouds' frame -> the scenario frame")
    frames_of_reference: dict[str, Transform] = Field(default_factory=dict, description="named frames of the "
                                                                                        "scenario's paths (e.g. "
                                                                                        "robot) -> scenario frame, "
                                                                                        "replacing the scenario "
                                                                                        "file's (this recording's "
                                                                                        "calibration)")
    sensor: Sensor = Field(default_factory=Sensor, description="the sensor model a fit uses by default")
    truth: Optional[dict[str, float]] = Field(None, description="a simulated recording's hidden parameters "
                                                                "(physical units)")
    effects: list[str] = Field(default_factory=list, description="a simulated recording's effects switched on")
    source: str = Field("", description="where the data come from (one line)")
    calibration: Optional[str] = Field(None, description="a camera calibration file in the folder, read as is")

    @model_validator(mode="after")
    def _times(self) -> "RecordingMeta":
        if any(b <= a for a, b in zip(self.times, self.times[1:])):
            raise ValueError("times must increase strictly (s, one per frame)")
        return self


@dataclass
class RecordingData:
    """What :func:`read_recording` returns.

    Attributes:
        folder: the recording directory.
        meta: the validated ``recording.yaml``.
        clouds: ``T`` arrays ``(P_t, 3)`` m, already mapped into the scenario frame.
        times: ``(T,)`` s.
        images: optional ``(T, H, W, 3)`` uint8.
        depth: optional ``T`` arrays ``(H, W)`` m.
        extras: ``{"calibration": ...}`` when the recording names a calibration file.
    """
    folder: Path
    meta: RecordingMeta
    clouds: list[np.ndarray]
    times: np.ndarray
    images: np.ndarray | None = None
    depth: list[np.ndarray] | None = None
    extras: dict[str, Any] = field(default_factory=dict)


def is_recording(folder: str | Path) -> bool:
    """Whether ``folder`` is a recording directory (holds ``recording.yaml``)."""
    return (Path(folder) / META).is_file()


def parse_meta(data: Any, source: str) -> RecordingMeta:
    """Validate a ``recording.yaml`` mapping; one-line :class:`DataError` naming the file, field and fix."""
    if not isinstance(data, Mapping):
        raise DataError(f"{source}: recording.yaml must be a mapping (format, scenario, times, transform, ...)")
    if data.get("format") != FORMAT:
        raise DataError(f"{source}: field 'format' is {short_repr(data.get('format'))}; this softsbi reads {FORMAT} "
                        f"(set format: {FORMAT})")
    try:
        return RecordingMeta.model_validate(dict(data))
    except ValidationError as exc:
        raise DataError(validation_line(source, exc, EXAMPLE, MISSING_HINTS)) from None


def _check_clouds(clouds: Sequence[np.ndarray], where: str) -> None:
    for i, c in enumerate(clouds):
        c = np.asarray(c)
        if c.ndim != 2 or c.shape[1] != 3 or len(c) == 0:
            raise DataError(f"{where} frame {i:03d}: a cloud must be (P, 3) with P >= 1, got {c.shape}; re-export it")
        if not np.all(np.isfinite(c)):
            raise DataError(f"{where} frame {i:03d}: NaN or inf points; drop them before saving")


def read_recording(folder: str | Path) -> RecordingData:
    """Read and check a recording directory; clouds are mapped into the scenario frame with ``transform``.

    Raises:
        DataError: no ``recording.yaml``; invalid YAML or fields (unknown field, wrong type, missing
            ``transform``); the number of ``times`` differs from the number of clouds; ``sensor.frames`` selects a
            frame the recording does not have; a malformed or misnamed cloud file.
    """
    folder = Path(folder)
    meta_file = folder / META
    if not meta_file.is_file():
        raise DataError(f"'{folder}' is not a recording directory (no {META}); convert DiffCloud folders with "
                        f"`softsbi import diffcloud SRC DST`, or write one with `softsbi simulate --out DIR`")
    raw = read_yaml(meta_file)
    meta = parse_meta(raw, str(meta_file))
    files = numbered_files(folder / "clouds", (".npy",))
    if not files:
        raise DataError(f"{folder / 'clouds'} holds no frames 000.npy, 001.npy, ...; a recording needs one (P, 3) "
                        f"cloud per frame")
    if len(files) != len(meta.times):
        raise DataError(f"{meta_file}: field 'times' has {len(meta.times)} entries but clouds/ holds {len(files)} "
                        f"frames; give one time per frame")
    if isinstance(meta.sensor.frames, list):
        bad = [i for i in meta.sensor.frames if not 0 <= i < len(files)]
        if bad:
            raise DataError(f"{meta_file}: field 'sensor.frames' selects frame {bad[0]}, but the recording has "
                            f"{len(files)} frames (0 to {len(files) - 1}); give frames within them, or all or auto")
    clouds = [read_npy(f, "frame", "re-export it as a (P, 3) float .npy").astype(float) for f in files]
    _check_clouds(clouds, str(folder / "clouds"))
    m = meta.transform.as_matrix()
    clouds = [c @ m[:3, :3].T + m[:3, 3] for c in clouds]
    images = None
    if (folder / "images").is_dir() and any(p.stem.isdigit() for p in (folder / "images").iterdir()):
        images = load_frames(folder / "images")
        if len(images) != len(files):
            raise DataError(f"{folder / 'images'} holds {len(images)} images for {len(files)} frames; give one per "
                            f"frame or none")
    depth = None
    dfiles = numbered_files(folder / "depth", (".npy",)) if (folder / "depth").is_dir() else []
    if dfiles:
        if len(dfiles) != len(files):
            raise DataError(f"{folder / 'depth'} holds {len(dfiles)} depth images for {len(files)} frames; give one "
                            f"per frame or none")
        depth = [read_npy(f, "depth image") for f in dfiles]
    extras: dict[str, Any] = {}
    if meta.calibration:
        cal = folder / meta.calibration
        if not cal.is_file():
            raise DataError(f"{meta_file}: field 'calibration' names {cal}, which "
                            f"{'is a folder' if cal.is_dir() else 'does not exist'}; add the file or remove the field")
        extras["calibration"] = read_yaml(cal, "fix it or remove the field 'calibration'")
    return RecordingData(folder=folder, meta=meta, clouds=clouds, times=np.asarray(meta.times, float),
                         images=images, depth=depth, extras=extras)


def write_recording(folder: str | Path, meta: Mapping[str, Any], clouds: Sequence[np.ndarray],
                    images: np.ndarray | None = None, depth: Sequence[np.ndarray] | None = None,
                    overwrite: bool = False, calibration: Mapping[str, Any] | None = None) -> Path:
    """Write a recording directory: ``recording.yaml``, ``clouds/NNN.npy`` (and ``images/``, ``depth/``).

    Everything is checked first and written into a temporary sibling folder that is renamed into
    place, so a failure leaves nothing at ``folder``. With ``overwrite`` an existing folder keeps its
    other files (e.g. ``softsbi simulate``'s ``rollout.zarr``); ``recording.yaml``, ``clouds/``
    (``images/``, ``depth/``) are replaced.

    Args:
        meta: the ``recording.yaml`` mapping (``format`` is added if absent).
        clouds: ``T`` arrays ``(P_t, 3)`` m in the recording frame.
        calibration: camera calibration written as ``calibration.yaml`` (and named in ``meta``), e.g.
            ``{"cameras": {"overhead": {"intrinsics": {...}, "robot_from_camera": 3x4}}}``.

    Raises:
        DataError: invalid meta, times vs clouds disagree, malformed clouds, ``folder`` exists and is
            not empty (unless ``overwrite``).
    """
    folder = Path(folder)
    meta = dict(meta)
    meta.setdefault("format", FORMAT)
    if calibration is not None:
        meta["calibration"] = "calibration.yaml"
    parsed = parse_meta(meta, str(folder / META))
    if len(parsed.times) != len(clouds):
        raise DataError(f"{folder / META}: field 'times' has {len(parsed.times)} entries for {len(clouds)} clouds; "
                        f"give one time per frame")
    _check_clouds(clouds, str(folder / "clouds"))
    if folder.exists() and any(folder.iterdir()):
        if not overwrite:
            raise DataError(f"'{folder}' exists and is not empty; choose a new folder or remove it")
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
    try:
        (tmp / "clouds").mkdir()
        for i, c in enumerate(clouds):
            np.save(tmp / "clouds" / f"{i:03d}.npy", np.asarray(c, dtype=np.float64))
        if images is not None:
            save_frames(images, tmp / "images")
        if depth is not None:
            (tmp / "depth").mkdir()
            for i, d in enumerate(depth):
                np.save(tmp / "depth" / f"{i:03d}.npy", np.asarray(d, dtype=np.float32))
        if calibration is not None:
            (tmp / "calibration.yaml").write_text(yaml.safe_dump(dict(calibration), sort_keys=False,
                                                                 default_flow_style=None, width=120))
        (tmp / META).write_text(yaml.safe_dump(parsed.model_dump(mode="json", exclude_none=True), sort_keys=False,
                                                default_flow_style=None, width=120))
        if not folder.exists():
            os.replace(tmp, folder)
        else:  # overwrite: replace the recording's own entries, keep anything else in the folder
            for item in tmp.iterdir():
                old = folder / item.name
                if old.is_dir():
                    shutil.rmtree(old)
                elif old.exists():
                    old.unlink()
                os.replace(item, old)
            tmp.rmdir()
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return folder
