"""The four built-in effects keep their numbers through the effect door.

``data/builtin_main.npz`` holds the vertices (m) of short lift and fling rollouts with each built-in
switched on, recorded from main's name-switch implementation (commit stored in the file) by
``record_reference.py``; the effect door must reproduce them within 1e-6 m.

One deliberate change: ``extra-damping`` applied twice its documented force on main (MuJoCo's
inertia-box viscous term is ``6 pi mu h v``); the force field applies ``-rate m v``, so the door's
rollout at ``2 * damping_rate`` is compared with main's at ``damping_rate``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.effects.record_reference import CASES, rollouts

pytestmark = pytest.mark.integration

#: parameter changes of the deliberate fixes (see the module docstring)
RESCALE = {"damping_rate": 2.0}

REF = Path(__file__).parent / "data" / "builtin_main.npz"


@pytest.fixture(scope="module")
def now():
    return rollouts(rescale=RESCALE)


@pytest.mark.parametrize("key", [f"{sc}/{eff}" for sc, eff, _ in CASES])
def test_builtin_effect_rollout_matches_main(now, key):
    ref = np.load(REF)
    err = np.abs(now[key] - ref[key]).max()
    assert err < 1e-6, f"{key}: max vertex difference {err:.3g} m from main ({ref['commit']})"


def test_reference_effects_are_not_nominal():
    """Each recorded effect moved the cloth by > 1 mm from the nominal rollout (else the test above is void)."""
    from softsbi.backends.mujoco_flex import MujocoFlex
    from tests.effects.record_reference import GRID, scenarios
    ref = np.load(REF)
    sim = MujocoFlex(grid=GRID)
    for name, sc in scenarios().items():
        base = sim.simulate(sc, sim.param_space(sc).midpoint()).vertices
        for sc_name, eff, _ in CASES:
            if sc_name == name:
                assert np.abs(ref[f"{sc_name}/{eff}"] - base).max() > 1e-3, eff
