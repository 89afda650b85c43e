"""Toy effects for the diagnosis tests, loaded only where a test names this module in ``SOFTSBI_PLUGINS`` (an
effect tried before it is packaged): three shifts of the toy patch through the observation door. ``toy-drift``
and ``toy-rise`` move it in proportion to time (flexible candidates); ``toy-magnet`` lifts it mid-motion, which no
combination of the other two reproduces."""
from __future__ import annotations

import numpy as np

from softsbi import hookimpl
from softsbi.core.interfaces import Effect
from softsbi.core.types import Param, ParamSpace, Rollout


class _Shift(Effect):
    """A toy effect through the observation door: the observed patch moves by ``amount * profile(s_t)`` along
    ``axis`` (``s_t = t / (T - 1)``)."""

    backends = ("toy-gauss",)
    axis: int = 0
    unit_name: str = "amount"

    def profile(self, s: np.ndarray) -> np.ndarray:
        return s

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param(self.unit_name, 0.0, 0.5, "m", description=self.description)])

    def observe(self, rollout: Rollout, theta, rng) -> Rollout:
        T = len(rollout.vertices)
        v = np.array(rollout.vertices, float)
        s = np.linspace(0, 1, T) if T > 1 else np.zeros(1)
        v[:, :, self.axis] += theta[self.unit_name] * self.profile(s)[:, None]
        return Rollout(times=rollout.times, gripper=rollout.gripper, vertices=v, faces=rollout.faces,
                       status=rollout.status, reason=rollout.reason, info=dict(rollout.info))


class ToyDrift(_Shift):
    """Toy: the patch drifts along +y in proportion to time."""

    name = "toy-drift"
    description = "toy effect: shifts the patch by drift * t/T along y"
    axis, unit_name = 1, "drift"


class ToyRise(_Shift):
    """Toy: the patch rises along +z in proportion to time."""

    name = "toy-rise"
    description = "toy effect: shifts the patch by rise * t/T along z"
    axis, unit_name = 2, "rise"


class ToyMagnet(_Shift):
    """Toy: a magnet passing overhead lifts the patch mid-motion, ``pull * sin(pi t/T)`` along z; no combination of
    the other toy effects (linear in time) reproduces it."""

    name = "toy-magnet"
    description = "toy effect: lifts the patch by pull * sin(pi t/T) along z"
    axis, unit_name = 2, "pull"

    def profile(self, s: np.ndarray) -> np.ndarray:
        return np.sin(np.pi * s)


@hookimpl
def softsbi_effects():
    return [ToyDrift, ToyRise, ToyMagnet]
