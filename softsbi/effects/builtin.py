"""The four original built-in effects, declared exactly like third-party ones (the effect door).

Each effect has its own parameters in physical units; its lower bound (or zero) switches it off.
No backend knows them by name: each acts through the kinds of :class:`~softsbi.core.interfaces.Effect`:

* ``air-drag`` (model edit for ``mujoco-flex``, force field :func:`fluid_force` elsewhere): MuJoCo's
  inertia-box fluid model (MuJoCo docs,
  *Computation / Fluid forces*): option ``density`` (kg/m^3) and ``viscosity`` (air's kinematic
  viscosity times the density: 1.8e-5 Pa s at 1.2 kg/m^3), with the flex vertex ``inertiabox`` set to
  the grid spacing so each vertex carries the drag of its cloth patch (measured here: a 1 m drop
  ends at 0.01 m without air, 0.57 m with density 1.2).
* ``wind`` (model edit for ``mujoco-flex``, force field elsewhere): option ``wind`` (m/s) acting
  through the same fluid model at air density 1.2.
* ``extra-damping``: ``F = -gamma m_v v`` on every vertex at a rate gamma (1/s), ``m_v`` the vertex
  mass. On ``mujoco-flex`` a model edit (MuJoCo's fluid viscosity, integrated implicitly by the
  ``discrete`` integrator, stable at any rate); elsewhere a force field. Deliberate change: before the
  effect door the viscosity was ``gamma m_v / (3 pi h)``, which applied ``-2 gamma m_v v`` (measured:
  MuJoCo's inertia-box viscous force is ``6 pi mu h v`` for a box of side h), twice the documented
  force. It is now ``gamma m_v / (6 pi h)``, and the prior's upper bound went from 30 to 60 1/s so
  that it spans the same forces as before: the rollout at ``2 gamma`` equals main's at ``gamma`` to
  < 1e-6 m (``tests/effects/test_builtin_regression.py``). The force field applied on mujoco-flex
  instead (explicitly, before each step) differs by 1.8 mm at 4 ms steps and 0.97 mm at 2 ms (first
  order in the step, measured at gamma = 24 1/s on a 5x5 lift).
* ``grip-compliance`` (model edit for ``mujoco-flex``): the time constant (s) of the weld between
  gripper and cloth corner (``solref`` of the equality constraint), so the corner lags and sags like
  cloth slipping in soft fingers.

The other built-in candidates live in :mod:`softsbi.effects.physics` (tilted table, sticky patch,
heavy hem), :mod:`softsbi.effects.robot` (the motion's duration, a grasp holding a patch),
:mod:`softsbi.effects.sensor` (calibration offset, point noise, time offset), :mod:`softsbi.effects.material`
(anisotropic stretch), :mod:`softsbi.effects.rig` (the depth rig's arm mask and camera offset) and
:mod:`softsbi.effects.generic` (generic force terms); this module's hook registers them all.
"""
from __future__ import annotations

import math
from typing import Any, ClassVar, Mapping

import numpy as np

from softsbi.core.interfaces import Effect, VertexContext
from softsbi.core.types import Param, ParamSpace
from softsbi.effects.generic import GENERIC_EFFECTS
from softsbi.effects.material import MATERIAL_EFFECTS
from softsbi.effects.physics import PHYSICS_EFFECTS
from softsbi.effects.rig import RIG_EFFECTS
from softsbi.effects.robot import ROBOT_EFFECTS
from softsbi.effects.sensor import SENSOR_EFFECTS
from softsbi.plugins.hookspecs import hookimpl

AIR_VISCOSITY = 1.8e-5  # Pa s
AIR_DENSITY = 1.2  # kg/m^3


def _fluid(spec: dict[str, Any], spacing: float, density: float = 0.0, air_viscosity: float = 0.0,
           extra_viscosity: float = 0.0) -> None:
    """Switch on MuJoCo's inertia-box fluid model in a mujoco-flex spec, so that several fluid effects
    combine in any order: the air's density and viscosity are the largest asked for, extra (damping)
    viscosities add to them; each flex vertex carries a box of side ``spacing`` m. The parts are kept in
    ``spec["fluid_parts"]`` (not serialised)."""
    parts = spec.setdefault("fluid_parts", {"density": 0.0, "air_viscosity": 0.0, "extra_viscosity": 0.0})
    parts["density"] = max(parts["density"], float(density))
    parts["air_viscosity"] = max(parts["air_viscosity"], float(air_viscosity))
    parts["extra_viscosity"] += float(extra_viscosity)
    spec["option"]["density"] = parts["density"]
    spec["option"]["viscosity"] = parts["air_viscosity"] + parts["extra_viscosity"]
    spec["flexcomp"]["inertiabox"] = spacing


