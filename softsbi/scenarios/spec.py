"""Scenario files: a versioned YAML format, validated with pydantic v2, turned into a :class:`Scenario`.

A scenario file (``format: softsbi-scenario/1``) describes a task as data (docs/design.md, "Scenarios
and recordings are data")::

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
from typing import Any, Mapping

import numpy as np

from softsbi.core.arrays import read_npy
from softsbi.core.errors import DataError
from softsbi.core.types import Handle, Scenario, jsonable
# the format's models and reader (softsbi.scenarios.schema); FORMAT, MAX_POSITION, ScenarioSpec importable here too
from softsbi.scenarios.schema import (FORMAT, MAX_POSITION, CameraSpec, ScenarioSpec, TransformSpec,
                                      parse_spec, read_scenario_yaml)

# ---------------------------------------------------------------------------------------------
# building a Scenario
# ---------------------------------------------------------------------------------------------
def transform_matrix(t: TransformSpec | Mapping[str, Any]) -> np.ndarray:
    """4x4 matrix (column vectors, metres) of a transform spec (or its mapping) into the scenario frame."""
    if not isinstance(t, TransformSpec):
        t = TransformSpec.model_validate(dict(t))
    if t.matrix is not None:
        return np.asarray(t.matrix, dtype=float)
    from scipy.spatial.transform import Rotation  # heavy (scipy): loaded only for a diffcloud transform
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
    import trimesh  # heavy: loaded only for a scenario with a mesh
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
    for i, h in enumerate(handles):
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
    spec = parse_spec(read_scenario_yaml(path), str(path))
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


# -- what a built scenario declares beyond its core fields: the optional entries of its options and object -------
def keyframe_times(scenario: Scenario) -> list[float]:
    """The times (s, sorted) of the keyframes of a scenario file's gripper path (``options["keyframe_times"]``, which
    :func:`build_scenario` writes); ``[]`` for a scenario without them (a built-in one, or one stored before they
    were kept)."""
    return sorted(float(t) for t in (scenario.options or {}).get("keyframe_times") or [])


def scenario_source(scenario: Scenario) -> str:
    """Where a scenario was read from (``options["source"]``: a scenario file, or the recording folder a DiffCloud
    lift was derived from); ``""`` when it does not say."""
    return str((scenario.options or {}).get("source", ""))


def declared_size(scenario: Any) -> tuple[str | None, float | None]:
    """The kind of a scenario's object (its ``object.kind``; None when not declared) and the size it declares (m): a
    rope's ``length``, another object's ``size`` (a cloth's side); None when it declares none (a mesh)."""
    obj = getattr(scenario, "object", None) or {}
    return obj.get("kind"), obj.get("length") if obj.get("kind") == "rope" else obj.get("size")


def declared_spool(scenario: Scenario) -> Mapping[str, Any] | None:
    """The occluding spool a scenario's object is wound on (``object.spool``: ``centre``, ``radius``, ``height``, m;
    the built-in winding's), or None."""
    return (scenario.object or {}).get("spool")


def obstacles(scenario: Scenario) -> list[dict[str, Any]]:
    """The scenario's obstacles (``world["obstacles"]``; a scenario built in code with only
    ``object["spool"]`` gets that cylinder)."""
    obs = scenario.world.get("obstacles")
    if obs is None:
        sp = scenario.object.get("spool")
        obs = [{"type": "cylinder", "name": "spool", "centre": list(sp["centre"]), "radius": float(sp["radius"]),
                "height": float(sp["height"])}] if sp else []
    return list(obs)
