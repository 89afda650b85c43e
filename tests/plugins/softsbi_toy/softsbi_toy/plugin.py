"""A cheap analytic simulator with a known (linear-Gaussian) posterior, and one effect.

``toy-gauss``: a tiny square patch (side 2 mm) whose centre at frame t is

    c_t = A_t theta + eps_t,  A_t = 0.1 * [[1, 0], [0, 1], [s_t, s_t]],  s_t = t / (T - 1),
    eps_t ~ N(0, sigma^2 I),  sigma = 0.05 m (seeded by ``seed``)

plus ``wind * s_t`` along x when the ``toy-wind`` effect is on. With a uniform prior
wide enough, the posterior given the centres is Gaussian with precision
``sum_t A_t^T A_t / sigma^2`` (see :func:`analytic_posterior`).

Test hooks (environment variables read at each ``simulate``): ``SOFTSBI_TOY_SLEEP=<s>`` sleeps
(``SOFTSBI_TOY_START_SLEEP=<s>``: the simulator's construction sleeps, a worker's start-up);
``SOFTSBI_TOY_DIVERGE_ABOVE=<a>`` returns a diverged rollout for a larger ``a``;
``SOFTSBI_TOY_CRASH_ONCE=<dir>`` kills the worker process (``os._exit(13)``) the first time a
seed is simulated (a marker file ``<dir>/crashed-<seed>`` records it);
``SOFTSBI_TOY_CRASH_ABOVE=<a>`` kills it (``os._exit(14)``) for a larger ``a``, every time;
``SOFTSBI_TOY_HANG_ABOVE=<a>`` sleeps forever for a larger ``a``.
"""
from __future__ import annotations

import os
import time

import numpy as np

from softsbi import hookimpl
from softsbi.core.interfaces import Effect, Simulator
from softsbi.core.types import STATUS_DIVERGED, Param, ParamSpace, Rollout, Scenario

SIGMA = 0.05
HALF = 0.001


def design(T: int) -> np.ndarray:
    """``(T, 3, 2)`` matrices A_t."""
    s = np.linspace(0, 1, T) if T > 1 else np.zeros(1)
    A = np.zeros((T, 3, 2))
    A[:, 0, 0] = 0.1
    A[:, 1, 1] = 0.1
    A[:, 2, 0] = 0.1 * s
    A[:, 2, 1] = 0.1 * s
    return A


