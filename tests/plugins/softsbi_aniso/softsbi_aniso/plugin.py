"""Anisotropic table friction, a third-party effect that softsbi's backends know nothing about.

``aniso-friction``: a ribbed table (or a fabric with a nap) resists sliding across the ribs, along
the table's x axis, more than along them. A vertex resting on the table (within 5 mm of its rest
height) that slides with velocity ``u_x`` along x feels the extra friction force

    F_x = -rib_friction * m * g * u_x / max(|u_x|, 0.1 m/s)      (N; F_y = F_z = 0)

(smooth Coulomb friction, saturating above 0.1 m/s so that it stays stable at explicit 4 ms steps).
``rib_friction`` is dimensionless (prior 0-3), off at the lower bound 0. It acts through the force-field door
(:meth:`softsbi.core.interfaces.Effect.force`), so every backend that applies vertex forces runs it.
"""
from __future__ import annotations

from typing import ClassVar, Mapping

import numpy as np

from softsbi import hookimpl
from softsbi.core.interfaces import Effect, VertexContext
from softsbi.core.types import Param, ParamSpace

#: height above the rest height (m) below which a vertex rests on the table
BAND = 0.005
#: speed (m/s) above which the friction saturates
V_SMOOTH = 0.1


class AnisotropicFriction(Effect):
    """Extra table friction across the ribs (along x): F_x = -mu m g u_x / max(|u_x|, 0.1 m/s). Off at mu = 0."""

    name: ClassVar[str] = "aniso-friction"
    description: ClassVar[str] = "ribbed table: extra sliding friction along x only (coefficient)"

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("rib_friction", 0.0, 3.0, "1",
                                 description="extra friction coefficient for sliding along the table's x axis")])

    def force(self, x: np.ndarray, v: np.ndarray, t: float, theta: Mapping[str, float],
              ctx: VertexContext) -> np.ndarray:
        rest = max(float(ctx.x0[:, 2].min()), ctx.table_z)
        on = x[:, 2] < rest + BAND
        g = float(np.linalg.norm(ctx.gravity))
        f = np.zeros_like(v)
        mu = float(theta["rib_friction"])
        f[:, 0] = -np.where(on, mu * ctx.mass * g, 0.0) * v[:, 0] / np.maximum(np.abs(v[:, 0]), V_SMOOTH)
        return f


@hookimpl
def softsbi_effects():
    return [AnisotropicFriction]
