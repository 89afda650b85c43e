"""Point-cloud operations shared by the observer, the depth sensor and the workflows: area-weighted surface
sampling, the points a sensor sees (the table-unseen threshold, the arm's mask), the Chamfer distance per frame
between a simulated and a measured cloud, and the cylinder occluder.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from softsbi.core.errors import ShapeError
from softsbi.core.metrics import chamfer_terms
from softsbi.core.types import INFO_ARM_MASK_RADIUS, INFO_MIN_VISIBLE_Z, Rollout


def sample_surface(vertices: np.ndarray, faces: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points ``(n, 3)`` sampled uniformly by area on a triangle mesh.

    Args:
        vertices: ``(N, 3)`` m. faces: ``(F, 3)`` int. For a mesh without faces (a rope)
            points are sampled uniformly along the polyline of the vertices.

    Raises:
        ShapeError: bad shapes.
    """
    vertices = np.asarray(vertices, float)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ShapeError(f"vertices must be (N, 3), got {vertices.shape}")
    if len(faces) == 0:
        seg = np.linalg.norm(np.diff(vertices, axis=0), axis=1)
        p = seg / seg.sum() if seg.sum() > 0 else np.full(len(seg), 1 / len(seg))
        k = rng.choice(len(seg), size=n, p=p)
        t = rng.random((n, 1))
        return vertices[k] * (1 - t) + vertices[k + 1] * t
    tri = vertices[faces]  # (F, 3, 3)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    total = area.sum()
    p = area / total if total > 0 else np.full(len(area), 1 / len(area))
    k = rng.choice(len(faces), size=n, p=p)
    r1 = np.sqrt(rng.random(n))
    r2 = rng.random(n)
    w = np.stack([1 - r1, r1 * (1 - r2), r1 * r2], axis=1)
    return np.einsum("nk,nkd->nd", w, tri[k])


def rollout_clouds(rollout: Rollout, n: int, rng: np.random.Generator) -> np.ndarray:
    """Area-weighted surface samples of every frame: ``(T, n, 3)`` m."""
    return np.stack([sample_surface(v, rollout.faces, n, rng) for v in rollout.vertices])


def visible_subset(cloud: np.ndarray, k: int, rng: np.random.Generator, min_z: float | None) -> np.ndarray:
    """``k`` points ``(k, 3)`` drawn from the part of ``cloud (P, 3)`` a depth sensor sees.

    The sensor model: points less than the visibility threshold above the table (``z <=
    min_z``) are not segmented from the table (the real DiffCloud clouds contain no cloth
    lying flat). If no point is visible, the ``k`` highest points stand in (the frame is then
    as uninformative as the real one). ``min_z=None`` sees everything. Draws are without
    replacement when enough points are visible.
    """
    if min_z is not None:
        vis = cloud[cloud[:, 2] > min_z]
        if len(vis) == 0:
            vis = cloud[np.argsort(cloud[:, 2])[-k:]]
    else:
        vis = cloud
    return vis[rng.choice(len(vis), size=k, replace=len(vis) < k)]


def combined_min_z(*thresholds: float | None) -> float | None:
    """The visibility threshold (absolute height, m) of several sensor models applied together: the
    highest of those given (a point is seen only if every model sees it); None when none is given."""
    given = [float(z) for z in thresholds if z is not None]
    return max(given) if given else None


def rollout_min_z(rollout: Any) -> float | None:
    """The visibility threshold a sensor effect set on a rollout (``info[INFO_MIN_VISIBLE_Z]``, m), on a job result
    (its ``info``) or on a dict holding the key, else None."""
    v = _info(rollout).get(INFO_MIN_VISIBLE_Z)
    return None if v is None else float(v)


def _info(rollout: Any) -> dict:
    info = rollout.get("info", rollout) if isinstance(rollout, dict) else getattr(rollout, "info", None) or {}
    return info if isinstance(info, dict) else {}