def analytic_posterior(centres: np.ndarray, wind: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Mean ``(2,)`` and covariance ``(2, 2)`` of theta given observed centres ``(T, 3)`` (flat prior)."""
    T = len(centres)
    A = design(T)
    y = np.array(centres, float)
    y[:, 0] -= wind * (np.linspace(0, 1, T) if T > 1 else 0)
    P = np.einsum("tki,tkj->ij", A, A) / SIGMA**2
    b = np.einsum("tki,tk->i", A, y) / SIGMA**2
    cov = np.linalg.inv(P)
    return cov @ b, cov


def toy_scenario(T: int = 3) -> Scenario:
    return Scenario(name="toy", times=np.arange(T) * 0.1, gripper=np.zeros((T, 3)), table_z=0.0,
                    object={"kind": "patch"})


class ToyWind(Effect):
    """Constant push along +x growing over the trajectory (toy)."""

    name = "toy-wind"
    description = "toy effect: shifts the patch by wind * t/T along x"
    backends = ("toy-gauss",)

    def param_space(self) -> ParamSpace:
        return ParamSpace([Param("wind", 0.0, 0.5, "m", description="toy wind displacement at the end")])


class ToyGauss(Simulator):
    """Linear-Gaussian toy simulator with an analytic posterior; its own effect is ``toy-wind``, and it applies any
    effect's observation transform (the built-in sensor effects, the shifts of :mod:`softsbi_toy.shifts`)."""

    name = "toy-gauss"
    scenarios = ("toy", "lift")
    effects = ("toy-wind",)
    effect_kinds = ("observation",)

    def __init__(self, sigma: float = SIGMA, batch_size: int = 1):
        self.sigma = float(sigma)
        self.batch_size = int(batch_size)  # > 1: workers get simulations in batches (the inherited simulate_batch)
        if os.environ.get("SOFTSBI_TOY_START_SLEEP"):
            time.sleep(float(os.environ["SOFTSBI_TOY_START_SLEEP"]))

    def param_space(self, scenario: Scenario) -> ParamSpace:
        return ParamSpace([Param("a", -1.0, 1.0, "1", description="toy parameter a"),
                           Param("b", -1.0, 1.0, "1", description="toy parameter b")])

    def simulate(self, scenario, theta, effects=(), seed=0):
        if scenario.name not in self.scenarios:
            raise ValueError(f"toy-gauss cannot run scenario '{scenario.name}'; it runs {list(self.scenarios)}")
        from softsbi.backends.common import check_effects
        plan = check_effects(self, [e for e in effects if e not in self.effects])
        space = self.param_space(scenario)
        if "toy-wind" in effects:
            space = space + ToyWind().param_space()
        for e in plan.effects:
            space = space + e.param_space()
        vals = space.check({k: v for k, v in theta.items() if k in space.names}, within="limits")
        T = scenario.n_frames
        # test hooks: slow simulations (to kill a fit mid-round), a divergence region, a region the engine warns in
        if os.environ.get("SOFTSBI_TOY_SLEEP"):
            time.sleep(float(os.environ["SOFTSBI_TOY_SLEEP"]))
        # fault-injection hooks (executor tests): crash the worker process once per seed, hang
        crash_dir = os.environ.get("SOFTSBI_TOY_CRASH_ONCE")
        if crash_dir:
            marker = os.path.join(crash_dir, f"crashed-{int(seed)}")
            if not os.path.exists(marker):
                open(marker, "w").close()
                os._exit(13)
        crash_above = os.environ.get("SOFTSBI_TOY_CRASH_ABOVE")
        if crash_above is not None and vals["a"] > float(crash_above):
            os._exit(14)
        hang_above = os.environ.get("SOFTSBI_TOY_HANG_ABOVE")
        if hang_above is not None and vals["a"] > float(hang_above):
            while True:
                time.sleep(3600)
        limit = os.environ.get("SOFTSBI_TOY_DIVERGE_ABOVE")
        if limit is not None and vals["a"] > float(limit):
            return Rollout(times=scenario.times.copy(), gripper=scenario.gripper.copy(),
                           vertices=np.full((T, 4, 3), np.nan), faces=np.array([[0, 1, 2], [0, 2, 3]]),
                           status=STATUS_DIVERGED, reason=f"toy divergence: a = {vals['a']:.3f} > {limit}")
        rng = np.random.default_rng(seed)
        th = np.array([vals["a"], vals["b"]])
        c = design(T) @ th + rng.normal(0, self.sigma, (T, 3))
        if "toy-wind" in effects:
            c[:, 0] += vals["wind"] * (np.linspace(0, 1, T) if T > 1 else 0)
        sq = np.array([[-HALF, -HALF, 0], [HALF, -HALF, 0], [HALF, HALF, 0], [-HALF, HALF, 0]])
        verts = c[:, None, :] + sq[None]
        faces = np.array([[0, 1, 2], [0, 2, 3]])
        info = {"centres": c}
        warn_above = os.environ.get("SOFTSBI_TOY_WARN_ABOVE")  # an engine that warns (INFO_ENGINE_WARNINGS)
        if warn_above is not None and vals["a"] > float(warn_above):
            info["engine_warnings"] = f"toy warning: a = {vals['a']:.3f} > {warn_above}"
        ro = Rollout(times=scenario.times.copy(), gripper=scenario.gripper.copy(), vertices=verts, faces=faces,
                     info=info)
        return plan.observe(ro, vals, seed)


@hookimpl
def softsbi_simulators():
    return [ToyGauss]


@hookimpl
def softsbi_effects():
    return [ToyWind]
