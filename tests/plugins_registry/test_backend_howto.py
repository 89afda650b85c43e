"""docs/howto/backend-plugin.md builds a working backend: its code, run as written, passes the conformance checker
and applies a built-in sensor effect through its observation door."""
from __future__ import annotations

import re
import types
from pathlib import Path

import numpy as np

from softsbi.backends.conformance import check_simulator
from softsbi.scenarios.builtin import make_scenario

HOWTO = Path(__file__).resolve().parents[2] / "docs" / "howto" / "backend-plugin.md"


def _howto_backend() -> types.ModuleType:
    """The how-to's first Python block, executed as a module (as a user's plugin module would be)."""
    code = re.search(r"```python\n(.*?)```", HOWTO.read_text(), re.S).group(1)
    module = types.ModuleType("hanging_sheet")
    exec(compile(code, str(HOWTO), "exec"), module.__dict__)
    return module


def test_the_howtos_backend_passes_the_conformance_checker():
    sheet = _howto_backend().HangingSheet
    assert check_simulator(sheet, "lift") == []
    assert check_simulator(sheet(n=3), "lift") == []


def test_the_howtos_backend_applies_a_sensor_effect_through_its_observation_door():
    sim = _howto_backend().HangingSheet()
    sc = make_scenario("lift")
    theta = {"scale": 0.2, "sag": 0.1, "offset_x": 0.0, "offset_y": 0.0, "offset_z": 0.02}
    plain = sim.simulate(sc, {"scale": 0.2, "sag": 0.1})
    shifted = sim.simulate(sc, theta, effects=("calibration-offset",))
    assert plain.ok and plain.vertices.shape == (sc.n_frames, 25, 3)
    np.testing.assert_allclose(shifted.vertices - plain.vertices, np.broadcast_to([0, 0, 0.02], plain.vertices.shape),
                               atol=1e-12)