def fluid_force(v: np.ndarray, spacing: float, density: float, viscosity: float,
                wind: np.ndarray | None = None) -> np.ndarray:
    """The force ``(N, 3)`` N that MuJoCo's inertia-box fluid model applies to flex vertices with
    ``inertiabox = spacing`` (measured to machine precision against ``qfrc_fluid``):
    ``-(6 pi mu h u + 2 rho h^2 |u| u)`` per axis, ``u = v - wind`` (m/s), h = ``spacing`` (m),
    rho = ``density`` (kg/m^3), mu = ``viscosity`` (Pa s). The force-field version of :class:`AirDrag`
    and :class:`Wind` for backends without their MuJoCo model edit."""
    u = v if wind is None else v - np.asarray(wind, dtype=float)[None, :]
    h = float(spacing)
    return -(6.0 * math.pi * viscosity * h * u + 2.0 * density * h * h * np.abs(u) * u)


class AirDrag(Effect):
    """Aerodynamic drag on the cloth (MuJoCo inertia-box fluid model, per vertex).

    Physics: each vertex carries MuJoCo's inertia-box drag with ``inertiabox`` = h (the grid spacing) in
    air of density ``air_density`` kg/m^3 with kinematic viscosity 1.5e-5 m^2/s:
    ``F = -(6 pi mu h v + 2 rho h^2 |v| v)`` per axis (:func:`fluid_force`). Off at the lower bound
    0 kg/m^3. Model edit for ``mujoco-flex`` (integrated implicitly), force field elsewhere.
    """

    name: ClassVar[str] = "air-drag"
    description: ClassVar[str] = "aerodynamic drag of the air on the cloth (density in kg/m^3; air = 1.2)"
    backends: ClassVar[tuple[str, ...]] = ("mujoco-flex",)
    model_edits: ClassVar[tuple[str, ...]] = ("mujoco-flex",)

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("air_density", 0.0, 6.0, "kg/m^3",
                                 description="density of the air seen by the cloth (1.2 = air; larger = "
                                             "fluffier fabric, more drag per area)")])

    def edit_model(self, backend: str, model: Any, theta: Mapping[str, float], ctx: Mapping[str, Any]) -> None:
        """Fluid model at ``air_density`` with air's kinematic viscosity (so density 0 is the nominal model)."""
        rho = float(theta["air_density"])
        _fluid(model, float(ctx["spacing"]), density=rho, air_viscosity=AIR_VISCOSITY * rho / AIR_DENSITY)

    def force(self, x: np.ndarray, v: np.ndarray, t: float, theta: Mapping[str, float],
              ctx: VertexContext) -> np.ndarray:
        """Force field elsewhere: :func:`fluid_force` in still air (with ``wind`` also on, the two force
        fields add, i.e. the drag counts twice; on mujoco-flex the model edits combine them properly)."""
        rho = float(theta["air_density"])
        return fluid_force(v, ctx.spacing, rho, AIR_VISCOSITY * rho / AIR_DENSITY)


class Wind(Effect):
    """Steady horizontal wind (through MuJoCo's fluid model at air density 1.2 kg/m^3).

    Physics: the drag of :class:`AirDrag` at 1.2 kg/m^3 computed on the velocity relative to the wind
    ``(wind_x, wind_y, 0)`` m/s. Off at 0 m/s (the prior's midpoint). Model edit for ``mujoco-flex``,
    force field elsewhere.
    """

    name: ClassVar[str] = "wind"
    description: ClassVar[str] = "steady horizontal wind (m/s) acting on the cloth through air drag"
    backends: ClassVar[tuple[str, ...]] = ("mujoco-flex",)
    model_edits: ClassVar[tuple[str, ...]] = ("mujoco-flex",)

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("wind_x", -2.0, 2.0, "m/s", description="wind velocity along x"),
                           Param("wind_y", -2.0, 2.0, "m/s", description="wind velocity along y")])

    def nominal(self) -> dict[str, float]:
        return {"wind_x": 0.0, "wind_y": 0.0}

    def edit_model(self, backend: str, model: Any, theta: Mapping[str, float], ctx: Mapping[str, Any]) -> None:
        """Fluid model at air density and viscosity, option ``wind``."""
        _fluid(model, float(ctx["spacing"]), density=AIR_DENSITY, air_viscosity=AIR_VISCOSITY)
        model["option"]["wind"] = [float(theta["wind_x"]), float(theta["wind_y"]), 0.0]

    def force(self, x: np.ndarray, v: np.ndarray, t: float, theta: Mapping[str, float],
              ctx: VertexContext) -> np.ndarray:
        """Force field elsewhere: :func:`fluid_force` at air density relative to the wind."""
        return fluid_force(v, ctx.spacing, AIR_DENSITY, AIR_VISCOSITY,
                           np.array([float(theta["wind_x"]), float(theta["wind_y"]), 0.0]))


