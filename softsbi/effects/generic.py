"""Generic force terms (``generic = True``): a small library of force fields that describe a residual
no named effect explains ("misspecified by nothing installed").

They are not ordinary diagnosis candidates (``softsbi.workflows.criticism.diagnose`` leaves them out of its
default list); a verdict screens them to say which simple force shape explains the residual and by
how much. All are per unit mass (accelerations), so they do not depend on the cloth's density,
and all are off at zero.
"""
from __future__ import annotations

from typing import ClassVar, Mapping

import numpy as np

from softsbi.core.interfaces import Effect, VertexContext
from softsbi.core.types import Param, ParamSpace


class _Generic(Effect):
    """Base of the generic terms: physics, generic, off at zero."""

    generic: ClassVar[bool] = True
    backends: ClassVar[tuple[str, ...]] = ("mujoco-flex",)

    def nominal(self) -> dict[str, float]:
        return {p.name: 0.0 for p in self.param_space()}


class ConstantForce(_Generic):
    """Constant force per unit mass: ``F = m (a_x, a_y, a_z)`` N (a in m/s^2). Off at a = 0 (midpoint)."""

    name: ClassVar[str] = "generic-constant"
    description: ClassVar[str] = "generic term: constant acceleration (m/s^2) on every vertex"

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param(f"const_a{c}", -2.0, 2.0, "m/s^2", description=f"acceleration along {c}")
                           for c in "xyz"])

    def force(self, x: np.ndarray, v: np.ndarray, t: float, theta: Mapping[str, float],
              ctx: VertexContext) -> np.ndarray:
        a = np.array([theta["const_ax"], theta["const_ay"], theta["const_az"]], dtype=float)
        return ctx.mass[:, None] * a[None, :]


class LinearDrag(_Generic):
    """Drag linear in velocity, horizontal and vertical rates apart: ``F = -m (k_h v_x, k_h v_y, k_v v_z)``
    N (k in 1/s). Off at the lower bounds 0."""

    name: ClassVar[str] = "generic-linear-drag"
    description: ClassVar[str] = "generic term: drag linear in velocity (rates 1/s, horizontal and vertical)"

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("lin_kh", 0.0, 30.0, "1/s", description="horizontal damping rate"),
                           Param("lin_kv", 0.0, 30.0, "1/s", description="vertical damping rate")])

    def force(self, x: np.ndarray, v: np.ndarray, t: float, theta: Mapping[str, float],
              ctx: VertexContext) -> np.ndarray:
        k = np.array([theta["lin_kh"], theta["lin_kh"], theta["lin_kv"]], dtype=float)
        return -ctx.mass[:, None] * k[None, :] * v


class QuadraticDrag(_Generic):
    """Drag quadratic in velocity: ``F = -m c |v| v`` N (c in 1/m). Off at the lower bound 0."""

    name: ClassVar[str] = "generic-quadratic-drag"
    description: ClassVar[str] = "generic term: drag quadratic in velocity (1/m)"

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("quad_c", 0.0, 20.0, "1/m", description="quadratic drag per unit mass")])

    def force(self, x: np.ndarray, v: np.ndarray, t: float, theta: Mapping[str, float],
              ctx: VertexContext) -> np.ndarray:
        return -float(theta["quad_c"]) * ctx.mass[:, None] * np.linalg.norm(v, axis=1, keepdims=True) * v


class HeightForce(_Generic):
    """Force linear in the height above the table: ``F = m (k_x, k_y, k_z) (z - table_z)`` N
    (k in 1/s^2). Off at k = 0 (midpoint)."""

    name: ClassVar[str] = "generic-height-force"
    description: ClassVar[str] = "generic term: acceleration proportional to the height above the table (1/s^2)"

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param(f"height_k{c}", -20.0, 20.0, "1/s^2", description=f"acceleration along {c} per m of height")
                           for c in "xyz"])

    def force(self, x: np.ndarray, v: np.ndarray, t: float, theta: Mapping[str, float],
              ctx: VertexContext) -> np.ndarray:
        k = np.array([theta["height_kx"], theta["height_ky"], theta["height_kz"]], dtype=float)
        return ctx.mass[:, None] * (x[:, 2:3] - ctx.table_z) * k[None, :]


GENERIC_EFFECTS = (ConstantForce, LinearDrag, QuadraticDrag, HeightForce)
