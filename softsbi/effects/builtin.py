"""Built-in effects for the ``mujoco-flex`` backend.

Each effect has its own parameters in physical units; its lower bound (or zero) switches
it off. A backend applies an effect by name; for MuJoCo the application edits the model
dict of :func:`softsbi.backends.mujoco_flex.build_spec` before it is compiled:

* ``air-drag``: MuJoCo's inertia-box fluid model (MuJoCo docs, *Computation / Fluid forces*):
  option ``density`` (kg/m^3) and ``viscosity`` (air's kinematic viscosity times the density:
  1.8e-5 Pa s at 1.2 kg/m^3), with the flex vertex
  ``inertiabox`` set to the grid spacing so each vertex carries the drag of its cloth patch
  (measured here: a 1 m drop ends at 0.01 m without air, 0.57 m with density 1.2).
* ``wind``: option ``wind`` (m/s) acting through the same fluid model at air density 1.2.
* ``extra-damping``: velocity damping of every cloth vertex at a rate gamma (1/s): MuJoCo's
  viscous (Stokes) term of the fluid model with ``viscosity = gamma * m_v / (3 pi h)``, m_v the
  vertex mass and h the spacing, i.e. ``F = -gamma m_v v``.
* ``grip-compliance``: the grasp is soft: the time constant (s) of the weld between gripper and
  cloth corner (``solref`` of the equality constraint), so the corner lags and sags like cloth
  slipping in soft fingers.
"""
from __future__ import annotations

import math
from typing import Any, ClassVar, Mapping

from softsbi.core.interfaces import Effect
from softsbi.core.types import Param, ParamSpace
from softsbi.plugins.hookspecs import hookimpl

AIR_VISCOSITY = 1.8e-5  # Pa s
AIR_DENSITY = 1.2  # kg/m^3


class AirDrag(Effect):
    """Aerodynamic drag on the cloth (inertia-box fluid model, per vertex)."""

    name: ClassVar[str] = "air-drag"
    description: ClassVar[str] = "aerodynamic drag of the air on the cloth (density in kg/m^3; air = 1.2)"
    backends: ClassVar[tuple[str, ...]] = ("mujoco-flex",)

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("air_density", 0.0, 6.0, "kg/m^3",
                                 description="density of the air seen by the cloth (1.2 = air; larger = "
                                             "fluffier fabric, more drag per area)")])


class Wind(Effect):
    """Steady horizontal wind (through the fluid model at air density 1.2 kg/m^3)."""

    name: ClassVar[str] = "wind"
    description: ClassVar[str] = "steady horizontal wind (m/s) acting on the cloth through air drag"
    backends: ClassVar[tuple[str, ...]] = ("mujoco-flex",)

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("wind_x", -2.0, 2.0, "m/s", description="wind velocity along x"),
                           Param("wind_y", -2.0, 2.0, "m/s", description="wind velocity along y")])

    def nominal(self) -> dict[str, float]:
        return {"wind_x": 0.0, "wind_y": 0.0}


class ExtraDamping(Effect):
    """Velocity damping of the cloth vertices beyond the material's own damping."""

    name: ClassVar[str] = "extra-damping"
    description: ClassVar[str] = "extra velocity damping of the cloth (rate in 1/s)"
    backends: ClassVar[tuple[str, ...]] = ("mujoco-flex",)

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("damping_rate", 0.0, 30.0, "1/s",
                                 description="F = -rate * m_vertex * v on every cloth vertex")])


class GripCompliance(Effect):
    """A soft grasp: the cloth corner follows the gripper through a compliant constraint."""

    name: ClassVar[str] = "grip-compliance"
    description: ClassVar[str] = "soft grasp: time constant (s) of the gripper-cloth constraint"
    backends: ClassVar[tuple[str, ...]] = ("mujoco-flex",)

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("grip_timeconst", 0.008, 0.3, "s", log=True,
                                 description="time constant of the grasp constraint (0.008 s = rigid grasp)")])


BUILTIN_EFFECTS = (AirDrag, Wind, ExtraDamping, GripCompliance)


def apply_mujoco(spec: dict[str, Any], theta: Mapping[str, float], effects, *, grid: int) -> None:
    """Edit a ``mujoco-flex`` model dict in place for the given effect names.

    Args:
        spec: the dict of :func:`softsbi.backends.mujoco_flex.build_spec`.
        theta: parameter values, including each effect's parameters (physical units).
        effects: effect names (already validated by the backend).
        grid: vertices per side (for the per-vertex mass and spacing).
    """
    fc = spec["flexcomp"]
    h = float(fc["spacing"][0])
    fluid = False
    density = 0.0
    viscosity = 0.0
    if "air-drag" in effects:
        density = max(density, float(theta["air_density"]))
        # constant kinematic viscosity of air: mu = nu * rho, so density 0 is the nominal model
        viscosity = AIR_VISCOSITY * density / AIR_DENSITY
        fluid = True
    if "wind" in effects:
        density = max(density, AIR_DENSITY)
        viscosity = max(viscosity, AIR_VISCOSITY)
        spec["option"]["wind"] = [float(theta["wind_x"]), float(theta["wind_y"]), 0.0]
        fluid = True
    if "extra-damping" in effects:
        m_v = float(fc["mass"]) / (grid * grid)
        viscosity += float(theta["damping_rate"]) * m_v / (3.0 * math.pi * h)
        fluid = True
    if fluid:
        spec["option"]["density"] = density
        spec["option"]["viscosity"] = viscosity
        fc["inertiabox"] = h
    if "grip-compliance" in effects:
        # only the time constant changes (the damping ratio stays), so the lower bound is the nominal grasp
        tc, ratio = spec["connect"]["solref"]
        spec["connect"]["solref"] = [max(float(theta["grip_timeconst"]), tc), ratio]


@hookimpl
def softsbi_effects():
    return list(BUILTIN_EFFECTS)