class ExtraDamping(Effect):
    """Velocity damping of the cloth vertices beyond the material's own damping.

    Physics: ``F_i = -damping_rate * m_i * v_i`` (N) on every vertex i (m_i kg, v_i m/s), i.e. a
    velocity decay at ``damping_rate`` 1/s. Off at the lower bound 0 1/s. Model edit for mujoco-flex
    (MuJoCo's Stokes viscosity ``mu = rate m_v / (6 pi h)``, integrated implicitly; with ``wind`` it acts
    on the velocity relative to the wind, as before), force field elsewhere.
    """

    name: ClassVar[str] = "extra-damping"
    description: ClassVar[str] = "extra velocity damping of the cloth (rate in 1/s)"
    backends: ClassVar[tuple[str, ...]] = ("mujoco-flex",)
    model_edits: ClassVar[tuple[str, ...]] = ("mujoco-flex",)

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("damping_rate", 0.0, 60.0, "1/s",
                                 description="F = -rate * m_vertex * v on every cloth vertex")])

    def edit_model(self, backend: str, model: Any, theta: Mapping[str, float], ctx: Mapping[str, Any]) -> None:
        """Stokes viscosity giving ``F = -rate m_v v`` on the vertex boxes of side h (``6 pi mu h = rate m_v``)."""
        h = float(ctx["spacing"])
        _fluid(model, h, extra_viscosity=float(theta["damping_rate"]) * float(ctx["vertex_mass"]) / (6.0 * math.pi * h))

    def force(self, x: np.ndarray, v: np.ndarray, t: float, theta: Mapping[str, float],
              ctx: VertexContext) -> np.ndarray:
        return -float(theta["damping_rate"]) * ctx.mass[:, None] * v


class GripCompliance(Effect):
    """A soft grasp: the cloth corner follows the gripper through a compliant constraint.

    Physics: the grasp constraint's time constant ``grip_timeconst`` s (MuJoCo ``solref``; the damping
    ratio is kept), so the corner lags the gripper. Off at the lower bound 0.008 s (the rigid grasp,
    twice the step). Model edit for ``mujoco-flex`` only.
    """

    name: ClassVar[str] = "grip-compliance"
    description: ClassVar[str] = "soft grasp: time constant (s) of the gripper-cloth constraint"
    backends: ClassVar[tuple[str, ...]] = ("mujoco-flex",)
    model_edits: ClassVar[tuple[str, ...]] = ("mujoco-flex",)

    def param_space(self) -> ParamSpace:
        # the rigid grasp is the edge of what the effect can be (the edit never goes below it): a physical limit
        return ParamSpace([Param("grip_timeconst", 0.008, 0.3, "s", log=True, limits=(0.008, float("inf")),
                                 description="time constant of the grasp constraint (0.008 s = rigid grasp)")])

    def edit_model(self, backend: str, model: Any, theta: Mapping[str, float], ctx: Mapping[str, Any]) -> None:
        """Only the time constant changes (never below the nominal grasp's), so the lower bound is nominal. Every
        other constraint on the gripper (``grasp-patch``'s held vertices) is slowed by the same factor, so the two
        edits give one model in either order."""
        grip = model["connect"]
        tc, ratio = grip["solref"]
        slow = max(float(theta["grip_timeconst"]), tc)
        for c in model.get("connects", [grip]):
            if c is not grip and c["body2"] == grip["body2"]:
                c["solref"] = [float(c["solref"][0]) * slow / tc, c["solref"][1]]
        grip["solref"] = [slow, ratio]


BUILTIN_EFFECTS = (AirDrag, Wind, ExtraDamping, GripCompliance)


@hookimpl
def softsbi_effects():
    """Every built-in effect: the four above, the physical, robot, sensor, material and rig candidates and the
    generic terms."""
    return [*BUILTIN_EFFECTS, *PHYSICS_EFFECTS, *ROBOT_EFFECTS, *SENSOR_EFFECTS, *GENERIC_EFFECTS, *MATERIAL_EFFECTS,
            *RIG_EFFECTS]