def rollout_arm_radius(rollout: Any) -> float | None:
    """The arm-mask radius a sensor effect set on a rollout (``info[INFO_ARM_MASK_RADIUS]``, m), on a job result
    (its ``info``) or on a dict holding the key, else None."""
    v = _info(rollout).get(INFO_ARM_MASK_RADIUS)
    return None if v is None else float(v)


def arm_distance(points: np.ndarray, grip: np.ndarray) -> np.ndarray:
    """``(P,)`` m: each point's distance to the arm, the vertical half-line ``{grip + s e_z, s >= 0}`` from the grasp
    point ``grip (3,)`` m upwards (a point below the grasp point: its distance to the grasp point; above it: its
    horizontal distance to the line)."""
    d = np.asarray(points, float) - np.asarray(grip, float).reshape(1, 3)
    return np.where(d[:, 2] < 0.0, np.linalg.norm(d, axis=1), np.hypot(d[:, 0], d[:, 1]))


def arm_hidden(points: np.ndarray, grip: np.ndarray, radius: float) -> np.ndarray:
    """``(P,)`` bool: the points of ``points (P, 3)`` m that the arm's mask of ``radius`` m hides, those within it of
    the grasp point ``grip (3,)`` or of the vertical line above it (:func:`arm_distance`)."""
    return arm_distance(points, grip) < float(radius)


def arm_view(cloud: np.ndarray, grip: np.ndarray, radius: float) -> np.ndarray:
    """The part ``(P', 3)`` of ``cloud (P, 3)`` m outside the arm's mask (:func:`arm_hidden`), in cloud order; when the
    mask hides every point, the :data:`FALLBACK_SHARE` of the points farthest from the arm stand in."""
    dist = arm_distance(cloud, grip)
    seen = dist >= float(radius)
    if seen.any():
        return cloud[seen]
    k = max(1, int(round(FALLBACK_SHARE * len(cloud))))
    return cloud[np.sort(np.argsort(dist)[-k:])]


def effect_views(clouds: Sequence[np.ndarray], rollout: Any, frames: Sequence[int] | None = None):
    """``clouds`` (``T'`` clouds ``(P, 3)`` m of ``rollout``'s frames ``frames``, default all, in that order) as the
    rollout's per-point sensor effects leave them: the arm's mask (:func:`rollout_arm_radius`, around the rollout's
    gripper in each frame, :func:`arm_view`). The clouds themselves (the same object) when it has none, else a list of
    ``(P'_t, 3)`` clouds. The height threshold (:func:`rollout_min_z`) is not applied here: it combines with the fit's
    own (:func:`combined_min_z`)."""
    r = rollout_arm_radius(rollout)
    if r is None:
        return clouds
    grip = np.asarray(rollout.get("gripper") if isinstance(rollout, dict) else rollout.gripper, float)
    idx = range(len(clouds)) if frames is None else frames
    return [arm_view(np.asarray(c, float), grip[t], r) for c, t in zip(clouds, idx)]


def seen_resampled(cloud: np.ndarray, min_z: float | None, rng: np.random.Generator) -> np.ndarray:
    """``(P, 3)``: the part of ``cloud (P, 3)`` m seen through ``min_z`` (:func:`sensor_indices`, with its
    fallback), drawn back to ``P`` points with replacement (as DiffCloud draws its clouds), so that a
    measurement keeps one point count per frame. ``min_z=None`` returns the cloud itself."""
    if min_z is None:
        return cloud
    idx = sensor_indices(cloud, min_z)
    return cloud[idx[rng.integers(len(idx), size=len(cloud))]]


#: share of a cloud's highest points that stand in when a sensor sees none of it (:func:`sensor_view`)
FALLBACK_SHARE = 0.1


def sensor_indices(cloud: np.ndarray, min_z: float) -> np.ndarray:
    """Indices ``(P',)`` of the points of ``cloud (P, 3)`` m that the fit's depth-sensor model sees: those
    more than the visibility threshold above the table (``z > min_z``, absolute height in m, in cloud
    order), as in :func:`visible_subset`. When none is seen, the highest :data:`FALLBACK_SHARE` of the
    points (at least one, lowest first) stand in, so a frame of cloth lying flat still has a defined
    distance."""
    seen = np.flatnonzero(cloud[:, 2] > min_z)
    if len(seen):
        return seen
    k = max(1, int(round(FALLBACK_SHARE * len(cloud))))
    return np.argsort(cloud[:, 2])[-k:]


