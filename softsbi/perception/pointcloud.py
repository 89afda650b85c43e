"""Point-cloud observer (simulated rollouts) and the real point-cloud loader.

The observed state per frame is ``s_t = [gripper, k_1..k_K]`` (Antonova et al. 2022,
Sec. IV: keypoints / points are samples of a distribution): K points sampled
*area-weighted* on the simulated cloth surface, or subsampled from a recorded cloud,
independently in every frame, so the K points are an unordered set with no
correspondence across frames.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar, Mapping, Sequence

import numpy as np

from softsbi.core.arrays import read_npy
from softsbi.core.errors import DataError
from softsbi.core.interfaces import Observer
from softsbi.core.types import Observation, Rollout
from softsbi.data.frames import numbered_files
from softsbi.plugins.hookspecs import hookimpl
# the cloud operations live in clouds; the workflows and studies import them from here too
from softsbi.perception.clouds import (FALLBACK_SHARE, arm_hidden, combined_min_z, effect_views,  # noqa: F401
                                       occluded_by_cylinder, rollout_arm_radius, rollout_clouds, rollout_min_z,
                                       sample_surface, seen_resampled, sensor_chamfer_per_frame, sensor_indices,
                                       sensor_view, visible_subset)
from softsbi.perception.depth_sensor import sensor_from_json

#: surface points sampled per observed point where a view (sensor threshold, occluder, camera) keeps only some:
#: the kept points are drawn from this denser cloud
DENSE_FACTOR = 8


class PointCloudObserver(Observer):
    """K points per frame sampled area-weighted on the simulated surface.

    Args:
        n_points: K, points per frame (default 64).
        noise: isotropic Gaussian noise std added to each point, metres (default 0).
        min_z: visibility threshold (m, absolute height): points at or below it are not
            observed (see :func:`visible_subset`); None = every point is visible. Set it to
            ``table_z + min_height`` to model a depth sensor that cannot tell cloth lying flat
            from the table.
        viewpoint, occluder: with both, points hidden from ``viewpoint (3,)`` m by the cylinder
            ``occluder = {"centre": (x, y), "radius", "z0", "height"}`` (the winding scenario's spool)
            are not observed (:func:`occluded_by_cylinder`); the fit sets them for scenarios with a
            spool.
        camera: a virtual depth sensor (:meth:`softsbi.perception.depth_sensor.VirtualDepthSensor.to_json`):
            the K points of a simulated frame are drawn from the sensor's cloud of it (the highest 10% of
            dense surface samples when it sees nothing), those of a recorded cloud from the cloud as recorded
            (the real sensor made it); replaces ``min_z`` (``FitConfig.sensor = "camera"``).
    """

    name: ClassVar[str] = "pointcloud"

    def __init__(self, n_points: int = 64, noise: float = 0.0, min_z: float | None = None,
                 viewpoint: Sequence[float] | None = None, occluder: Mapping[str, Any] | None = None,
                 camera: Mapping[str, Any] | None = None):
        if n_points < 1:
            raise ValueError(f"n_points must be >= 1, got {n_points}")
        if (viewpoint is None) != (occluder is None):
            raise ValueError("give both viewpoint and occluder (or neither)")
        self.n_points = int(n_points)
        self.noise = float(noise)
        self.min_z = None if min_z is None else float(min_z)
        self.viewpoint = None if viewpoint is None else np.asarray(viewpoint, float)
        self.occluder = None if occluder is None else dict(occluder)
        self.camera = None
        if camera is not None:
            self.camera = sensor_from_json(camera)

    def _unoccluded(self, cloud: np.ndarray) -> np.ndarray:
        if self.occluder is None:
            return cloud
        o = self.occluder
        keep = ~occluded_by_cylinder(cloud, self.viewpoint, o["centre"], float(o["radius"]), float(o["z0"]),
                                     float(o["height"]))
        return cloud[keep] if keep.any() else cloud

    def observe(self, rollout: Rollout, rng: np.random.Generator) -> Observation:
        # a sensor effect's threshold (table-unseen) adds to the observer's own; its arm mask (arm-mask) hides more
        min_z = combined_min_z(self.min_z, rollout_min_z(rollout))
        arm = rollout_arm_radius(rollout)
        if self.camera is not None:
            dense = rollout_clouds(rollout, DENSE_FACTOR * self.n_points, rng)
            views = [self.camera.observe(v, rollout.faces, g, rng) for v, g in zip(rollout.vertices, rollout.gripper)]
            pts = np.stack([visible_subset(c if len(c) else d[sensor_indices(d, np.inf)], self.n_points, rng, None)
                            for c, d in zip(views, dense)])
        elif min_z is None and self.occluder is None and arm is None:
            pts = rollout_clouds(rollout, self.n_points, rng)
        else:
            dense = effect_views(rollout_clouds(rollout, DENSE_FACTOR * self.n_points, rng), rollout)
            pts = np.stack([visible_subset(self._unoccluded(c), self.n_points, rng, min_z) for c in dense])
        if self.noise > 0:
            pts = pts + rng.normal(0, self.noise, pts.shape)
        return Observation(points=pts, gripper=np.asarray(rollout.gripper, float),
                           times=np.asarray(rollout.times, float), source="simulated")

    def observe_clouds(self, clouds: list[np.ndarray], gripper: np.ndarray, times: np.ndarray,
                       rng: np.random.Generator, source: str = "") -> Observation:
        """Subsample K points from each recorded cloud ``clouds[t] (P_t, 3)`` (same sensor model
        as :meth:`observe`). Clouds with fewer than K points are sampled with replacement.
        """
        pts = np.stack([visible_subset(self._unoccluded(np.asarray(c, float)), self.n_points, rng, self.min_z)
                        for c in clouds])
        return Observation(points=pts, gripper=np.asarray(gripper, float), times=np.asarray(times, float),
                           source=source)


def load_cloud_frames(folder: str | Path) -> list[np.ndarray]:
    """Load a recording's frames ``000.npy, 001.npy, ...`` (each ``(P, 3)``) in order.

    Args:
        folder: a recording folder such as ``../shared/data/diffcloud_lift/lift_tan``.

    Returns:
        A list of ``T`` float64 arrays ``(P_t, 3)``, in the file's units (callers convert).

    Raises:
        DataError: missing folder, no ``NNN.npy`` frames, a gap in the numbering, a frame
            that is not ``(P, 3)``, or NaN/inf values — the message names the file and the fix.
            (Point counts may differ between frames; the frame *count* is checked against the
            scenario by :func:`softsbi.workflows.measurement.load_recording`.)
    """
    folder = Path(folder)
    if folder.is_file():
        raise DataError(f"observed data '{folder}' is a file; pass a recording folder such as "
                        f"../shared/data/diffcloud_lift/lift_tan (frames 000.npy, 001.npy, ...)")
    if not folder.is_dir():
        raise DataError(f"observed data folder '{folder}' does not exist; pass a recording folder such as "
                        f"../shared/data/diffcloud_lift/lift_tan (frames 000.npy, 001.npy, ...)")
    files = numbered_files(folder, (".npy",), start=None)
    if not files:
        if (folder / "run.zarr").exists():
            raise DataError(f"'{folder}' is a run directory (the output of `softsbi fit`), not a recording; pass the "
                            f"recording it was fitted to (report.json's 'observed') or check/diagnose it")
        if (folder / "clouds").is_dir():
            raise DataError(f"'{folder}' holds clouds/ but no recording.yaml, which says what they are (scenario, "
                            f"times, transform); write it (softsbi/data/recording.py shows the format) or re-create "
                            f"the recording with `softsbi import diffcloud` / `softsbi simulate --out`")
        raise DataError(f"'{folder}' holds no frames named 000.npy, 001.npy, ...; a recording folder must "
                        f"contain one (P, 3) point cloud per frame")
    clouds = []
    for f in files:
        a = read_npy(f, "frame", "re-export it as a (P, 3) float .npy")
        if a.ndim != 2 or a.shape[1] != 3 or len(a) == 0:
            raise DataError(f"frame '{f}' has shape {a.shape}; each frame must be a (P, 3) point cloud")
        if not np.all(np.isfinite(a)):
            bad = int((~np.isfinite(a)).any(1).sum())
            raise DataError(f"frame '{f}' contains {bad} points with NaN/inf coordinates; remove them before fitting")
        clouds.append(a.astype(float))
    return clouds


@hookimpl
def softsbi_observers():
    return [PointCloudObserver]
