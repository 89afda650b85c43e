"""Scenario files: a versioned YAML format, validated with pydantic v2, turned into a :class:`Scenario`.

A scenario file (``format: softsbi-scenario/1``) describes a task as data (DESIGN.md "Scenarios are
data")::

    format: softsbi-scenario/1
    name: fold
    object:                       # cloth from a grid (size) or a mesh; or a rope (length, radius)
      kind: cloth
      mesh: {file: cloth.obj, units: 0.35}     # .obj relative to this file, metres per mesh unit
    placement:                    # rest pose; yaw_bounds: the fit infers the yaw about the grasped vertex
      yaw_bounds: [-45, 45]
    handles:                      # any number; each pinned or following a path
      - {name: held, grasp: {vertex: 13}, pinned: true}
      - name: grip
        grasp: {vertex: 42}       # or {corner: k} (grid), {end: k} (rope), {point: [x, y, z]}
        path: {file: traj.npy, frame: robot}   # or keyframes: [{t: 0.0, p: [x, y, z]}, ...]
    frames: {count: 25, dt: 0.04}              # or {count, duration}, or {times: [...]}
    transforms:                   # named frames -> the scenario frame (metres, z up)
      robot: {diffcloud: {z_rotation: 90, translation: [0.55, 0.18, 0], scale: 0.35,
                          compensation_factor: [0, 0, 0]}}     # or {matrix: 4x4}
    world: {table_z: 0.075, gravity: [0, 0, -9.81], obstacles: [{type: cylinder, ...}]}
    cameras:                      # look-at, or calibrated: intrinsics {fx, fy, cx, cy} px + world_to_cam 3x4
      - {name: top, eye: [..], target: [..], up: [..], fovy_deg: 50, width: 128, height: 128}
    view: yz                      # the plane of 2-D figures: xz (default), yz (side views) or xy (top view)
    robot: {base: [0, 0, 0.33], frame: robot}  # the shoulder of the visual arm drawn in rendered images

Units: metres, seconds, degrees for angles. Every error is one line naming the file, the field and
the fix (:class:`~softsbi.core.errors.DataError`); nothing is built from an invalid file.

Frames of paths: ``scenario`` (the default) or a name under ``transforms``; a recording may supply
its own transforms (e.g. its robot -> scenario calibration), which replace the file's.
DiffCloud transform convention (``diffcloud:``; ``shared/data/README.md``): with row vectors
``p_sim = (((p + c) - t) / s) @ Rz(a)`` and the scenario frame is ``p_sim * s`` metres, i.e. the
rigid map ``p -> (p + c - t) @ Rz(a)``.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Literal, Mapping, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from softsbi.core.errors import DataError
from softsbi.core.types import Handle, Scenario
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


def _read_yaml(path: Path) -> Any:
    from softsbi.core.yamlfile import read_yaml
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


# ---------------------------------------------------------------------------------------------
# building a Scenario
# ---------------------------------------------------------------------------------------------
def transform_matrix(t: TransformSpec | Mapping[str, Any]) -> np.ndarray:
    """4x4 matrix (column vectors, metres) of a transform spec (or its mapping) into the scenario frame."""
    if not isinstance(t, TransformSpec):
        t = TransformSpec.model_validate(dict(t))
    if t.matrix is not None:
        return np.asarray(t.matrix, dtype=float)
    from scipy.spatial.transform import Rotation
    d = t.diffcloud
    rz = Rotation.from_euler("z", float(d.z_rotation), degrees=True).as_matrix()
    m = np.eye(4)
    m[:3, :3] = rz.T                        # row vectors: p @ Rz == Rz.T @ p (column)
    m[:3, 3] = rz.T @ (np.asarray(d.compensation_factor) - np.asarray(d.translation))
    return m


def apply_transform(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Points ``(..., 3)`` mapped by the 4x4 ``m``."""
    p = np.asarray(p, dtype=float)
    return p @ m[:3, :3].T + m[:3, 3]


