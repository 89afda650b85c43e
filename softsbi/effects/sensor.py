"""Sensor candidate effects: observation transforms (``kind = "sensor"``) acting on the finished rollout.

They change what the sensor reports, never the motion: a backend with the ``"observation"`` door
applies :meth:`~softsbi.core.interfaces.Effect.observe` to a successful rollout, with a generator
seeded by the simulation's seed. The commanded gripper path is left unchanged (it is the robot's,
not the sensor's). They act on the rollout's vertices, from which the observers sample their
points, and not on rendered images (image observers do not see them).

"Points near the table unseen" (:class:`TableUnseen`) does not move vertices: it sets the rollout's
visibility threshold (``info[INFO_MIN_VISIBLE_Z]``), which the point-cloud observer, the metric, the
synthetic measurement and check/diagnose's summaries apply per frame on top of the fit's own sensor model.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any, ClassVar, Mapping

import numpy as np

from softsbi.core.interfaces import Effect
from softsbi.core.types import INFO_MIN_VISIBLE_Z, Param, ParamSpace, Rollout


class CalibrationOffset(Effect):
    """A calibration error of the camera: the observed cloud is shifted by a constant offset.

    Physics/sensor model: observed vertex = true vertex + ``(offset_x, offset_y, offset_z)`` m, every
    frame (a translation error of the camera extrinsics). Off at 0 m (the prior's midpoint).
    Direction: the observed cloud's centroid moves by the offset.
    """

    name: ClassVar[str] = "calibration-offset"
    description: ClassVar[str] = "the observed cloud is shifted by a constant offset (camera extrinsics, m)"
    kind: ClassVar[str] = "sensor"

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param(f"offset_{c}", -0.03, 0.03, "m", description=f"shift of the observed cloud along {c}")
                           for c in "xyz"])

    def nominal(self) -> dict[str, float]:
        return {"offset_x": 0.0, "offset_y": 0.0, "offset_z": 0.0}

    def observe(self, rollout: Rollout, theta: Mapping[str, float], rng: np.random.Generator) -> Rollout:
        off = np.array([theta["offset_x"], theta["offset_y"], theta["offset_z"]], dtype=float)
        return replace(rollout, vertices=rollout.vertices + off, info=dict(rollout.info))


class PointNoise(Effect):
    """Depth-sensor noise: every observed vertex jitters independently.

    Sensor model: observed vertex = true vertex + N(0, ``noise_std``^2 I) m, independent per vertex and
    frame (seeded). Points the observer samples inside a triangle mix three vertices, so their own
    noise is between ``noise_std / sqrt(3)`` and ``noise_std``. Off at the lower bound 0 m.
    Direction: the observed surface gets rougher (larger distances to the true surface).
    """

    name: ClassVar[str] = "point-noise"
    description: ClassVar[str] = "independent Gaussian noise on the observed surface (std, m)"
    kind: ClassVar[str] = "sensor"
    #: the estimator's kernel mean embedding cannot see centimetre noise: without the local-thickness summary
    #: the posterior of ``noise_std`` stayed the prior (measured by retraining stored point-noise refits)
    estimator_options: ClassVar[Mapping[str, Any]] = {"frame_thickness": True}

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("noise_std", 0.0, 0.01, "m", description="standard deviation per axis")])

    def observe(self, rollout: Rollout, theta: Mapping[str, float], rng: np.random.Generator) -> Rollout:
        s = float(theta["noise_std"])
        return replace(rollout, vertices=rollout.vertices + rng.normal(0.0, s, rollout.vertices.shape),
                       info=dict(rollout.info))


class TimeOffset(Effect):
    """A time offset between the recording and the commanded path.

    Sensor model: the cloud stamped at time t shows the object at ``t + time_offset`` s (positive: the
    cloud runs ahead of the stamps), linearly interpolated between simulated frames and held at the
    first/last frame beyond the rollout. The gripper path stays at t. Off at 0 s (the prior's
    midpoint). Direction: with a positive offset a lifted cloth is observed higher earlier.
    """

    name: ClassVar[str] = "time-offset"
    description: ClassVar[str] = "the recorded clouds are shifted in time against the commanded path (s)"
    kind: ClassVar[str] = "sensor"

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("time_offset", -0.1, 0.1, "s", description="cloud time minus stamp time")])

    def nominal(self) -> dict[str, float]:
        return {"time_offset": 0.0}

    def observe(self, rollout: Rollout, theta: Mapping[str, float], rng: np.random.Generator) -> Rollout:
        times = np.asarray(rollout.times, dtype=float)
        tq = np.clip(times + float(theta["time_offset"]), times[0], times[-1])
        k = np.clip(np.searchsorted(times, tq, side="right") - 1, 0, len(times) - 2) if len(times) > 1 else np.zeros(len(times), int)
        if len(times) < 2:
            return rollout
        w = ((tq - times[k]) / np.maximum(times[k + 1] - times[k], 1e-12))[:, None, None]
        verts = (1.0 - w) * rollout.vertices[k] + w * rollout.vertices[k + 1]
        return replace(rollout, vertices=verts, info=dict(rollout.info))


class TableUnseen(Effect):
    """The depth sensor does not see the cloth near the table: points less than ``unseen_height`` above
    the cloth's resting height are not segmented from the table.

    Sensor model: a point of frame t is seen iff its height is above ``z_rest + unseen_height``, with
    ``z_rest`` the lowest vertex of the first frame (the cloth starts resting on the table, one collision
    radius above it); when a frame has no point above it, its highest 10% stand in, as for the fit's own
    height cut (:func:`~softsbi.perception.pointcloud.sensor_indices`). This is the real DiffCloud clouds'
    crop (``FitConfig.min_height``) as a candidate with an unknown height: it applies to fits through the
    height cut or full clouds; a ``--sensor camera`` fit's virtual sensor decides itself what the table
    hides. Off at the lower bound 0 m (everything seen). It is not smooth at 0: any positive height hides
    the whole flat cloth at once, so the screening's finite difference (a step of the prior range) measures
    that jump, not a slope.
    """

    name: ClassVar[str] = "table-unseen"
    description: ClassVar[str] = "points near the table are not seen (height above the resting cloth, m)"
    kind: ClassVar[str] = "sensor"

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("unseen_height", 0.0, 0.03, "m",
                                 description="height above the resting cloth below which nothing is seen")])

    def observe(self, rollout: Rollout, theta: Mapping[str, float], rng: np.random.Generator) -> Rollout:
        h = float(theta["unseen_height"])
        if h <= 0.0:
            return rollout
        z_rest = float(np.asarray(rollout.vertices)[0, :, 2].min())
        return replace(rollout, info={**rollout.info, INFO_MIN_VISIBLE_Z: z_rest + h})


SENSOR_EFFECTS = (CalibrationOffset, PointNoise, TimeOffset, TableUnseen)
