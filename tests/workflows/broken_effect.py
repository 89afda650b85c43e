"""A broken effect plugin for the diagnosis tests (loaded by path through ``SOFTSBI_PLUGINS``): its observation
transform fails with a softsbi error in every rollout of the toy simulator."""
from __future__ import annotations

from softsbi import hookimpl
from softsbi.core.errors import ShapeError
from softsbi.core.interfaces import Effect
from softsbi.core.types import Param, ParamSpace, Rollout


class ToyBroken(Effect):
    """Toy: an effect whose code fails in every rollout."""

    name = "toy-broken"
    description = "toy effect whose observe() fails"
    backends = ("toy-gauss",)

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("broken", 0.0, 0.5, "m", description="unused")])

    def observe(self, rollout: Rollout, theta, rng) -> Rollout:
        raise ShapeError("effect 'toy-broken': observe() must return a Rollout of the same shape")


@hookimpl
def softsbi_effects():
    return [ToyBroken]