def ease_keyframes(key_t: np.ndarray, key_p: np.ndarray, times: np.ndarray, easing: str) -> np.ndarray:
    """Piecewise path through keyframes ``key_p (K, 3)`` at ``key_t (K,)`` s, sampled at ``times``;
    each segment eased with the smoothstep ``3w^2 - 2w^3`` (zero velocity at every keyframe) or linear;
    held constant before the first and after the last keyframe."""
    out = np.empty((len(times), 3))
    for k, t in enumerate(times):
        i = int(np.clip(np.searchsorted(key_t, t, side="right") - 1, 0, len(key_t) - 2))
        span = key_t[i + 1] - key_t[i]
        w = float(np.clip((t - key_t[i]) / span, 0.0, 1.0)) if span > 0 else 1.0
        if easing == "smoothstep":
            w = w * w * (3.0 - 2.0 * w)
        out[k] = key_p[i] + w * (key_p[i + 1] - key_p[i])
    return out


def read_mesh(path: Path, source: str, field: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices ``(N, 3)`` (file units) and triangles ``(F, 3)`` of an ``.obj``, in file order, checked:
    every edge in at most two triangles (manifold), no degenerate triangle, at least one triangle.

    Raises:
        DataError: missing/unreadable file, non-manifold or degenerate mesh (names the file and field).
    """
    import trimesh
    if not path.is_file():
        raise DataError(f"{source}: field '{field}': mesh {path} {_missing(path)}; give a .obj file path relative "
                        f"to the scenario file")
    try:
        m = trimesh.load(str(path), process=False, force="mesh")
    except Exception as exc:  # noqa: BLE001 - trimesh raises many kinds
        raise DataError(f"{source}: field '{field}': cannot read mesh {path} ({exc}); give a triangle .obj") from None
    v = np.asarray(m.vertices, dtype=float)
    f = np.asarray(m.faces, dtype=np.int64)
    if not np.all(np.isfinite(v)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(v), axis=1))[0])
        raise DataError(f"{source}: field '{field}': mesh {path} has a NaN or infinite coordinate (vertex {bad}); "
                        f"fix the .obj file")
    if len(f) == 0:
        raise DataError(f"{source}: field '{field}': mesh {path} has no triangles; give a triangle .obj")
    if np.any(f[:, 0] == f[:, 1]) or np.any(f[:, 1] == f[:, 2]) or np.any(f[:, 0] == f[:, 2]) or \
            np.any(np.asarray(m.area_faces) <= 0):
        raise DataError(f"{source}: field '{field}': mesh {path} has degenerate triangles (repeated or collinear "
                        f"vertices); remove them")
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    if counts.max() > 2:
        e = uniq[int(np.argmax(counts))]
        raise DataError(f"{source}: field '{field}': mesh {path} is non-manifold (edge {int(e[0])}-{int(e[1])} "
                        f"is shared by {int(counts.max())} triangles); a cloth must be a surface where every edge "
                        f"borders at most two triangles: split or remove the extra triangles")
    return v, f


def _missing(path: Path) -> str:
    """Why ``path`` is not a file: ``"is a folder"`` or ``"does not exist"``."""
    return "is a folder" if path.is_dir() else "does not exist"


def _resolve_path(base: Path | None, rel: str) -> Path:
    p = Path(rel).expanduser()
    return p if p.is_absolute() or base is None else base / p


def build_scenario(spec: ScenarioSpec, source: str, base_dir: Path | None,
                   transforms: Mapping[str, Any] | None = None) -> Scenario:
    """The :class:`Scenario` a validated spec describes.

    Args:
        spec: :func:`parse_spec`'s result.
        source: the file (or description) named in errors.
        base_dir: folder relative paths (mesh, path files) are resolved against.
        transforms: named frame -> transform (:class:`TransformSpec` mapping or 4x4 matrix) replacing the
            file's (a recording's calibration).

    Raises:
        DataError: unknown frame name, a path whose length disagrees with the frames or that reaches beyond
            :data:`MAX_POSITION` from the origin, a handle vertex out
            of range or a grasp kind that does not fit the object, a missing or non-manifold mesh.
    """
    from softsbi.core.arrays import read_npy

    times = spec.frames.values()
    T = len(times)
    mats: dict[str, np.ndarray] = {"scenario": np.eye(4)}
    for k, t in spec.transforms.items():
        mats[k] = transform_matrix(t)
    for k, t in (transforms or {}).items():
        mats[k] = np.asarray(t, dtype=float) if isinstance(t, (np.ndarray, list)) else transform_matrix(t)

    # object (mesh first: grasps by point need its vertices)
    obj: dict[str, Any] = {"kind": spec.object.kind}
    verts = faces = None
    if spec.object.mesh is not None:
        mpath = _resolve_path(base_dir, spec.object.mesh.file)
        v, faces = read_mesh(mpath, source, "object.mesh.file")
        verts = v * float(spec.object.mesh.units)

    # handle paths
    handles: list[Handle] = []
    for i, h in enumerate(spec.handles):
        where = f"handles[{i}]"
        path = None
        if h.path is not None:
            pth = h.path
            if pth.frame not in mats:
                raise DataError(f"{source}: field '{where}.path.frame': unknown frame '{pth.frame}'; use 'scenario' "
                                f"or one of the names under 'transforms' ({', '.join(sorted(mats))})")
            if pth.file is not None:
                f = _resolve_path(base_dir, pth.file)
                if not f.is_file():
                    raise DataError(f"{source}: field '{where}.path.file': {f} {_missing(f)}; give a (T, 3) .npy "
                                    f"file relative to the scenario file")
                raw = read_npy(f, "handle path", "save a (T, 3) float array with numpy.save")
                if raw.ndim != 2 or raw.shape[1] != 3:
                    raise DataError(f"{source}: field '{where}.path.file': {f} must be (T, 3) positions, got "
                                    f"{raw.shape}")
                if len(raw) != T:
                    raise DataError(f"{source}: field '{where}.path.file': {f} has {len(raw)} rows but frames gives "
                                    f"{T} frames; give one row per frame (or set frames.count to {len(raw)})")
            elif pth.points is not None:
                raw = np.asarray(pth.points, dtype=float)
                if len(raw) != T:
                    raise DataError(f"{source}: field '{where}.path.points': {len(raw)} points but frames gives {T} "
                                    f"frames; give one point per frame (or set frames.count to {len(raw)})")
            else:
                kt = np.array([k.t for k in pth.keyframes])
                if kt[-1] > times[-1] + 1e-9:
                    raise DataError(f"{source}: field '{where}.path.keyframes': the last keyframe (t = {kt[-1]:g} s) "
                                    f"is after the last frame (t = {times[-1]:g} s); end the keyframes by then")
                raw = ease_keyframes(kt, np.array([k.p for k in pth.keyframes], dtype=float), times, pth.easing)
            path = apply_transform(mats[pth.frame], raw) + np.asarray(pth.offset, dtype=float)
            far = np.linalg.norm(path, axis=1)
            if not np.all(far <= MAX_POSITION):
                k = int(np.argmax(np.where(np.isfinite(far), far, np.inf)))
                raise DataError(f"{source}: field '{where}.path': the handle is {far[k]:.3g} m from the scenario origin "
                                f"at t = {times[k]:g} s, beyond the {MAX_POSITION:g} m a task can span; positions are "
                                f"metres in the path's frame (check the units and the frame's transform)")
        handles.append(Handle(h.name, h.grasp.as_dict(), path))
    gripper = next(h.path for h in handles if h.path is not None)

    # grasps fit the object
    for i, (h, hs) in enumerate(zip(handles, spec.handles)):
        field = f"handles[{i}].grasp"
        kind = next(iter(h.grasp))
        if kind == "vertex":
            if verts is None:
                raise DataError(f"{source}: field '{field}.vertex': a vertex index needs a mesh object (a grid's or "
                                f"rope's resolution is the backend's); use corner (grid) / end (rope) or point")
            if not h.grasp["vertex"] < len(verts):
                raise DataError(f"{source}: field '{field}.vertex': vertex {h.grasp['vertex']} is out of range, the "
                                f"mesh has {len(verts)} vertices (0..{len(verts) - 1}); choose one of those")
        elif kind == "corner" and (spec.object.kind != "cloth" or verts is not None):
            raise DataError(f"{source}: field '{field}.corner': corners are for a grid cloth; use vertex (mesh) or "
                            f"end (rope)")
        elif kind == "end" and spec.object.kind != "rope":
            raise DataError(f"{source}: field '{field}.end': ends are for a rope; use corner (grid) or vertex (mesh)")

    pl = spec.placement
    first = next(h for h in handles if h.path is not None)
    if verts is not None:
        # mesh cloth: rest flat on the table (z = the table's), the fit's scale and yaw act about the
        # first moving handle's vertex (the pivot)
        if "point" in first.grasp:
            pivot = int(np.argmin(np.linalg.norm(verts - np.asarray(first.grasp["point"]), axis=1)))
        else:
            pivot = int(first.grasp["vertex"])
        area = float(0.5 * np.linalg.norm(np.cross(verts[faces[:, 1]] - verts[faces[:, 0]],
                                                    verts[faces[:, 2]] - verts[faces[:, 0]]), axis=1).sum())
        far = verts[int(np.argmax(np.linalg.norm(verts[:, :2] - verts[pivot, :2], axis=1)))]
        d = far[:2] - verts[pivot, :2]
        obj.update(size=math.sqrt(area), corner=[float(verts[pivot, 0]), float(verts[pivot, 1])],
                   direction=[float(v) for v in d / np.linalg.norm(d)], grasp="vertex",
                   mesh={"vertices": verts.tolist(), "faces": faces.tolist(), "pivot": pivot, "rest": pl.rest,
                         "file": str(_resolve_path(base_dir, spec.object.mesh.file).resolve()),
                         "units": float(spec.object.mesh.units)})
    elif spec.object.kind == "cloth":
        corner = pl.corner if pl.corner is not None else (float(gripper[0, 0]), float(gripper[0, 1]))
        obj.update(size=float(spec.object.size), corner=[float(corner[0]), float(corner[1])],
                   direction=[float(v) for v in (pl.direction or (1.0, 0.0))], grasp="corner")
    else:
        start = pl.corner if pl.corner is not None else (float(gripper[0, 0]), float(gripper[0, 1]))
        obj.update(length=float(spec.object.length), radius=float(spec.object.radius or 0.004),
                   start=[float(start[0]), float(start[1])],
                   direction=[float(v) for v in (pl.direction or (0.0, -1.0))], grasp="end")
    if spec.object.fabric:
        obj["fabric"] = spec.object.fabric
    if pl.yaw_bounds is not None:
        obj["yaw_bounds"] = [float(pl.yaw_bounds[0]), float(pl.yaw_bounds[1])]
    obstacles = []
    for o in spec.world.obstacles:
        d = o.model_dump()
        d = {k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items() if v is not None}
        obstacles.append(d)
        if o.type == "cylinder" and o.occludes:  # observers hide what it occludes
            obj["spool"] = {"centre": list(o.centre), "radius": float(o.radius), "height": float(o.height)}
    world: dict[str, Any] = {}
    if tuple(spec.world.gravity) != (0.0, 0.0, -9.81):
        world["gravity"] = list(spec.world.gravity)
    if obstacles:
        world["obstacles"] = obstacles
    options = dict(spec.options)
    options.setdefault("source", source)
    moving = next(h for h in spec.handles if h.path is not None)
    if moving.path.keyframes is not None:  # the motion's phases (check's error by phase)
        options["keyframe_times"] = [float(k.t) for k in moving.path.keyframes]
    if spec.robot is not None:
        if "robot_base" in options:
            raise DataError(f"{source}: field 'robot' and options.robot_base both place the arm; keep one")
        if spec.robot.frame not in mats:
            raise DataError(f"{source}: field 'robot.frame': unknown frame '{spec.robot.frame}'; use 'scenario' or one "
                            f"of the names under 'transforms' ({', '.join(sorted(mats))})")
        options["robot_base"] = apply_transform(mats[spec.robot.frame], np.asarray(spec.robot.base, float)).tolist()
    return Scenario(name=spec.name, times=times, gripper=gripper, table_z=float(spec.world.table_z), object=obj,
                    options=options, handles=handles, world=world, cameras=camera_dicts(spec.cameras),
                    view=spec.view, description=spec.description)


def camera_dicts(cameras: list[CameraSpec]) -> list[dict[str, Any]]:
    """The cameras of a scenario file as :attr:`Scenario.cameras` keeps them (plain lists, no unset keys)."""
    from softsbi.core.types import jsonable
    return [jsonable(c.model_dump(exclude_none=True)) for c in cameras]


def load_scenario_file(path: str | Path, transforms: Mapping[str, Any] | None = None) -> Scenario:
    """Read, validate and build a scenario file (module docstring).

    Args:
        path: the ``.yaml`` file; relative paths inside it are resolved against its folder.
        transforms: named frames -> scenario frame replacing the file's (e.g. a recording's
            ``robot`` calibration).

    Raises:
        DataError: one line naming the file, the field and the fix.
    """
    path = Path(path)
    spec = parse_spec(_read_yaml(path), str(path))
    sc = build_scenario(spec, str(path), path.parent, transforms)
    sc.options["file"] = str(path.resolve())
    return sc


def load_scenario_data(data: Mapping[str, Any], source: str, base_dir: Path | None,
                       transforms: Mapping[str, Any] | None = None) -> Scenario:
    """:func:`load_scenario_file` for a mapping already read (an inline scenario of a recording)."""
    return build_scenario(parse_spec(data, source), source, base_dir, transforms)


def spec_from_scenario(sc: Scenario, description: str = "") -> dict[str, Any]:
    """A scenario-file mapping (inline in a recording) that builds ``sc`` again: paths as ``points`` in
    the scenario frame (exact), its ``description`` (``description`` replaces it when given), the object, placement, world and cameras; ``options`` kept when they are
    plain data. A mesh cloth refers to its ``.obj`` by absolute path.

    Raises:
        DataError: an object this format cannot express (e.g. a mesh cloth built in code without a file).
    """
    from softsbi.core.types import jsonable
    obj = sc.object
    kind = obj.get("kind", "cloth")
    o: dict[str, Any] = {"kind": kind}
    placement: dict[str, Any] = {}
    if kind == "rope":
        o.update(length=float(obj["length"]), radius=float(obj.get("radius", 0.004)))
        placement.update(corner=list(obj["start"]), direction=list(obj["direction"]))
    elif "mesh" in obj:
        if not obj["mesh"].get("file"):
            raise DataError(f"scenario '{sc.name}': a mesh cloth needs object['mesh']['file'] to be written out")
        o["mesh"] = {"file": str(obj["mesh"]["file"]), "units": float(obj["mesh"].get("units", 1.0))}
        placement["rest"] = obj["mesh"].get("rest", "flat")
    else:
        o["size"] = float(obj["size"])
        placement.update(corner=list(obj["corner"]), direction=list(obj["direction"]))
    if obj.get("fabric"):
        o["fabric"] = obj["fabric"]
    if obj.get("yaw_bounds") is not None:
        placement["yaw_bounds"] = [float(v) for v in obj["yaw_bounds"]]
    handles = []
    for h in sc.handles:
        d: dict[str, Any] = {"name": h.name, "grasp": jsonable(h.grasp)}
        if h.pinned:
            d["pinned"] = True
        else:
            d["path"] = {"points": np.asarray(h.path).tolist()}
        handles.append(d)
    world: dict[str, Any] = {"table_z": float(sc.table_z), "gravity": sc.gravity}
    obs = sc.world.get("obstacles")
    if obs is None and obj.get("spool"):
        sp = obj["spool"]
        obs = [{"type": "cylinder", "name": "spool", "centre": list(sp["centre"]), "radius": float(sp["radius"]),
                "height": float(sp["height"]), "occludes": True}]
    if obs:
        world["obstacles"] = jsonable(obs)
    out = {"format": FORMAT, "name": sc.name, "description": description or sc.description,
           "object": o, "placement": placement, "handles": handles, "frames": {"times": sc.times.tolist()},
           "world": world, "options": {k: v for k, v in jsonable(sc.options).items() if k != "transforms"}}
    if sc.cameras:
        out["cameras"] = jsonable(sc.cameras)
    if sc.view != "xz":
        out["view"] = sc.view
    return out
