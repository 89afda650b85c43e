"""Physical candidate effects for cloth and rope, as engine-neutral force fields (the effect door).

Each is a :class:`~softsbi.core.interfaces.Effect` with a :meth:`force` (N per vertex, world frame,
z up), so every backend that applies vertex forces runs it without knowing its name. Each is off at
a prior bound (listed per class) and changes the rollout in the direction its docstring states
(``tests/effects/test_candidates.py``).

"Resting on the table" below means within :data:`CONTACT_BAND` of the vertex's rest height (the
cloth starts flat on the table, one collision radius above it).
"""
from __future__ import annotations

import math
from typing import ClassVar, Mapping

import numpy as np

from softsbi.core.interfaces import Effect, VertexContext
from softsbi.core.types import Param, ParamSpace

#: a vertex within this height (m) above its rest height counts as resting on the table
CONTACT_BAND = 0.005
#: speed (m/s) above which the sticky patch's friction force saturates (smooth Coulomb law; keeps the
#: explicit force stable at MuJoCo's 4 ms step: rate mu g / V_SMOOTH <= 98 1/s)
V_SMOOTH = 0.1


def _on_table(x: np.ndarray, ctx: VertexContext) -> np.ndarray:
    """``(N,)`` bool: vertices resting on the table (within :data:`CONTACT_BAND` of their rest height)."""
    rest = max(float(ctx.x0[:, 2].min()), ctx.table_z)
    return x[:, 2] < rest + CONTACT_BAND


class TableSlope(Effect):
    """A tilted table: the downhill component of gravity on the vertices resting on it.

    Physics: the table descends by ``slope_x`` (deg) along +x and ``slope_y`` (deg) along +y, i.e. its
    tilt ``alpha`` has ``tan(alpha) = |(tan slope_x, tan slope_y)|`` towards that direction. A resting
    vertex of mass m feels ``m g sin(alpha)`` downhill along the table, on top of the (horizontal)
    table's contact and friction, and its normal load falls by ``m g (1 - cos alpha)``. The table plane
    itself stays where it is (an approximation for small angles: the height change over the cloth,
    ``L tan alpha``, is ignored). Off at ``slope_x = slope_y = 0`` (the prior's midpoint). The two
    gradient components (not a tilt and a direction) keep the effect linear to first order in both
    parameters, so the diagnosis's finite-difference screening sees a tilt in any direction (with a
    direction parameter the derivative at zero tilt sees only one). Direction: the cloth drifts
    downhill while it slides on the table.
    """

    name: ClassVar[str] = "table-slope"
    description: ClassVar[str] = "tilted table: downhill pull m g sin(slope) on the vertices resting on it"
    backends: ClassVar[tuple[str, ...]] = ("mujoco-flex",)

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("slope_x", -10.0, 10.0, "deg", limits=(-90.0, 90.0),
                                 description="descent of the table along +x"),
                           Param("slope_y", -10.0, 10.0, "deg", limits=(-90.0, 90.0),
                                 description="descent of the table along +y")])

    def nominal(self) -> dict[str, float]:
        return {"slope_x": 0.0, "slope_y": 0.0}

    def force(self, x: np.ndarray, v: np.ndarray, t: float, theta: Mapping[str, float],
              ctx: VertexContext) -> np.ndarray:
        grad = np.array([math.tan(math.radians(float(theta["slope_x"]))),
                         math.tan(math.radians(float(theta["slope_y"])))])
        tan_a = float(np.linalg.norm(grad))
        if tan_a == 0.0:
            return np.zeros_like(x)
        a = math.atan(tan_a)
        g = float(np.linalg.norm(ctx.gravity))
        down = grad / tan_a
        acc = np.array([g * math.sin(a) * down[0], g * math.sin(a) * down[1], g * (1.0 - math.cos(a))])
        return _on_table(x, ctx)[:, None] * ctx.mass[:, None] * acc[None, :]


class StickyPatch(Effect):
    """A sticky patch of the table: extra sliding friction inside a disc under the cloth's rest position.

    Physics: a vertex resting on the table inside the disc of radius ``patch_radius`` (m) centred on the
    cloth's rest centroid feels an extra friction force ``-patch_friction m g u / max(|u|, V_SMOOTH)``
    with u its horizontal velocity (smooth Coulomb friction, saturating above :data:`V_SMOOTH` m/s),
    on top of the table's own friction. Off at the lower bound ``patch_friction = 0``. Direction: cloth
    dragged over the patch lags behind (less displacement along the drag).
    """

    name: ClassVar[str] = "sticky-patch"
    description: ClassVar[str] = "a disc of the table with extra friction under the cloth's rest position"
    backends: ClassVar[tuple[str, ...]] = ("mujoco-flex",)

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("patch_friction", 0.0, 1.5, "1", description="extra friction coefficient in the patch"),
                           Param("patch_radius", 0.03, 0.2, "m", description="radius of the sticky disc")])

    def force(self, x: np.ndarray, v: np.ndarray, t: float, theta: Mapping[str, float],
              ctx: VertexContext) -> np.ndarray:
        centre = ctx.x0[:, :2].mean(axis=0)
        inside = np.linalg.norm(x[:, :2] - centre, axis=1) <= float(theta["patch_radius"])
        on = inside & _on_table(x, ctx)
        u = np.zeros_like(v)
        u[:, :2] = v[:, :2]
        speed = np.maximum(np.linalg.norm(u, axis=1), V_SMOOTH)
        g = float(np.linalg.norm(ctx.gravity))
        return -(on * float(theta["patch_friction"]) * ctx.mass * g / speed)[:, None] * u


class HeavyHem(Effect):
    """A heavy hem: extra weight along the cloth's border (a rope: at both ends).

    Physics: a hem of linear density ``hem_density`` (kg/m) sewn along the four edges adds the weight
    ``hem_density * spacing * g`` (N, along gravity) to every border vertex. Its weight only: the hem's
    inertia is not added (the vertex masses are the engine's). Off at the lower bound 0 kg/m.
    Direction: a lifted cloth hangs lower (its free edges sag).
    """

    name: ClassVar[str] = "heavy-hem"
    description: ClassVar[str] = "extra weight along the cloth's edges (hem, kg/m)"
    backends: ClassVar[tuple[str, ...]] = ("mujoco-flex",)

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("hem_density", 0.0, 0.05, "kg/m", description="linear density of the hem")])

    def force(self, x: np.ndarray, v: np.ndarray, t: float, theta: Mapping[str, float],
              ctx: VertexContext) -> np.ndarray:
        w = float(theta["hem_density"]) * ctx.spacing
        return ctx.edges[:, None] * w * ctx.gravity[None, :]


PHYSICS_EFFECTS = (TableSlope, StickyPatch, HeavyHem)
