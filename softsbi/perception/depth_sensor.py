"""A virtual depth sensor: simulated point clouds made the way DiffCloud's real clouds were made.

The real lift/fold clouds of ``../shared/data/diffcloud_*`` come out of DiffCloud's post-processing
(``priyasundaresan/diffcloud_real2sim``, ``real/post_proc/generate_merged_masked_pcls.py``), per frame:

1. each RealSense camera (overhead, side; 640x480, ``calib_*/intrinsics.npy`` = ``(fx, fy, cx, cy)``,
   ``calib_*/trc.npy`` = robot base -> camera ``[R | t]``) gives one 3-D point per valid depth pixel,
   in the robot base frame;
2. the robot is masked in image space: a Blender render of the robot (``render_blender_masks.py``,
   480x480 = the central columns 80-559 of the 640x480 image) keeps only the pixels where the rendered
   table is visible (``mask == 0``); the mask is dilated. Pixels outside those 480 columns are dropped;
3. a robot-frame crop box (lift: ``x in [0.5, 0.95]``, ``y in [-0.35, 0.35]``, ``z in [0.075, 0.35]`` m in
   the repository's version; :func:`diffcloud_lift_crop`) and a statistical outlier filter (PCL,
   ``mean_k = 175``, ``std_mul = 0.5``:
   points whose mean distance to their 175 nearest neighbours exceeds the mean of that over the cloud by
   more than 0.5 standard deviations are removed), per camera;
4. the side camera's points are shifted by a hard-coded ``(0.0075, 0.0175, 0)`` m (robot frame;
   "sensor/calibration error" in the source), the cameras merged and **randomly subsampled with
   replacement** to ``n`` points (``np.random.choice``; 3500 for the lift recordings here);
5. the real -> simulator transform of the recording (``lift_real2sim.yaml``, see
   :mod:`softsbi.scenarios.builtin`).

:class:`VirtualDepthSensor` repeats these steps on a simulated mesh. It renders a depth image of the
cloth's triangles into every calibrated camera with a numpy z-buffer (exact ray/triangle intersections at
the pixel centres, no OpenGL), at a reduced resolution (default 160x120 px, intrinsics scaled by
:meth:`Camera.resized`), back-projects the valid pixels, masks the robot, crops, optionally filters, and
subsamples. Cost: about 2-4 ms per frame for the 81-vertex lift cloth on the shared 2-core machine.
Occlusion (the cloth hiding itself) and the unseen flat cloth follow from the geometry.

Frames (row-vector points, metres). The *scene* frame is the scenario's (lift: DiffCloud simulator frame
x 0.35 m). ``scene_to_robot`` is the 4x4 matrix ``M`` with ``p_robot = M [p_scene, 1]``; for a DiffCloud
recording it is the inverse of the recording's real2sim transform, ``p_robot = p_scene Rz(a)^T + t - c``
(:func:`softsbi.scenarios.builtin.lift_frame_to_real`; the scale cancels in the lift frame). A camera of
robot-frame pose ``[R | t_c]`` that DiffCloud shifts by ``delta`` (step 4) sees scene point ``p`` at
``R (M p - delta) + t_c``: its true centre is the calibrated one moved by ``delta``, so the back-projected
point plus ``delta`` is the surface point itself (the virtual cameras are exact) while occlusion is
computed from where the camera was.

Modelling choices, stated (the source does not fix them):

* **Robot mask.** The robot is a sphere of radius ``mask_radius`` centred ``mask_lift`` above the grasp
  point (the gripper body sits on the grasped corner); like DiffCloud's rendered silhouette it removes
  every pixel whose ray passes through it, cloth in front of the gripper included. Arm links are not
  modelled (behind the cloth in the overhead view, above it in the side view). Evidence: with the grasp
  point at the cloud's top (the scenarios' data-derived grasp offset), the real clouds reach within
  0.4-0.7 cm of it (median over frames 10-24, 7 of the 10 lift recordings; the other 3 miss the offset's
  vertical part), so the mask cannot extend below the grasp point.
* **Crop plane vs simulated table.** The crop's ``z >= 0.075`` m is the scenarios' table (``table_z``, by
  construction: every recording's lowest point sits there); the real cloth lying flat is not in the
  clouds, so the real table is below the crop. mujoco-flex rests a flat cloth 3 mm above ``table_z``
  (its contact margin; measured on the lift at the prior midpoint), so the crop is applied
  ``crop_clearance`` (default 5 mm) above the mapped plane: a flat simulated cloth is unseen, as the real
  one is, and a fold or wrinkle rising a few millimetres is seen.
* **Depth noise** of the RealSense is not modelled.
* **Outlier filter off by default.** DiffCloud's statistical filter (step 3) is implemented
  (:func:`statistical_outliers`, ``outlier=DIFFCLOUD_OUTLIER``; ``k`` scaled with the pixel count, which
  removes the same 13-26 % of a camera's points at 160x120 as at 640x480), but its threshold (mean + 0.5
  standard deviations of the k-nearest-neighbour distances) depends on the real depth noise, which the
  noiseless render lacks: on the five first-repeat lift recordings at their fits' posterior means it
  removes edges the real clouds keep (one-sided measured -> simulated Chamfer of the hanging frames 1.95
  cm with it, 1.85 cm without; the second repeats agree, 1.70 vs 1.52 cm;
  ``benchmarks/studies/virtual_sensor.py``).
* **Resolution.** 160x120 px (intrinsics scaled from 640x480); 320x240 changes the per-phase Chamfer of the
  same benchmark by <= 0.06 cm at 1.5x the cost.
"""
from __future__ import annotations

