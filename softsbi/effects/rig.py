"""The depth rig's candidate effects: how two merged depth cameras and a masked-out arm report a cloth.

DiffCloud's rig (``../shared/data/README.md``; :mod:`softsbi.perception.depth_sensor` repeats its processing):
two RealSense cameras, one overhead and one at the side, each give a cloud; the robot is masked out of both by
its kinematics (a render of the arm); the side camera's points are shifted by a hand-set correction and the two
clouds merged. Two ways this can differ from the fit's sensor model, each an observation transform
(``kind = "sensor"``) of the finished rollout:

* ``arm-mask``: the arm's mask removes the cloth near the gripper (:class:`ArmMask`). It moves no vertex: it
  sets the rollout's arm-mask radius (``info[INFO_ARM_MASK_RADIUS]``), which the point-cloud observer, the
  metric, the synthetic measurement and check/diagnose's summaries apply per frame around the rollout's gripper
  (:func:`softsbi.perception.clouds.effect_views`), as they apply table-unseen's height.
* ``camera-offset``: the side camera's share of the points is shifted against the overhead camera's
  (:class:`CameraOffset`).

Both act on the clouds of fits through the height cut or full clouds; a ``--sensor camera`` fit's virtual depth
sensor (its own robot mask and camera offsets) decides itself what the cameras see, as for table-unseen.
"""
from __future__ import annotations

from dataclasses import replace
from typing import ClassVar, Mapping

import numpy as np

from softsbi.core.interfaces import Effect
from softsbi.core.types import INFO_ARM_MASK_RADIUS, Param, ParamSpace, Rollout


class ArmMask(Effect):
    """The arm's mask: the depth rig does not see the cloth near the gripper, where it masked the robot out.

    Sensor model: in frame t a point p is not seen when it lies within ``mask_radius`` (m) of the gripper's grasp
    point ``g_t`` (the rollout's gripper) or of the vertical line above it, along the arm: its distance to the
    half-line ``{g_t + s e_z, s >= 0}`` is below the radius (a ball around the gripper under a vertical cylinder,
    the arm reaching down to a top grasp). When a frame has no point outside the mask, the tenth of its points
    farthest from the half-line stand in. The vertices are not moved: the observers, the metric, the synthetic
    measurement and the summaries drop the masked points (with the fit's height cut and table-unseen on top);
    the real clouds were merged and resampled to a fixed count after masking, so the synthetic measurement
    redraws its clouds from the seen points. Off at the lower bound 0 m (nothing masked).

    Direction: the observed cloud loses the cloth around the grasped corner: the points nearest the gripper (the
    top of a hanging cloth) are missing, so a lifted cloth's observed centroid is lower and farther from the
    gripper (``tests/effects/test_rig.py``). Not smooth at 0 (the first masked point appears at once).
    """

    name: ClassVar[str] = "arm-mask"
    description: ClassVar[str] = "the cloth near the gripper and under the arm is masked out with the robot (radius, m)"
    kind: ClassVar[str] = "sensor"

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("mask_radius", 0.0, 0.1, "m",
                                 description="radius of the mask around the grasp point and the arm above it")])

    def observe(self, rollout: Rollout, theta: Mapping[str, float], rng: np.random.Generator) -> Rollout:
        r = float(theta["mask_radius"])
        if r <= 0.0:
            return rollout
        return replace(rollout, info={**rollout.info, INFO_ARM_MASK_RADIUS: r})


def side_share(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(T, N)``: the share of each vertex's merged points that come from the side camera, ``|n_h| / (|n_h| +
    |n_z|)`` for the vertex's unit normal ``n`` (area-weighted over its triangles, in every frame), ``n_h`` its
    horizontal part: 0 where the cloth lies flat, 1 where it hangs vertically, 1/2 at 45 degrees. A camera sees a
    surface patch in proportion to its area projected across the camera's line of sight: the overhead camera
    (looking down) by ``|n_z|``, the side camera (looking horizontally at it) by ``|n_h|``. Without faces (a rope)
    or where a normal vanishes: 1/2.

    Args:
        vertices: ``(T, N, 3)`` m. faces: ``(F, 3)`` int.
    """
    v = np.asarray(vertices, float)
    out = np.full(v.shape[:2], 0.5)
    f = np.asarray(faces, int)
    if len(f) == 0:
        return out
    tri = v[:, f]                                                             # (T, F, 3 vertices, 3)
    fn = np.cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0])   # twice the area along the normal
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, (slice(None), f[:, k]), fn)
    nz = np.abs(n[..., 2])
    nh = np.hypot(n[..., 0], n[..., 1])
    tot = nh + nz
    ok = tot > 1e-12 * max(float(tot.max()), 1e-300)
    out[ok] = nh[ok] / tot[ok]
    return out


class CameraOffset(Effect):
    """The two merged cameras are offset from each other: the side camera's points are shifted against the
    overhead camera's.

    Sensor model: the merged cloud at a surface patch mixes the overhead camera's points and the side camera's,
    in proportion to how squarely each camera sees the patch (:func:`side_share`: 0 for cloth lying flat, which
    only the overhead camera sees well; 1 for cloth hanging vertically, seen face-on by the side camera). The side
    camera's points are shifted by ``(side_dx, side_dy, side_dz)`` m (a residual of the side camera's extrinsic
    calibration after the rig's own correction), so the observed vertex is ``x + w (side_dx, side_dy, side_dz)``
    for its share ``w``: the mean of the patch's merged points (a vertex cannot carry two layers). The overhead
    camera is the reference (a shift of both cameras together is calibration-offset). Approximations, stated: the
    overhead camera looks straight down and the side camera horizontally at the patch (DiffCloud's are tilted: the
    overhead by about 35 degrees from the vertical, the side one about 20 degrees below the horizontal), and both
    sample a patch at the same density per projected area. Off at 0 m (the prior's midpoint).

    Direction: the hanging part of a lifted cloth moves by the offset and the part lying flat does not, so the
    observed shift grows as the cloth is lifted (``tests/effects/test_rig.py``).
    """

    name: ClassVar[str] = "camera-offset"
    description: ClassVar[str] = "the side camera's points are offset from the overhead camera's (m)"
    kind: ClassVar[str] = "sensor"

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param(f"side_d{c}", -0.03, 0.03, "m",
                                 description=f"shift of the side camera's points against the overhead camera's "
                                             f"along {c}") for c in "xyz"])

    def nominal(self) -> dict[str, float]:
        return {"side_dx": 0.0, "side_dy": 0.0, "side_dz": 0.0}

    def observe(self, rollout: Rollout, theta: Mapping[str, float], rng: np.random.Generator) -> Rollout:
        off = np.array([theta["side_dx"], theta["side_dy"], theta["side_dz"]], dtype=float)
        if not off.any():
            return rollout
        w = side_share(rollout.vertices, rollout.faces)
        return replace(rollout, vertices=rollout.vertices + w[..., None] * off, info=dict(rollout.info))


RIG_EFFECTS = (ArmMask, CameraOffset)
