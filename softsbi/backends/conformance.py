"""Conformance checker for Simulator plugins (in the spirit of Gymnasium's ``check_env``).

:func:`check_simulator` runs a simulator through the contract of
:class:`softsbi.core.interfaces.Simulator`: class attributes, a valid parameter space, rollout
shapes and units, finiteness, determinism and the documented errors for bad input.
"""
from __future__ import annotations

import inspect
import math
from typing import Any

import numpy as np

from softsbi.core.errors import ParameterError, SoftsbiError
from softsbi.core.interfaces import Simulator
from softsbi.core.types import STATUS_NAMES, STATUS_OK, ParamSpace, Rollout, Scenario
from softsbi.plugins import registry
from softsbi.scenarios.builtin import SCENARIOS, make_scenario


class ConformanceError(SoftsbiError, AssertionError):
    """A simulator breaks the plugin contract; ``problems`` lists every finding."""

    def __init__(self, name: str, problems: list[str]):
        self.problems = list(problems)
        super().__init__(f"simulator '{name}' fails {len(problems)} conformance check(s):\n  - "
                         + "\n  - ".join(problems))


def default_scenario(name: str) -> Scenario:
    """A scenario by name: the built-in ones from :func:`softsbi.scenarios.builtin.make_scenario`,
    else a minimal 3-frame scenario of that name (for third-party scenario names)."""
    if name in SCENARIOS:
        return make_scenario(name)
    return Scenario(name=name, times=np.arange(3) * 0.1, gripper=np.zeros((3, 3)), table_z=0.0)


def check_simulator(sim: type[Simulator] | Simulator, scenario: Scenario | str | None = None, *,
                    raise_on_error: bool = False, check_determinism: bool = True) -> list[str]:
    """Check a simulator class (instantiated with no arguments) or instance against the contract.

    Checks: ``name``/``scenarios``/``effects`` class attributes; ``param_space`` returns a
    non-empty :class:`ParamSpace`; ``simulate`` at the prior midpoint returns a :class:`Rollout`
    with ``T = scenario.n_frames``, ``times (T,)``, ``gripper (T, 3)``, ``vertices (T, N, 3)``,
    ``faces (F, 3)`` integer indices < N, a known status, finite values when ok; the same seed
    gives identical vertices; a value outside the physical limits (:attr:`~softsbi.core.types.Param.physical_limits`; not
    the declared prior, which ``--bounds`` may widen) or a non-finite one raises :class:`ParameterError`; an unknown
    effect raises :class:`ParameterError`; an unknown scenario raises ``ValueError`` (or
    ``ParameterError``).

    Args:
        sim: the class or an instance.
        scenario: a :class:`Scenario`, a scenario name, or None (the first of ``sim.scenarios``).
        raise_on_error: raise :class:`ConformanceError` listing all problems instead of returning them.
        check_determinism: run the midpoint rollout twice.

    Returns:
        A list of human-readable problems (empty: conformant).

    Raises:
        ConformanceError: with ``raise_on_error`` and at least one problem.
    """
    problems: list[str] = []
    cls = sim if inspect.isclass(sim) else type(sim)
    name = getattr(cls, "name", None)
    if not isinstance(name, str) or not name:
        problems.append("class attribute 'name' must be a non-empty string")
        name = cls.__name__
    for attr in ("scenarios", "effects"):
        v = getattr(cls, attr, None)
        if not isinstance(v, (tuple, list)) or not all(isinstance(x, str) for x in v):
            problems.append(f"class attribute '{attr}' must be a tuple of strings, got {v!r}")
    if not getattr(cls, "scenarios", None):
        problems.append("'scenarios' is empty: the simulator runs no scenario")
        return _finish(name, problems, raise_on_error)
    try:
        inst = cls() if inspect.isclass(sim) else sim
    except Exception as exc:  # noqa: BLE001
        problems.append(f"cannot instantiate {cls.__name__}() with no arguments: {type(exc).__name__}: {exc}")
        return _finish(name, problems, raise_on_error)
    if scenario is None or isinstance(scenario, str):
        scenario = default_scenario(scenario or cls.scenarios[0])

    # parameter space
    try:
        space = inst.param_space(scenario)
    except Exception as exc:  # noqa: BLE001
        problems.append(f"param_space({scenario.name!r}) raised {type(exc).__name__}: {exc}")
        return _finish(name, problems, raise_on_error)
    if not isinstance(space, ParamSpace) or space.dim == 0:
        problems.append(f"param_space must return a non-empty ParamSpace, got {space!r}")
        return _finish(name, problems, raise_on_error)
    for p in space:
        if not np.isfinite([p.low, p.high]).all():
            problems.append(f"parameter '{p.name}' has non-finite bounds")
        if not p.unit:
            problems.append(f"parameter '{p.name}' has no unit")
    theta = space.midpoint()

    # a rollout
    ro = _simulate(inst, scenario, theta, 0, problems, "at the prior midpoint")
    if ro is not None:
        problems += _rollout_problems(ro, scenario)
        if check_determinism:
            ro2 = _simulate(inst, scenario, theta, 0, problems, "(second run, same seed)")
            if ro2 is not None and (ro2.vertices.shape != ro.vertices.shape
                                    or not np.array_equal(ro2.vertices, ro.vertices)):
                problems.append("not deterministic: the same parameters and seed gave different vertices")

    # bad input
    # outside the physical limits (a prior widened with --bounds beyond the declared one must still simulate)
    p0 = space.params[0]
    span = p0.high - p0.low
    lowest = p0.physical_limits[0]
    bad = dict(theta, **{p0.name: lowest - max(abs(span), 1.0) if math.isfinite(lowest) else math.nan})
    _expect(lambda: inst.simulate(scenario, bad), (ParameterError,), problems,
            f"a value of '{p0.name}' below its physical limit" if math.isfinite(lowest)
            else f"a non-finite value of '{p0.name}'")
    _expect(lambda: inst.simulate(scenario, theta, effects=["__no_such_effect__"]), (ParameterError,), problems,
            "an unknown effect")
    unknown = Scenario(name="__no_such_scenario__", times=scenario.times, gripper=scenario.gripper,
                       table_z=scenario.table_z, object=dict(scenario.object, kind="__no_such_kind__"))
    _expect(lambda: inst.simulate(unknown, theta), (ValueError, ParameterError), problems, "an unknown scenario")
    return _finish(name, problems, raise_on_error)