import json
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from softsbi.core.camera import Camera
from softsbi.core.errors import DataError, ShapeError
from softsbi.core.types import Scenario
from softsbi.perception.clouds import sensor_chamfer_per_frame, sensor_indices
from softsbi.scenarios.builtin import lift_scenario, load_recording, recording_transform

#: DiffCloud's lift crop box in the robot base frame, m (``filter_pointcloud`` of the post-processing,
#: repository version): ``(min (3,), max (3,))``. The recordings tan2, redblack, redblack2 end exactly on
#: it (y >= -0.35, z <= 0.350); the other seven stop at y <= 0.30 and reach z = 0.40-0.42, i.e. they were
#: cropped with an earlier box (:data:`DIFFCLOUD_LIFT_CROP_EARLY`). See :func:`diffcloud_lift_crop`.
DIFFCLOUD_LIFT_CROP = ((0.5, -0.35, 0.075), (0.95, 0.35, 0.35))
#: the crop box the seven other lift recordings are consistent with (y <= 0.30, no upper z cut seen), m
DIFFCLOUD_LIFT_CROP_EARLY = ((0.5, -0.35, 0.075), (0.95, 0.30, np.inf))
#: DiffCloud's hard-coded shift of the side RealSense's points, robot frame, m
DIFFCLOUD_SIDE_OFFSET = (0.0075, 0.0175, 0.0)
#: PCL statistical outlier filter of DiffCloud (at 640x480): neighbours, std multiplier
DIFFCLOUD_OUTLIER = (175, 0.5)
#: image columns DiffCloud keeps (its masks are 480x480, centre-cropped from 640x480), px at 640 wide
DIFFCLOUD_COLUMNS = (80, 560)
#: full calibration resolution of the DiffCloud RealSense intrinsics, px
CALIB_SIZE = (640, 480)
_NEAR = 0.05  # m: triangles with a vertex closer than this to a camera are not rendered by it


