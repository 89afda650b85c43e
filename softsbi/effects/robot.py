"""How the robot executes the scenario: candidate effects of the motion's timing and of the grasp (the effect door).

Both are model edits for ``mujoco-flex`` (the model dict of :func:`softsbi.backends.mujoco_flex.build_spec`), so a
backend without that edit reports that it lacks it (``Simulator.supports``):

* ``duration-scale``: the commanded paths take ``s`` times the scenario's duration, and the frames are recorded at
  the same fractions of the motion (``spec["motion"]["time_scale"]``, read by the simulator's stepping loop);
* ``grasp-patch``: the gripper holds the cloth within a radius of the grasp point, not one vertex (extra
  ``<connect>`` constraints between the ``grip`` mocap and the vertices around the grasped one).

Each is off at its lower bound and changes the lift in the direction its docstring states
(``tests/effects/test_robot_effects.py``).
"""
from __future__ import annotations

from typing import Any, ClassVar, Mapping

import numpy as np

from softsbi.core.interfaces import Effect
from softsbi.core.types import Param, ParamSpace

#: a partly held vertex whose hold weight is below this is left free (so ``grasp_radius = 0`` adds no constraint)
MIN_HOLD = 1e-6
#: the lowest impedance MuJoCo accepts (``mjMINIMP``)
MIN_IMPEDANCE = 1e-4


class DurationScale(Effect):
    """The motion's real duration: the robot executes the commanded path ``duration_scale`` times slower.

    Physics: the gripper follows the scenario's path over ``s`` times the scenario's duration (physical time
    ``s t`` for the scenario's time ``t``), and the recording's frame ``k`` shows the object at ``s t_k``, the same
    fraction of the motion; the rollout keeps the scenario's stamps. Gravity, the cloth's inertia and damping act in
    physical time, so a slower lift is closer to quasi-static: the hanging cloth lags and swings less behind the
    gripper (not only a relabelled time axis). Dimensionless; off at the lower bound 1 (the scenario's own timing).
    Model edit for ``mujoco-flex`` (``spec["motion"]["time_scale"]``, multiplied, so two time scales compose); a
    rollout costs ``s`` times the nominal's steps.

    Prior 1-4, log-uniform: DiffCloud's scene compresses the real lift into 1 s (the real timing is not in the
    recordings). Its 0.36 m path then moves at 0.38 m/s on average and 0.55 m/s at its fastest, above the Kinova
    Gen3's top Cartesian speed (0.5 m/s on its specification sheet), so the real lift took at least about 1.1 s;
    s = 4 is a careful 0.1 m/s on average (0.14 m/s at the fastest). Slower still changes the clouds no more: on
    the built-in lift (grid 9, 25 frames, the prior's midpoint) the vertices move on average 0.63, 0.82, 0.73 and
    0.85 cm from the nominal's at s = 2, 4, 8 and 16 (measured), the change saturating as the lift becomes
    quasi-static. Direction: a slower lift trails less: while the gripper rises the cloth hangs higher than the
    nominal's (its mean height +0.2 to +0.6 cm, 0.39 cm on average, at s = 4 over the rising frames 5-8 of the 5x5
    test lift); as the gripper slows down at the end, the nominal's cloth swings on along the path, the slower one
    much less. On the path of the real lift_tan (grid 9, the prior's midpoint) the cloth's centroid is 0.1-0.2 cm
    higher while it rises, and over the last 6 frames 0.6-2.0 cm back along the path (+y there) and 0.1-0.9 cm lower,
    at s = 2 and 4 (measured); on the built-in lift the height there changes with s without a fixed sign.
    """

    name: ClassVar[str] = "duration-scale"
    description: ClassVar[str] = "the lift takes s times the scenario's duration (slower, less dynamic lag)"
    backends: ClassVar[tuple[str, ...]] = ("mujoco-flex",)
    model_edits: ClassVar[tuple[str, ...]] = ("mujoco-flex",)

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("duration_scale", 1.0, 4.0, "1", log=True,
                                 description="real duration of the motion over the scenario's (1 = as scripted)")])

    def nominal(self) -> dict[str, float]:
        return {"duration_scale": 1.0}

    def edit_model(self, backend: str, model: Any, theta: Mapping[str, float], ctx: Mapping[str, Any]) -> None:
        """Multiply the motion's time scale by ``duration_scale`` (1: the model dict is unchanged)."""
        model["motion"]["time_scale"] = float(model["motion"]["time_scale"]) * float(theta["duration_scale"])