def sensor_view(cloud: np.ndarray, min_z: float | None) -> np.ndarray:
    """The part ``(P', 3)`` of ``cloud (P, 3)`` m that the fit's depth-sensor model sees
    (:func:`sensor_indices`); ``min_z=None`` sees everything (the cloud itself, no copy)."""
    return cloud if min_z is None else cloud[sensor_indices(cloud, min_z)]


def sensor_chamfer_per_frame(simulated: Sequence[np.ndarray], measured: Sequence[np.ndarray],
                             min_z: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame distances between simulated and measured clouds, both seen through the same sensor
    model (:func:`sensor_view`): the metric of every fit, check and diagnosis.

    Args:
        simulated: ``T`` clouds ``(n_t, 3)`` m (e.g. ``(T, n, 3)`` area-weighted surface samples).
        measured: ``T`` clouds ``(m_t, 3)`` m.
        min_z: the sensor's visibility threshold (absolute height, m); None = full clouds.

    Returns:
        ``(bidirectional (T,), one_sided (T,))`` in m: the bidirectional Chamfer
        (:func:`softsbi.core.metrics.chamfer`) and the one-sided ``D(measured -> simulated)``
        (:func:`softsbi.core.metrics.one_sided_chamfer`).

    Raises:
        ShapeError: different frame counts, empty clouds.
    """
    if len(simulated) != len(measured):
        raise ShapeError(f"sequences have different frame counts: {len(simulated)} vs {len(measured)}")
    bi, one = np.empty(len(simulated)), np.empty(len(simulated))
    for t, (s, m) in enumerate(zip(simulated, measured)):
        sm, ms = chamfer_terms(sensor_view(np.asarray(s, float), min_z), sensor_view(np.asarray(m, float), min_z))
        bi[t], one[t] = 0.5 * (sm + ms), ms
    return bi, one


def occluded_by_cylinder(points: np.ndarray, viewpoint: Sequence[float], centre: Sequence[float], radius: float,
                         z0: float, height: float) -> np.ndarray:
    """Which points a vertical cylinder (the winding scenario's spool) hides from a viewpoint.

    A point is occluded when the open segment from ``viewpoint`` to it passes through the solid
    cylinder of axis z through ``centre (x, y)``, ``radius`` and ``z0 <= z <= z0 + height``.

    Args:
        points: ``(N, 3)`` m. viewpoint: ``(3,)`` m (the camera centre).

    Returns:
        ``(N,)`` bool, True = hidden.
    """
    p = np.asarray(points, float)
    cam = np.asarray(viewpoint, float)
    d = p - cam  # X(t) = cam + t d, t in [0, 1)
    oc = cam[:2] - np.asarray(centre, float)
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = 2 * (d[:, :2] @ oc)
    c = oc @ oc - radius ** 2
    disc = b * b - 4 * a * c
    vertical = a <= 1e-18  # a segment parallel to the axis is inside for all t or for none
    hit = np.where(vertical, c < 0, disc > 0)
    sq = np.sqrt(np.where(hit & ~vertical, disc, 0.0))
    aa = np.where(vertical, 1.0, a)
    t1 = np.where(vertical, 0.0, (-b - sq) / (2 * aa))
    t2 = np.where(vertical, 1.0, (-b + sq) / (2 * aa))
    lo, hi = np.maximum(t1, 0.0), np.minimum(t2, 1.0 - 1e-6)  # inside the infinite cylinder for t in [lo, hi]
    hit &= lo < hi
    za, zb = cam[2] + lo * d[:, 2], cam[2] + hi * d[:, 2]
    hit &= (np.maximum(za, zb) >= z0) & (np.minimum(za, zb) <= z0 + height)
    return hit
