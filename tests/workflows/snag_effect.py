"""A user's own rope effect for the rope diagnosis tests (loaded by path through ``SOFTSBI_PLUGINS``): a peg on the
drag line snags the rope, pulling the vertex that lay nearest it at rest back towards it with a spring."""
from __future__ import annotations

import numpy as np

from softsbi import hookimpl
from softsbi.core.interfaces import Effect, VertexContext
from softsbi.core.types import Param, ParamSpace

#: the peg's position on the table (m, scenario frame): on the rope, 10 cm from its grasped end at rest
PEG = np.array([-0.10, 0.0])


class Snag(Effect):
    """A peg that snags the rope: a spring of stiffness ``snag_k`` (N/m) pulls the vertex nearest the peg at rest
    horizontally back towards it. Off at 0 N/m."""

    name = "snag"
    description = "a peg snags the rope: a spring towards a fixed point (N/m)"
    objects = ("rope",)

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("snag_k", 0.0, 10.0, "N/m", description="stiffness of the snag's spring")])

    def force(self, x: np.ndarray, v: np.ndarray, t: float, theta, ctx: VertexContext) -> np.ndarray:
        f = np.zeros_like(x)
        i = int(np.argmin(np.linalg.norm(ctx.x0[:, :2] - PEG, axis=1)))
        f[i, :2] = -float(theta["snag_k"]) * (x[i, :2] - PEG)
        return f


@hookimpl
def softsbi_effects():
    return [Snag]
