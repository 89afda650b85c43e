"""Every registered simulator (built-in and third-party, e.g. toy-gauss) passes check_simulator
for every scenario it lists."""
from __future__ import annotations

import pytest

from softsbi.backends.conformance import ConformanceError, check_simulator
from softsbi.core.errors import ParameterError
from softsbi.core.types import ParamSpace, Param, Rollout
from softsbi.plugins import registry

pytestmark = pytest.mark.integration

#: small meshes for the built-in engines (the check is about the contract, not accuracy)
SMALL = {"mujoco-flex": {"grid": 5, "rope_nodes": 12}, "pybullet-massspring": {"grid": 5, "rope_nodes": 12}}

CASES = [(name, sc) for name, cls in sorted(registry().tables["simulator"].items()) for sc in cls.scenarios]


def test_registry_has_both_backends_and_toy():
    names = set(registry().tables["simulator"])
    assert {"mujoco-flex", "pybullet-massspring", "toy-gauss"} <= names


@pytest.mark.parametrize("name,scenario", CASES, ids=[f"{n}-{s}" for n, s in CASES])
def test_conformance(name, scenario):
    if name == "newton-cloth":
        pytest.importorskip("newton", reason='newton-cloth needs Newton: pip install "softsbi[newton]"')
    cls = registry().simulator(name)
    sim = cls(**SMALL[name]) if name in SMALL else cls
    problems = check_simulator(sim, scenario)
    assert problems == [], problems


def test_checker_finds_problems():
    class Broken:
        name = "broken"
        scenarios = ("lift",)
        effects = ()

        def param_space(self, scenario):
            return ParamSpace([Param("a", 0.0, 1.0, "1")])

        def simulate(self, scenario, theta, effects=(), seed=0):  # ignores bounds, effects, scenario; bad shapes
            import numpy as np
            T = scenario.n_frames
            return Rollout(times=scenario.times, gripper=np.zeros((T, 2)), vertices=np.random.rand(T, 4, 3),
                           faces=np.zeros((1, 3), int))

    probs = check_simulator(Broken(), "lift")
    text = "\n".join(probs)
    assert "gripper must be" in text and "deterministic" in text
    assert "below its physical limit" in text and "unknown effect" in text and "unknown scenario" in text
    with pytest.raises(ConformanceError, match="broken"):
        check_simulator(Broken(), "lift", raise_on_error=True)
    assert issubclass(ConformanceError, Exception) and not issubclass(ConformanceError, ParameterError)