def _simulate(inst: Simulator, scenario: Scenario, theta: dict[str, float], seed: int, problems: list[str],
              what: str) -> Rollout | None:
    try:
        ro = inst.simulate(scenario, theta, seed=seed)
    except Exception as exc:  # noqa: BLE001
        problems.append(f"simulate {what} raised {type(exc).__name__}: {exc}")
        return None
    if not isinstance(ro, Rollout):
        problems.append(f"simulate must return a Rollout, got {type(ro).__name__}")
        return None
    return ro


def _rollout_problems(ro: Rollout, scenario: Scenario) -> list[str]:
    out: list[str] = []
    T = scenario.n_frames
    shp = lambda a: getattr(a, "shape", None)  # noqa: E731
    if shp(ro.times) != (T,):
        out.append(f"times must be ({T},), got {shp(ro.times)}")
    if shp(ro.gripper) != (T, 3):
        out.append(f"gripper must be ({T}, 3), got {shp(ro.gripper)}")
    v = np.asarray(ro.vertices)
    if v.ndim != 3 or v.shape[0] != T or v.shape[2] != 3:
        out.append(f"vertices must be ({T}, N, 3), got {v.shape}")
    f = np.asarray(ro.faces)
    if f.ndim != 2 or f.shape[1] != 3:
        out.append(f"faces must be (F, 3), got {f.shape}")
    elif len(f) and (not np.issubdtype(f.dtype, np.integer) or f.min() < 0
                     or (v.ndim == 3 and f.max() >= v.shape[1])):
        out.append("faces must be integer indices into the vertices")
    if ro.status not in STATUS_NAMES:
        out.append(f"unknown status {ro.status!r}")
    if ro.status == STATUS_OK:
        for nm, a in (("times", ro.times), ("gripper", ro.gripper), ("vertices", ro.vertices)):
            if not np.all(np.isfinite(np.asarray(a, float))):
                out.append(f"status ok but {nm} contains NaN/inf")
    elif not ro.reason:
        out.append("a failed rollout must give a reason")
    return out


def _expect(fn, types: tuple[type, ...], problems: list[str], what: str) -> None:
    try:
        fn()
    except types:
        return
    except Exception as exc:  # noqa: BLE001
        problems.append(f"{what} raised {type(exc).__name__} ({exc}), expected "
                        f"{' or '.join(t.__name__ for t in types)}")
        return
    problems.append(f"{what} did not raise (expected {' or '.join(t.__name__ for t in types)})")


def _finish(name: str, problems: list[str], raise_on_error: bool) -> list[str]:
    if problems and raise_on_error:
        raise ConformanceError(name, problems)
    return problems


def check_registered(**kw: Any) -> dict[tuple[str, str], list[str]]:
    """:func:`check_simulator` over every registered simulator and each scenario it lists."""
    out = {}
    for name, cls in sorted(registry().tables["simulator"].items()):
        for sc in cls.scenarios:
            out[(name, sc)] = check_simulator(cls, sc, **kw)
    return out