class GraspPatch(Effect):
    """A grasp that holds a patch: the gripper holds every cloth vertex within ``grasp_radius`` of the grasp point.

    Physics: a vertex at rest distance ``d`` (m) from the grasped vertex is held by the gripper with weight
    ``w = clip(1 - (d - r) / h, 0, 1)`` (``r`` = ``grasp_radius`` m, ``h`` the grid spacing m): fully within ``r``,
    partly in a band one grid spacing beyond it, so that the held patch grows continuously with ``r`` on the discrete
    grid. A held vertex keeps its rest offset from the grasp point (the patch is held in its flat rest shape, like a
    pad, not gathered into the fingers). Its constraint is the nominal grasp's (``<connect>`` to the ``grip`` mocap)
    with the impedance scaled by ``w`` and the time constant divided by ``w`` (MuJoCo's ``solimp``/``solref``):
    ``w = 1`` is the rigid grasp, ``w -> 0`` no hold. The first moving handle only (the gripper; the lift's one).
    Off at the lower bound 0 m (only the grasped vertex: the nominal grasp). Model edit for ``mujoco-flex``.

    Prior 0-0.05 m: a parallel gripper's fingers (pads 2-4 cm) pinch at most a few centimetres of cloth around
    the corner. Direction: the cloth hangs from the patch's edge instead of its corner, so the hanging cloth is
    shorter: the lifted cloth hangs higher than the nominal's, and it is carried along the diagonal into the cloth,
    where the patch lies. On the built-in lift (grid 9, 25 frames, the prior's midpoint) the last frame's mean height
    rises by 0.85, 1.8 and 4.5 cm at r = 1, 2 and 5 cm, and the cloth moves 1.0, 1.4 and 3.6 cm along the diagonal
    (measured).
    """

    name: ClassVar[str] = "grasp-patch"
    description: ClassVar[str] = "the gripper holds the cloth within a radius of the grasp point (m), not one vertex"
    backends: ClassVar[tuple[str, ...]] = ("mujoco-flex",)
    model_edits: ClassVar[tuple[str, ...]] = ("mujoco-flex",)

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("grasp_radius", 0.0, 0.05, "m",
                                 description="radius around the grasp point within which the gripper holds the cloth")])

    def nominal(self) -> dict[str, float]:
        return {"grasp_radius": 0.0}

    def edit_model(self, backend: str, model: Any, theta: Mapping[str, float], ctx: Mapping[str, Any]) -> None:
        """Add a ``<connect>`` from the ``grip`` mocap to each vertex with a hold weight ``w > 0`` (:meth:`weights`),
        with the grip's constraint softened by ``w``; none at ``grasp_radius = 0``."""
        r = float(theta["grasp_radius"])
        if r <= 0.0:
            return
        grip = model["connect"]
        held = {int(v) for v in model["handle_vertices"]}
        v0 = int(model["handle_vertices"][list(model["handle_mocaps"]).index(0)])
        w = self.weights(np.asarray(model["rest"], dtype=float), v0, r, float(ctx["spacing"]))
        body = grip["body1"].rsplit("_", 1)[0]
        tc, ratio = grip["solref"]
        imp = list(grip["solimp"])
        for i in np.flatnonzero(w > MIN_HOLD):
            if int(i) in held:
                continue
            wi = float(w[i])
            model["connects"].append({
                "body1": f"{body}_{int(i)}", "body2": grip["body2"], "anchor": [0.0, 0.0, 0.0],
                "solref": [float(tc) / wi, ratio],
                "solimp": [max(imp[0] * wi, MIN_IMPEDANCE), max(imp[1] * wi, MIN_IMPEDANCE), *imp[2:]]})

    @staticmethod
    def weights(rest: np.ndarray, grasped: int, radius: float, spacing: float) -> np.ndarray:
        """Hold weights ``(N,)`` in [0, 1] of the vertices ``rest (N, 3)`` m around vertex ``grasped``:
        ``clip(1 - (d - radius) / spacing, 0, 1)`` with ``d`` the rest distance (m); the grasped vertex has 1."""
        d = np.linalg.norm(rest - rest[grasped], axis=1)
        w = np.clip(1.0 - (d - float(radius)) / float(spacing), 0.0, 1.0)
        w[grasped] = 1.0
        return w


ROBOT_EFFECTS = (DurationScale, GraspPatch)