def rasterize_depth(camera: Camera, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Depth image of a triangle mesh: a z-buffer of exact ray/triangle intersections (no OpenGL).

    For every pixel centre ``(u, v)`` (OpenCV convention, :mod:`softsbi.core.camera`) inside a triangle's
    bounding box the ray ``((u - cx) / fx, (v - cy) / fy, 1)`` is intersected with the triangle
    (Moller-Trumbore; both faces count, cloth is two-sided); the nearest hit wins.

    Args:
        camera: the camera (``world_to_cam`` maps the mesh's frame to the camera).
        vertices: ``(N, 3)`` m. faces: ``(F, 3)`` int indices into ``vertices``.

    Returns:
        ``(H, W)`` float64 depth along the optical axis, m; ``inf`` where no triangle is hit.
        Triangles with a vertex within 5 cm of the camera plane or behind it are skipped.

    Raises:
        ShapeError: ``vertices`` not ``(N, 3)`` or ``faces`` not ``(F, 3)`` indices into them.
    """
    v = np.asarray(vertices, float)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ShapeError(f"vertices must be (N, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or (f.size and (f.min() < 0 or f.max() >= len(v))):
        raise ShapeError(f"faces must be (F, 3) indices into the {len(v)} vertices, got shape {f.shape}")
    W, H = camera.width, camera.height
    depth = np.full(H * W, np.inf)
    if f.size == 0:
        return depth.reshape(H, W)
    pc = camera.to_camera(v)
    tri = pc[f]  # (F, 3, 3) camera frame
    ok = (tri[:, :, 2] > _NEAR).all(axis=1)
    tri = tri[ok]
    if not len(tri):
        return depth.reshape(H, W)
    u = camera.fx * tri[:, :, 0] / tri[:, :, 2] + camera.cx
    w = camera.fy * tri[:, :, 1] / tri[:, :, 2] + camera.cy
    u0 = np.clip(np.ceil(u.min(1)), 0, W).astype(int)
    u1 = np.clip(np.floor(u.max(1)), -1, W - 1).astype(int)
    v0 = np.clip(np.ceil(w.min(1)), 0, H).astype(int)
    v1 = np.clip(np.floor(w.max(1)), -1, H - 1).astype(int)
    nu = np.maximum(u1 - u0 + 1, 0)
    nv = np.maximum(v1 - v0 + 1, 0)
    cnt = nu * nv
    if cnt.sum() == 0:
        return depth.reshape(H, W)
    k = np.repeat(np.arange(len(tri)), cnt)
    local = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    pu = u0[k] + local % nu[k]
    pv = v0[k] + local // nu[k]
    d = np.stack([(pu - camera.cx) / camera.fx, (pv - camera.cy) / camera.fy, np.ones(len(pu))], axis=1)
    a, b, c = tri[k, 0], tri[k, 1], tri[k, 2]
    e1, e2 = b - a, c - a
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    good = np.abs(det) > 1e-12
    inv = np.where(good, 1.0 / np.where(good, det, 1.0), 0.0)
    s = -a
    bu = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    bv = np.einsum("ij,ij->i", d, q) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv  # = depth, since d_z = 1
    hit = good & (bu >= 0) & (bv >= 0) & (bu + bv <= 1) & (t > _NEAR)
    np.minimum.at(depth, pv[hit] * W + pu[hit], t[hit])
    return depth.reshape(H, W)


def statistical_outliers(points: np.ndarray, k: int, std_mul: float) -> np.ndarray:
    """PCL's statistical outlier filter (``StatisticalOutlierRemoval``), as DiffCloud applies it.

    A point is an outlier when its mean distance to its ``k`` nearest neighbours exceeds the mean of
    that quantity over the cloud by more than ``std_mul`` standard deviations.

    Args:
        points: ``(P, 3)`` m. k: neighbours (clipped to ``P - 1``). std_mul: threshold multiplier.

    Returns:
        ``(P,)`` bool, True = outlier (removed). Nothing is removed when ``P <= 2`` or ``k < 1``.
    """
    from scipy.spatial import cKDTree  # heavy (~1 s): only outlier removal needs it
    n = len(points)
    k = min(int(k), n - 1)
    if n <= 2 or k < 1:
        return np.zeros(n, bool)
    dist, _ = cKDTree(points).query(points, k=k + 1)
    m = dist[:, 1:].mean(axis=1)
    return m > m.mean() + std_mul * m.std()


@dataclass(frozen=True)
class VirtualDepthSensor:
    """Simulated depth-camera point clouds made like DiffCloud's real ones (module docstring).

    Attributes:
        cameras: the calibrated cameras at the render resolution; ``world_to_cam`` maps the **robot base
            frame** to each camera (as ``trc.npy``).
        scene_to_robot: ``(4, 4)`` homogeneous ``p_robot = M [p_scene, 1]`` (m).
        offsets: per camera, the robot-frame shift ``(3,)`` m DiffCloud adds to its points.
        crop_min, crop_max: robot-frame crop box ``(3,)`` m (``inf`` = open side).
        crop_clearance: m added to ``crop_min``'s z (the simulated flat cloth rests above the table).
        mask_radius: radius of the gripper sphere, m (0 = no robot mask). mask_lift: its centre above the
            grasp point, m (along the scene's z).
        columns: per camera, the pixel columns ``[c0, c1)`` kept (at the render resolution).
        outlier_k, outlier_std: the statistical outlier filter (``outlier_k = 0``: off); ``outlier_k`` is
            at the render resolution (DiffCloud's 175 at 640x480 scales with the pixel count).
        n_points: points per frame after subsampling with replacement (DiffCloud: 3500; 0 = no subsampling,
            every kept pixel once).
    """

    cameras: tuple
    scene_to_robot: np.ndarray = field(default_factory=lambda: np.eye(4))
    offsets: tuple = ()
    crop_min: tuple = DIFFCLOUD_LIFT_CROP[0]
    crop_max: tuple = DIFFCLOUD_LIFT_CROP[1]
    crop_clearance: float = 0.005
    mask_radius: float = 0.03
    mask_lift: float = 0.03
    columns: tuple = ()
    outlier_k: int = 0
    outlier_std: float = 0.5
    n_points: int = 3500

    def __post_init__(self) -> None:
        cams = tuple(self.cameras)
        if not cams or not all(isinstance(c, Camera) for c in cams):
            raise DataError("VirtualDepthSensor needs at least one Camera; build it with "
                            "VirtualDepthSensor.from_calibration([calib_overhead, calib_side], ...)")
        m = np.asarray(self.scene_to_robot, float)
        if m.shape != (4, 4) or not np.allclose(m[3], [0, 0, 0, 1]) or not np.all(np.isfinite(m)):
            raise ShapeError(f"scene_to_robot must be a finite 4x4 homogeneous matrix (last row 0 0 0 1), "
                             f"got shape {m.shape}")
        offs = (tuple(np.asarray(o, float) for o in self.offsets) if self.offsets
                else tuple(np.zeros(3) for _ in cams))
        cols = (tuple(tuple(int(x) for x in c) for c in self.columns) if self.columns
                else tuple((0, c.width) for c in cams))
        if len(offs) != len(cams) or any(o.shape != (3,) for o in offs):
            raise ShapeError(f"offsets must give one (3,) shift per camera ({len(cams)}), got {len(offs)}")
        if len(cols) != len(cams):
            raise ShapeError(f"columns must give one (c0, c1) per camera ({len(cams)}), got {len(cols)}")
        if self.mask_radius < 0 or self.n_points < 0 or self.outlier_k < 0:
            raise DataError(f"mask_radius, n_points and outlier_k must be >= 0, got {self.mask_radius}, "
                            f"{self.n_points}, {self.outlier_k}")
        object.__setattr__(self, "cameras", cams)
        object.__setattr__(self, "scene_to_robot", m)
        object.__setattr__(self, "offsets", offs)
        object.__setattr__(self, "columns", cols)
        lo = np.asarray(self.crop_min, float).copy()
        lo[2] += float(self.crop_clearance)
        object.__setattr__(self, "_lo", lo)
        object.__setattr__(self, "_hi", np.asarray(self.crop_max, float))
        # scene -> camera for each camera: R (M p - delta) + t
        A, b = m[:3, :3], m[:3, 3]
        scene_cams = []
        for cam, o in zip(cams, offs):
            R, t = cam.R, cam.t
            scene_cams.append(Camera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy,
                                     np.hstack([R @ A, (R @ (b - o) + t)[:, None]])))
        object.__setattr__(self, "_scene_cams", tuple(scene_cams))
        object.__setattr__(self, "_robot_to_scene", np.linalg.inv(m))
        # renders kept while shared_renders() is active: {"depth": nesting, "memo": {frame key: (P, 3)}}
        object.__setattr__(self, "_shared", {"depth": 0, "memo": {}})

    # -- construction ------------------------------------------------------------------
    @classmethod
    def from_calibration(cls, folders: Sequence[str | Path], scene_to_robot: np.ndarray | None = None, *,
                         resolution: tuple[int, int] = (160, 120), offsets: Sequence[Sequence[float]] | None = None,
                         crop: tuple = DIFFCLOUD_LIFT_CROP, crop_clearance: float = 0.005,
                         mask_radius: float = 0.03, mask_lift: float = 0.03, n_points: int = 3500,
                         outlier: tuple[int, float] | None = None,
                         columns: tuple[int, int] | None = DIFFCLOUD_COLUMNS) -> "VirtualDepthSensor":
        """Sensor from DiffCloud calibration folders (``intrinsics.npy`` ``(4,)`` for 640x480, ``trc.npy``
        ``(3, 4)`` robot -> camera), rendered at ``resolution = (W, H)`` px (intrinsics scaled).

        Args:
            folders: one calibration folder per camera (``.../calib_overhead``, ``.../calib_side``).
            scene_to_robot: ``(4, 4)``, scene -> robot base frame (default identity: the scene is the robot
                frame). For a DiffCloud recording use :meth:`for_diffcloud_recording`.
            offsets: per camera robot-frame shift ``(3,)`` m of its points (DiffCloud's side offset).
            crop: robot-frame box ``(min (3,), max (3,))`` m. crop_clearance: m above ``min z``.
            mask_radius, mask_lift: the gripper sphere, m. n_points: points per frame (0: all kept pixels).
            outlier: ``(k, std_mul)`` at 640x480 (``k`` is scaled by the pixel count), e.g.
                :data:`DIFFCLOUD_OUTLIER`, or None (off, the default: module docstring).
            columns: ``(c0, c1)`` px at 640 wide kept in every camera (scaled), or None (all).

        Raises:
            DataError: a missing folder or calibration file, wrong shapes (one line naming the file).
        """
        if isinstance(folders, (str, Path)):
            folders = [folders]
        if not folders:
            raise DataError("from_calibration needs at least one calibration folder (calib_overhead, calib_side)")
        W, H = int(resolution[0]), int(resolution[1])
        cams = []
        for folder in folders:
            if not Path(folder).is_dir():
                raise DataError(f"calibration folder '{folder}' does not exist; pass folders holding "
                                f"intrinsics.npy (fx, fy, cx, cy) and trc.npy (robot -> camera 3x4)")
            cams.append(Camera.from_calibration(folder, *CALIB_SIZE).resized(W, H))
        s = W / CALIB_SIZE[0]
        k = 0 if outlier is None else max(1, int(round(outlier[0] * (W * H) / (CALIB_SIZE[0] * CALIB_SIZE[1]))))
        cols = () if columns is None else tuple((int(round(columns[0] * s)), int(round(columns[1] * s))) for _ in cams)
        return cls(tuple(cams), np.eye(4) if scene_to_robot is None else scene_to_robot,
                   tuple(offsets) if offsets is not None else (), tuple(crop[0]), tuple(crop[1]),
                   float(crop_clearance), float(mask_radius), float(mask_lift), cols, k,
                   0.5 if outlier is None else float(outlier[1]), int(n_points))

    @classmethod
    def for_diffcloud_recording(cls, recording: str | Path, calibration: str | Path | None = None,
                                scenario: Scenario | None = None, **kwargs) -> "VirtualDepthSensor":
        """The sensor of a DiffCloud lift recording folder (``.../diffcloud_lift/lift_tan``), in the lift
        frame: its ``lift_real2sim.yaml`` (:func:`softsbi.scenarios.builtin.recording_transform`), the
        calibration folders ``calib_overhead``, ``calib_side`` of ``calibration`` (default: the recording's
        parent), the side offset, and the crop box its clouds are consistent with
        (:func:`diffcloud_lift_crop`). ``kwargs`` go to :meth:`from_calibration`.

        ``scenario``: the lift the sensor looks at, when its frame is a translation of the recording's own
        lift frame (:func:`~softsbi.scenarios.builtin.lift_scenario`): the lift task that the rig's recordings
        share (:func:`~softsbi.scenarios.builtin.lift_task`). The translation is where the scenario's gripper
        starts against where the recording's own lift starts. None: the recording's own lift frame.

        Raises:
            DataError: missing yaml, calibration or frames.
        """
        rec = Path(recording)
        cfg = recording_transform(rec)
        calib = Path(calibration) if calibration is not None else rec.parent
        M = diffcloud_scene_to_robot(cfg)
        kwargs.setdefault("crop", diffcloud_lift_crop(load_recording(rec), M))
        if scenario is not None:  # scene points of the scenario's frame -> the recording's own lift frame -> robot
            back = np.eye(4)
            back[:3, 3] = lift_scenario(rec, len(scenario.times)).gripper[0] - np.asarray(scenario.gripper[0], float)
            M = M @ back
        kwargs.setdefault("offsets", ((0.0, 0.0, 0.0), DIFFCLOUD_SIDE_OFFSET))
        return cls.from_calibration([calib / "calib_overhead", calib / "calib_side"], M, **kwargs)

    def to_json(self) -> dict:
        """JSON-able dict (a fit's run config keeps its metric's sensor this way); :meth:`from_json` inverts it."""
        inf = lambda a: [None if not np.isfinite(x) else float(x) for x in a]  # noqa: E731
        return {"cameras": [c.to_json() for c in self.cameras], "scene_to_robot": self.scene_to_robot.tolist(),
                "offsets": [o.tolist() for o in self.offsets], "crop_min": inf(self.crop_min),
                "crop_max": inf(self.crop_max), "crop_clearance": self.crop_clearance,
                "mask_radius": self.mask_radius, "mask_lift": self.mask_lift,
                "columns": [list(c) for c in self.columns], "outlier_k": self.outlier_k,
                "outlier_std": self.outlier_std, "n_points": self.n_points}

    @classmethod
    def from_json(cls, d) -> "VirtualDepthSensor":
        """Inverse of :meth:`to_json` (``None`` in a crop bound = open, +-inf).

        Raises:
            DataError: a missing key (the dict is not a stored sensor).
        """
        try:
            lo = tuple(-np.inf if x is None else float(x) for x in d["crop_min"])
            hi = tuple(np.inf if x is None else float(x) for x in d["crop_max"])
            return cls(tuple(Camera.from_json(c) for c in d["cameras"]), np.asarray(d["scene_to_robot"], float),
                       tuple(tuple(o) for o in d["offsets"]), lo, hi, float(d["crop_clearance"]),
                       float(d["mask_radius"]), float(d["mask_lift"]), tuple(tuple(c) for c in d["columns"]),
                       int(d["outlier_k"]), float(d["outlier_std"]), int(d["n_points"]))
        except KeyError as exc:
            raise DataError(f"stored virtual depth sensor lacks {exc}; re-create it with "
                            f"VirtualDepthSensor.for_diffcloud_recording(...).to_json()") from None

    # -- the sensor ----------------------------------------------------------------------
    def _camera_points(self, vertices: np.ndarray, faces: np.ndarray, gripper: np.ndarray | None
                       ) -> list[np.ndarray]:
        """Per camera, the kept points ``(P_i, 3)`` in the robot frame before the offset (steps 1-3)."""
        out = []
        centre = None
        if gripper is not None and self.mask_radius > 0:
            g = np.asarray(gripper, float).reshape(3)
            centre = g + np.array([0.0, 0.0, self.mask_lift])
        for cam, rcam, off, (c0, c1) in zip(self._scene_cams, self.cameras, self.offsets, self.columns):
            depth = rasterize_depth(cam, vertices, faces)
            depth[:, :c0] = np.inf
            depth[:, c1:] = np.inf
            vv, uu = np.nonzero(np.isfinite(depth))
            z = depth[vv, uu]
            dirs = np.stack([(uu - cam.cx) / cam.fx, (vv - cam.cy) / cam.fy, np.ones(len(uu))], axis=1)
            if centre is not None and len(uu):
                c = cam.to_camera(centre)
                dn = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
                along = dn @ c
                keep = ~((along > 0) & (c @ c - along ** 2 < self.mask_radius ** 2))
                dirs, z = dirs[keep], z[keep]
            pc = dirs * z[:, None]
            # camera -> robot frame as the real camera measured it (before DiffCloud's offset)
            pr = (pc - rcam.t) @ rcam.R
            inside = np.all((pr >= self._lo) & (pr <= self._hi), axis=1)
            pr = pr[inside]
            if self.outlier_k > 0 and len(pr) > 2:
                pr = pr[~statistical_outliers(pr, self.outlier_k, self.outlier_std)]
            out.append(pr + off)
        return out

    @contextmanager
    def shared_renders(self) -> Iterator["VirtualDepthSensor"]:
        """Within the block every distinct frame is rendered once: :meth:`observe` of the same
        ``(vertices, faces, gripper)`` (compared by value) reuses the kept pixels of the first call, and the
        subsampling still draws from each call's ``rng`` exactly as without the block, so the results are
        bit-identical. A simulation job wraps its observer and its metric in it (both see every frame of
        the rollout through this sensor); the kept renders are dropped when the outermost block ends.
        Nesting is allowed."""
        st = self._shared
        st["depth"] += 1
        try:
            yield self
        finally:
            st["depth"] -= 1
            if st["depth"] <= 0:
                st["depth"] = 0
                st["memo"].clear()

    def _kept_points(self, vertices: np.ndarray, faces: np.ndarray, gripper: np.ndarray | None) -> np.ndarray:
        """Steps 1-4 before the subsampling: every kept pixel ``(P, 3)`` of all cameras, robot frame with the
        offsets added; memoised by value inside :meth:`shared_renders` (read-only then)."""
        st = self._shared
        if not st["depth"]:
            return np.concatenate(self._camera_points(vertices, faces, gripper), axis=0)
        v, f = np.ascontiguousarray(vertices, float), np.ascontiguousarray(faces)
        g = None if gripper is None else np.ascontiguousarray(gripper, float)
        key = (v.shape, v.tobytes(), f.shape, f.dtype.str, f.tobytes(), None if g is None else g.tobytes())
        pts = st["memo"].get(key)
        if pts is None:
            pts = np.concatenate(self._camera_points(vertices, faces, gripper), axis=0)
            pts.setflags(write=False)
            st["memo"][key] = pts
        return pts

    def observe(self, vertices: np.ndarray, faces: np.ndarray, gripper: np.ndarray | None,
                rng: np.random.Generator) -> np.ndarray:
        """The virtual sensor's cloud of one simulated frame.

        Args:
            vertices: ``(N, 3)`` m, scene frame. faces: ``(F, 3)`` int.
            gripper: ``(3,)`` m, the grasp point (scene frame) for the robot mask, or None (no mask).
            rng: for the subsampling.

        Returns:
            ``(n_points, 3)`` m in the scene frame (drawn with replacement from the kept pixels, like
            DiffCloud), or every kept pixel once when ``n_points == 0``; ``(0, 3)`` when nothing is seen.

        Raises:
            ShapeError: bad ``vertices`` / ``faces``.
        """
        pts = self._kept_points(vertices, faces, gripper)
        if len(pts) and self.n_points:
            pts = pts[rng.choice(len(pts), size=self.n_points, replace=True)]
        return pts @ self._robot_to_scene[:3, :3].T + self._robot_to_scene[:3, 3]

    def observe_rollout(self, vertices: np.ndarray, faces: np.ndarray, gripper: np.ndarray | None,
                        rng: np.random.Generator) -> list[np.ndarray]:
        """:meth:`observe` for every frame: ``vertices (T, N, 3)``, ``gripper (T, 3)`` or None -> ``T`` clouds."""
        v = np.asarray(vertices, float)
        if v.ndim != 3:
            raise ShapeError(f"vertices must be (T, N, 3), got {v.shape}")
        return [self.observe(v[i], faces, None if gripper is None else np.asarray(gripper)[i], rng)
                for i in range(len(v))]

    def seen(self, points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, gripper: np.ndarray | None,
             tolerance: float = 0.005) -> np.ndarray:
        """Which surface points ``(P, 3)`` m (scene frame, e.g. area-weighted samples of the same mesh) the
        sensor sees: in some camera, the rendered depth of the pixel the point projects to (inside the kept
        columns) is not more than ``tolerance`` m in front of it (no surface hides it), the robot mask does
        not cover it, and it passes the crop. Returns ``(P,)`` bool. The outlier
        filter is not applied (a pixel test, not a cloud)."""
        p = np.asarray(points, float)
        vis = np.zeros(len(p), bool)
        centre = None
        if gripper is not None and self.mask_radius > 0:
            centre = np.asarray(gripper, float).reshape(3) + np.array([0.0, 0.0, self.mask_lift])
        M = self.scene_to_robot
        for cam, off, (c0, c1) in zip(self._scene_cams, self.offsets, self.columns):
            depth = rasterize_depth(cam, vertices, faces)
            uv, z = cam.project(p)
            u = np.rint(uv[:, 0]).astype(int)
            v = np.rint(uv[:, 1]).astype(int)
            ok = (z > _NEAR) & (u >= c0) & (u < c1) & (v >= 0) & (v < cam.height)
            d = np.full(len(p), np.inf)
            d[ok] = depth[v[ok], u[ok]]
            ok &= d >= z - tolerance  # nothing in front (an empty pixel at the mesh's border counts as free)
            if centre is not None:
                pc = cam.to_camera(p)
                c = cam.to_camera(centre)
                dn = pc / np.linalg.norm(pc, axis=1, keepdims=True)
                along = dn @ c
                ok &= ~((along > 0) & (c @ c - along ** 2 < self.mask_radius ** 2))
            pr = p @ M[:3, :3].T + M[:3, 3] - off
            ok &= np.all((pr >= self._lo) & (pr <= self._hi), axis=1)
            vis |= ok
        return vis


def diffcloud_scene_to_robot(cfg) -> np.ndarray:
    """``(4, 4)`` lift frame -> robot base frame of a DiffCloud real2sim transform ``cfg``
    (:func:`softsbi.scenarios.builtin.recording_transform`): ``p_robot = p_lift Rz(a)^T + t - c`` (m)."""
    from scipy.spatial.transform import Rotation  # heavy (~1 s): only the DiffCloud transform needs it
    rz = Rotation.from_euler("z", float(cfg["z_rotation"]), degrees=True).as_matrix()
    m = np.eye(4)
    m[:3, :3] = rz
    m[:3, 3] = np.asarray(cfg["translation"], float) - np.asarray(cfg["compensation_factor"], float)
    return m


def diffcloud_lift_crop(clouds_scene: np.ndarray | Sequence[np.ndarray], scene_to_robot: np.ndarray,
                        tol: float = 0.002) -> tuple:
    """The DiffCloud crop box a lift recording's clouds are consistent with.

    :data:`DIFFCLOUD_LIFT_CROP` (the repository's box) when every point of every frame lies inside it
    (within ``tol`` m), else :data:`DIFFCLOUD_LIFT_CROP_EARLY`.

    Args:
        clouds_scene: ``T`` clouds ``(P, 3)`` m in the scene frame. scene_to_robot: ``(4, 4)``.
    """
    M = np.asarray(scene_to_robot, float)
    pts = np.concatenate([np.asarray(c, float) for c in clouds_scene]) @ M[:3, :3].T + M[:3, 3]
    lo, hi = np.asarray(DIFFCLOUD_LIFT_CROP[0]), np.asarray(DIFFCLOUD_LIFT_CROP[1])
    if np.all(pts >= lo - tol) and np.all(pts <= hi + tol):
        return DIFFCLOUD_LIFT_CROP
    return DIFFCLOUD_LIFT_CROP_EARLY


_FROM_JSON: dict[str, VirtualDepthSensor] = {}


def sensor_from_json(d: dict) -> VirtualDepthSensor:
    """:meth:`VirtualDepthSensor.from_json`, kept per process by the JSON's content: a simulation worker,
    ``check`` and ``diagnose`` build each stored sensor (a fit's ``metric_camera``) once, not per rollout.
    The sensor is immutable, so sharing it is safe.

    Raises:
        DataError: as :meth:`VirtualDepthSensor.from_json`.
    """
    key = json.dumps(d, sort_keys=True)
    if key not in _FROM_JSON:
        _FROM_JSON[key] = VirtualDepthSensor.from_json(d)
    return _FROM_JSON[key]


def views_or_highest(views: Sequence[np.ndarray], surface: Sequence[np.ndarray]) -> list[np.ndarray]:
    """The virtual sensor's clouds with the metric's convention for a frame it sees nothing of (cloth lying
    flat): that frame's highest :data:`~softsbi.perception.pointcloud.FALLBACK_SHARE` of ``surface[t]`` stand
    in (:func:`~softsbi.perception.pointcloud.sensor_indices` with no height cut), so every frame has a
    defined distance. The one place this convention lives for camera fits (the fit's metric, ``check``'s
    regions, the posterior-predictive summaries and Chamfer energy score).

    Args:
        views: ``T`` clouds ``(P_t, 3)`` m seen by the sensor (``P_t`` may be 0).
        surface: ``T`` surface samples ``(n_t, 3)`` m of the same frames (or any stand-in cloud).

    Returns:
        ``T`` clouds ``(P'_t, 3)`` m, ``P'_t >= 1`` where ``surface[t]`` has points.

    Raises:
        ShapeError: different frame counts.
    """
    if len(views) != len(surface):
        raise ShapeError(f"frame counts differ: sensor views {len(views)}, surface samples {len(surface)}")
    out = []
    for c, s in zip(views, surface):
        if len(c):
            out.append(c)
        else:
            s = np.asarray(s, float)
            out.append(s[sensor_indices(s, np.inf)])
    return out


def camera_chamfer_per_frame(sensor: VirtualDepthSensor, vertices: np.ndarray, faces: np.ndarray,
                             gripper: np.ndarray | None, measured, surface, rng: np.random.Generator
                             ) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame distances between a rollout seen through the virtual depth sensor and recorded clouds.

    The recorded clouds are used as recorded (the real sensor already made them); the simulated ones are
    :meth:`VirtualDepthSensor.observe` of each frame. A frame the sensor sees nothing of (cloth lying flat)
    is scored with the highest 10 % of ``surface[t]`` instead, the convention of
    :func:`softsbi.perception.pointcloud.sensor_indices`, so every frame has a defined distance.

    Args:
        sensor: the virtual sensor. vertices: ``(T, N, 3)`` m. faces: ``(F, 3)``. gripper: ``(T, 3)`` m or None.
        measured: ``T`` clouds ``(m_t, 3)`` m. surface: ``T`` surface samples ``(n, 3)`` m (fallback only).
        rng: for the sensor's subsampling.

    Returns:
        ``(bidirectional (T,), one_sided (T,))`` m: the bidirectional Chamfer and ``D(measured -> simulated)``,
        as :func:`softsbi.perception.pointcloud.sensor_chamfer_per_frame`.

    Raises:
        ShapeError: different frame counts.
    """
    v = np.asarray(vertices, float)
    if not (len(v) == len(measured) == len(surface)):
        raise ShapeError(f"frame counts differ: rollout {len(v)}, measured {len(measured)}, surface {len(surface)}")
    sims = [sensor.observe(v[t], faces, None if gripper is None else np.asarray(gripper)[t], rng)
            for t in range(len(v))]
    # the simulated views are the sensor's already
    return sensor_chamfer_per_frame(views_or_highest(sims, surface), measured, None)
