"""The scenario file format (``format: softsbi-scenario/1``, :mod:`softsbi.scenarios.spec` shows an example): its
pydantic v2 models, limits and reader. Every field is strict (no unknown field, no NaN or infinite number), and
every error is one line naming the file, the field and the fix (:class:`~softsbi.core.errors.DataError`).
:mod:`softsbi.scenarios.spec` turns a validated :class:`ScenarioSpec` into a :class:`~softsbi.core.types.Scenario`.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Literal, Mapping, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from softsbi.core.errors import DataError
from softsbi.core.yamlfile import read_yaml
from softsbi.data.validation import short_repr, validation_line

FORMAT = "softsbi-scenario/1"
#: the format versions this reader understands
FORMATS = (FORMAT,)

Vec2 = tuple[float, float]
Vec3 = tuple[float, float, float]


#: most frames a scenario may have: a simulation of more takes hours and its rollouts gigabytes (a typical task
#: has 25-100); a count above it is a mistake, not a longer recording
MAX_FRAMES = 10_000
#: farthest a handle's path may reach from the scenario origin (m, after its frame's transform): a cloth task spans a
#: few metres of a lab, and a position beyond this is a unit mistake (mm for m, a missing scale) that every engine
#: fails on
MAX_POSITION = 100.0
#: largest gravity magnitude accepted (m/s^2), ten times Earth's: a larger one is a unit mistake (e.g. mm/s^2)
#: that every engine fails on
MAX_GRAVITY = 100.0


class _Strict(BaseModel):
    """Every field of the format: no unknown field, no NaN or infinite number."""
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class MeshSpec(_Strict):
    """A triangle mesh file (``.obj``) relative to the scenario file; ``units`` metres per mesh unit."""
    file: str = Field(description="triangle mesh (.obj), relative to the scenario file; vertex indices are its order")
    units: float = Field(1.0, gt=0, description="metres per mesh unit")


class ObjectSpec(_Strict):
    """The deformable object: ``cloth`` (``size`` m of a square grid, or ``mesh``) or ``rope``
    (``length`` m, ``radius`` m). ``size`` / ``length`` is the size a single rollout (``softsbi simulate``)
    gives the parameter ``scale`` when it is not set; a fit infers ``scale`` over its prior (``--bounds``
    sets the prior, ``--fix scale=...`` holds it at a size)."""
    kind: Literal["cloth", "rope"] = Field(description="the object: a cloth (square grid or mesh) or a rope")
    size: Optional[float] = Field(None, gt=0, description="cloth: side of a square grid, m (corners 0-3 in order "
                                                          "round the square: 0 at placement.corner, 2 opposite it "
                                                          "along placement.direction, 1 left of that diagonal seen "
                                                          "from above)")
    mesh: Optional[MeshSpec] = Field(None, description="cloth: a triangle mesh instead of a grid")
    length: Optional[float] = Field(None, gt=0, description="rope: length, m")
    radius: Optional[float] = Field(None, gt=0, description="rope: radius, m (default 0.004)")
    fabric: Optional[str] = Field(None, description="a label of the material (e.g. thick), for figures and reports")

    @model_validator(mode="after")
    def _shape(self) -> "ObjectSpec":
        if self.kind == "cloth" and (self.size is None) == (self.mesh is None):
            raise ValueError("a cloth needs exactly one of 'size' (square grid side, m) or 'mesh' (.obj file)")
        if self.kind == "rope" and (self.length is None or self.mesh is not None or self.size is not None):
            raise ValueError("a rope needs 'length' (m) and optionally 'radius' (m), no 'size' or 'mesh'")
        return self


class PlacementSpec(_Strict):
    """Rest pose: the grid cloth's placed corner / the rope's start (``corner``, m; default under the
    first moving handle's start), the direction of the cloth's diagonal / rope from it, and
    ``yaw_bounds`` (deg) when the fit infers the rotation about the grasped vertex."""
    corner: Optional[Vec2] = Field(None, description="[x, y] m of the grid cloth's corner 0 / the rope's end 0; "
                                                     "default: under the first moving handle's start")
    direction: Optional[Vec2] = Field(None, description="[dx, dy]: direction of the cloth's diagonal from corner 0 "
                                                        "(default [1, 0]) / of the rope (default [0, -1])")
    yaw_bounds: Optional[Vec2] = Field(None, description="[low, high] deg: the fit infers the parameter yaw, the "
                                                         "rotation about the grasped vertex, over this prior")
    rest: Literal["flat", "mesh"] = Field("flat", description="mesh cloth: flat lays every vertex on the table; mesh "
                                                              "keeps the file's heights above its lowest vertex")

    @model_validator(mode="after")
    def _check(self) -> "PlacementSpec":
        if self.yaw_bounds is not None and not self.yaw_bounds[0] < self.yaw_bounds[1]:
            raise ValueError(f"yaw_bounds must be [low, high] with low < high (deg), got {list(self.yaw_bounds)}")
        if self.direction is not None and math.hypot(*self.direction) == 0:
            raise ValueError("direction must be a non-zero [dx, dy]")
        return self


class GraspSpec(_Strict):
    """Which vertex a handle holds: exactly one of ``vertex`` (mesh index), ``corner`` (grid corner
    0-3), ``end`` (rope end 0/1) or ``point`` (nearest rest vertex to this scenario-frame point, m)."""
    vertex: Optional[int] = Field(None, ge=0, description="mesh cloth: vertex index in the .obj file's order")
    corner: Optional[int] = Field(None, ge=0, le=3, description="grid cloth: corner 0-3 (object.size)")
    end: Optional[int] = Field(None, ge=0, le=1, description="rope: end 0 or 1")
    point: Optional[Vec3] = Field(None, description="[x, y, z] m, scenario frame: the nearest vertex at rest")

    @model_validator(mode="after")
    def _one(self) -> "GraspSpec":
        given = [k for k in ("vertex", "corner", "end", "point") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(f"give exactly one of vertex, corner, end or point (got {given or 'none'})")
        return self

    def as_dict(self) -> dict[str, Any]:
        k = next(k for k in ("vertex", "corner", "end", "point") if getattr(self, k) is not None)
        v = getattr(self, k)
        return {k: list(v) if isinstance(v, tuple) else int(v)}


class Keyframe(_Strict):
    """One point of a handle's path: where the handle is at a time."""
    t: float = Field(ge=0, description="time, s")
    p: Vec3 = Field(description="[x, y, z] m in the path's frame")


class PathSpec(_Strict):
    """A handle's path: a ``(T, 3)`` ``.npy`` ``file`` or inline ``points`` (one row per frame), or
    ``keyframes`` sampled at the frame times (``easing`` between them), in ``frame``, plus an ``offset``
    (m, scenario frame)."""
    file: Optional[str] = Field(None, description="(T, 3) .npy positions in m, one row per frame, relative to the "
                                                  "scenario file")
    points: Optional[list[Vec3]] = Field(None, description="one [x, y, z] m per frame")
    keyframes: Optional[list[Keyframe]] = Field(None, description="at least two, times not decreasing; held before "
                                                                  "the first and after the last")
    frame: str = Field("scenario", description="the frame of the positions: scenario, or a name under transforms")
    easing: Literal["smoothstep", "linear"] = Field("smoothstep", description="between keyframes: smoothstep (zero "
                                                                              "velocity at each keyframe) or linear")
    offset: Vec3 = Field((0.0, 0.0, 0.0), description="[x, y, z] m added to every position (scenario frame)")

    @model_validator(mode="after")
    def _one(self) -> "PathSpec":
        if sum(x is not None for x in (self.file, self.points, self.keyframes)) != 1:
            raise ValueError("give exactly one of 'file' (.npy, one row per frame), 'points' (one [x, y, z] per "
                             "frame) or 'keyframes'")
        if self.keyframes is not None:
            if len(self.keyframes) < 2:
                raise ValueError("keyframes need at least two entries")
            ts = [k.t for k in self.keyframes]
            if any(b < a for a, b in zip(ts, ts[1:])):
                raise ValueError(f"keyframe times must not decrease, got {ts}")
            for a, b in zip(self.keyframes, self.keyframes[1:]):
                if a.t == b.t and a.p != b.p:
                    raise ValueError(f"two keyframes at t = {a.t:g} s have different positions ({list(a.p)} and "
                                     f"{list(b.p)}): a handle cannot be in two places at once; give one of them "
                                     f"another time")
        return self


class HandleSpec(_Strict):
    """A vertex held by the robot: pinned where it rests, or following a path (the backends shift a path by a
    constant so that it starts on its vertex)."""
    name: str = Field(description="unique name of the handle (figures draw each)")
    grasp: GraspSpec = Field(description="the vertex it holds")
    pinned: bool = Field(False, description="held in place at rest (no path)")
    path: Optional[PathSpec] = Field(None, description="the path it follows (not with pinned)")

    @model_validator(mode="after")
    def _one(self) -> "HandleSpec":
        if self.pinned == (self.path is not None):
            raise ValueError("a handle is either 'pinned: true' or has a 'path', not both or neither")
        return self


class FramesSpec(_Strict):
    """Frame times: ``count`` and ``dt`` (s, ``t = k dt``), ``count`` and ``duration`` (evenly from 0),
    or explicit ``times`` (s, strictly increasing from 0)."""
    count: Optional[int] = Field(None, ge=2, le=MAX_FRAMES, description="number of recorded frames")
    dt: Optional[float] = Field(None, gt=0, description="s between frames (t = k dt)")
    duration: Optional[float] = Field(None, gt=0, description="s from the first frame to the last")
    times: Optional[list[float]] = Field(None, max_length=MAX_FRAMES, description="explicit frame times, s, strictly "
                                                                                  "increasing")

    @model_validator(mode="after")
    def _one(self) -> "FramesSpec":
        if self.times is not None:
            if self.dt is not None or self.duration is not None:
                raise ValueError("give either 'times' or 'count' with 'dt'/'duration', not both")
            if len(self.times) < 2 or any(b <= a for a, b in zip(self.times, self.times[1:])):
                raise ValueError("times need at least two strictly increasing values (s)")
            if self.count is not None and self.count != len(self.times):
                raise ValueError(f"count {self.count} disagrees with the {len(self.times)} times; drop count")
        elif self.count is None or (self.dt is None) == (self.duration is None):
            raise ValueError("give 'count' with exactly one of 'dt' or 'duration' (s), or 'times'")
        return self

    def values(self) -> np.ndarray:
        if self.times is not None:
            return np.asarray(self.times, dtype=float)
        if self.dt is not None:
            return np.arange(self.count) * float(self.dt)
        return np.linspace(0.0, float(self.duration), self.count)


class DiffCloudTransform(_Strict):
    """DiffCloud's real2sim fields (``<task>_real2sim.yaml``): ``p -> (p + c - t) @ Rz(a)`` in metres."""
    z_rotation: float = Field(description="a, deg about z")
    translation: Vec3 = Field(description="t, m")
    scale: float = Field(gt=0, description="DiffCloud's units per m (cancels in the scenario frame)")
    compensation_factor: Vec3 = Field((0.0, 0.0, 0.0), description="c, m")


class TransformSpec(_Strict):
    """A named frame -> scenario frame: a 4x4 homogeneous ``matrix`` (column vectors, metres) or the
    DiffCloud real2sim fields (``diffcloud``)."""
    matrix: Optional[list[list[float]]] = Field(None, description="4x4, last row [0, 0, 0, 1]")
    diffcloud: Optional[DiffCloudTransform] = Field(None, description="DiffCloud's real2sim fields")

    @model_validator(mode="after")
    def _one(self) -> "TransformSpec":
        if (self.matrix is None) == (self.diffcloud is None):
            raise ValueError("give exactly one of 'matrix' (4x4) or 'diffcloud' (z_rotation, translation, scale, "
                             "compensation_factor)")
        if self.matrix is not None:
            m = np.asarray(self.matrix, dtype=float)
            if m.shape != (4, 4) or not np.allclose(m[3], [0, 0, 0, 1]):
                raise ValueError("matrix must be 4x4 with last row [0, 0, 0, 1]")
        return self


class BoxSpec(_Strict):
    """A rigid box obstacle."""
    type: Literal["box"] = Field(description="box")
    name: Optional[str] = Field(None, description="a label")
    centre: Vec3 = Field(description="[x, y, z] m")
    half_size: Vec3 = Field(description="half extents, m")
    yaw: float = Field(0.0, description="rotation about z, deg")


class CylinderSpec(_Strict):
    """A vertical cylinder standing on the table (``centre`` [x, y] m, ``radius``, ``height`` m);
    ``occludes``: observers hide the points behind it (the winding scenario's spool)."""
    type: Literal["cylinder"] = Field(description="cylinder")
    name: Optional[str] = Field(None, description="a label")
    centre: Vec2 = Field(description="[x, y] m on the table")
    radius: float = Field(gt=0, description="m")
    height: float = Field(gt=0, description="m above the table")
    occludes: bool = Field(False, description="observers hide the points it hides from the first camera")


class WorldSpec(_Strict):
    """The table's height (m), gravity (m/s^2, at most :data:`MAX_GRAVITY` in magnitude) and rigid obstacles."""
    table_z: float = Field(0.0, description="height of the table top, m")
    gravity: Vec3 = Field((0.0, 0.0, -9.81), description="m/s^2")
    obstacles: list[BoxSpec | CylinderSpec] = Field(default_factory=list, description="rigid boxes and cylinders")

    @model_validator(mode="after")
    def _gravity(self) -> "WorldSpec":
        g = math.hypot(*self.gravity)
        if g > MAX_GRAVITY:
            raise ValueError(f"gravity {list(self.gravity)} is {g:.3g} m/s^2, more than {MAX_GRAVITY:g}; give it in "
                             f"m/s^2 (Earth: [0, 0, -9.81])")
        return self


class IntrinsicsSpec(_Strict):
    """Pinhole intrinsics (px): focal lengths ``fx``, ``fy`` and principal point ``cx``, ``cy``."""
    fx: float = Field(gt=0, description="focal length along x, px")
    fy: float = Field(gt=0, description="focal length along y, px")
    cx: float = Field(description="principal point x, px")
    cy: float = Field(description="principal point y, px")


class CameraSpec(_Strict):
    """A camera of the scenario (the first one renders its images and is the occlusion viewpoint): look-at
    (``eye``, ``target`` m, ``up``, ``fovy_deg``) or calibrated (``intrinsics`` px and ``world_to_cam``, the
    3x4 ``[R | t]`` from the scenario frame to the camera's OpenCV axes, m), ``width x height`` px
    (:class:`~softsbi.core.camera.Camera`)."""
    name: str = Field(description="the camera's name")
    eye: Optional[Vec3] = Field(None, description="look-at: camera position, m")
    target: Optional[Vec3] = Field(None, description="look-at: the point it looks at, m")
    up: Vec3 = Field((0.0, 0.0, 1.0), description="look-at: the image's up direction")
    fovy_deg: float = Field(50.0, gt=0, lt=180, description="look-at: vertical field of view, deg")
    intrinsics: Optional[IntrinsicsSpec] = Field(None, description="calibrated: pinhole intrinsics, px")
    world_to_cam: Optional[list[list[float]]] = Field(None, description="calibrated: 3x4 [R | t], scenario frame -> "
                                                                        "OpenCV camera axes, m")
    width: int = Field(128, ge=8, description="image width, px")
    height: int = Field(128, ge=8, description="image height, px")

    @model_validator(mode="after")
    def _one(self) -> "CameraSpec":
        look_at = self.eye is not None and self.target is not None
        calibrated = self.intrinsics is not None and self.world_to_cam is not None
        if look_at == calibrated or (self.eye is None) != (self.target is None) or \
                (self.intrinsics is None) != (self.world_to_cam is None):
            raise ValueError("give a camera either 'eye' and 'target' (look-at) or 'intrinsics' and 'world_to_cam' "
                             "(calibrated)")
        if self.world_to_cam is not None and np.asarray(self.world_to_cam, dtype=float).shape != (3, 4):
            raise ValueError("world_to_cam must be 3x4 [R | t] (scenario frame -> camera, m)")
        return self


class RobotSpec(_Strict):
    """Where the visual-only robot arm drawn in rendered images stands: its shoulder ``base`` (m) in
    ``frame`` (``scenario`` or a name under ``transforms``). Without it the arm stands behind the
    workspace along +y (:func:`softsbi.backends.common.robot_base`)."""
    base: Vec3 = Field(description="[x, y, z] m: the arm's shoulder")
    frame: str = Field("scenario", description="scenario, or a name under transforms")


class ScenarioSpec(_Strict):
    """A scenario file: the task as data."""
    format: Literal["softsbi-scenario/1"] = Field(description="the format and its version")
    name: str = Field(min_length=1, description="the task's name (runs and figures carry it)")
    description: str = Field("", description="one line for `softsbi scenarios`")
    object: ObjectSpec = Field(description="the deformable object")
    placement: PlacementSpec = Field(default_factory=PlacementSpec, description="its rest pose")
    handles: list[HandleSpec] = Field(min_length=1, description="the grasps; at least one follows a path")
    frames: FramesSpec = Field(description="the recorded frame times")
    transforms: dict[str, TransformSpec] = Field(default_factory=dict, description="named frames (e.g. robot) -> "
                                                                                   "scenario frame")
    world: WorldSpec = Field(default_factory=WorldSpec, description="table, gravity and obstacles")
    cameras: list[CameraSpec] = Field(default_factory=list, description="the first renders images and is the "
                                                                        "occlusion viewpoint")
    view: Literal["xz", "yz", "xy"] = Field("xz", description="the plane of 2-D figures: xz (side view across y), yz "
                                                              "(side view across x) or xy (top view)")
    robot: Optional[RobotSpec] = Field(None, description="where the arm drawn in rendered images stands")
    options: dict[str, Any] = Field(default_factory=dict, description="free-form notes kept with the scenario")

    @model_validator(mode="after")
    def _handles(self) -> "ScenarioSpec":
        if not any(not h.pinned for h in self.handles):
            raise ValueError("at least one handle must follow a path (all are pinned)")
        names = [h.name for h in self.handles]
        if len(set(names)) != len(names):
            raise ValueError(f"handle names must be unique, got {names}")
        return self


# ---------------------------------------------------------------------------------------------
# errors
# ---------------------------------------------------------------------------------------------
EXAMPLE = "softsbi/scenarios/files/lift.yaml"


def read_scenario_yaml(path: Path) -> Any:
    """The YAML value of the scenario file ``path``.

    Raises:
        DataError: the file does not exist or cannot be read (one line naming it and the fix).
    """
    try:
        return read_yaml(path)
    except FileNotFoundError:
        raise DataError(f"scenario file {path} does not exist; give a path to a .yaml scenario file or a "
                        f"built-in name (`softsbi scenarios` lists them)") from None
    except (IsADirectoryError, PermissionError) as exc:
        raise DataError(f"cannot read scenario file {path} ({exc.strerror}); give a readable .yaml file") from None


def parse_spec(data: Any, source: str) -> ScenarioSpec:
    """Validate a scenario mapping; one-line :class:`DataError` naming ``source``, the field and the fix."""
    if not isinstance(data, Mapping):
        raise DataError(f"{source}: a scenario file must be a YAML mapping (format, name, object, handles, "
                        f"frames, ...), got {type(data).__name__}")
    if data.get("format") not in FORMATS:
        raise DataError(f"{source}: field 'format' is {short_repr(data.get('format'))}; this softsbi reads "
                        f"{', '.join(FORMATS)} (set format: {FORMAT})")
    try:
        return ScenarioSpec.model_validate(dict(data))
    except ValidationError as exc:
        raise DataError(validation_line(source, exc, EXAMPLE)) from None
