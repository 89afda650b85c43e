"""Record the built-in effects' rollouts of the name-switch implementation (main before the effect door).

Run once against main's code, e.g. a clean export of the commit::

    git archive bf45a27 softsbi | tar -x -C /tmp/main-ref
    REF_COMMIT=bf45a27 PYTHONPATH=/tmp/main-ref python tests/effects/record_reference.py OUT.npz

``test_builtin_regression.py`` compares the effect door's rollouts with the stored vertices (m).
Not collected by pytest (no ``test_`` prefix).
"""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np

from softsbi.backends.mujoco_flex import MujocoFlex
from softsbi.scenarios.builtin import fling_scenario, lift_scenario

#: (scenario, effect, effect parameters): each built-in switched on at a fixed, non-nominal value
CASES = [
    ("lift", "air-drag", {"air_density": 3.0}),
    ("lift", "wind", {"wind_x": 1.5, "wind_y": -1.0}),
    ("lift", "extra-damping", {"damping_rate": 12.0}),
    ("lift", "grip-compliance", {"grip_timeconst": 0.1}),
    ("fling", "air-drag", {"air_density": 3.0}),
    ("fling", "wind", {"wind_x": -1.0, "wind_y": 1.5}),
    ("fling", "extra-damping", {"damping_rate": 12.0}),
    ("fling", "grip-compliance", {"grip_timeconst": 0.1}),
    ("lift", "air-drag+wind", {"air_density": 3.0, "wind_x": 1.5, "wind_y": -1.0}),
    ("lift", "extra-damping+wind", {"damping_rate": 12.0, "wind_x": 1.5, "wind_y": -1.0}),
    ("fling", "air-drag+extra-damping+grip-compliance", {"air_density": 3.0, "damping_rate": 12.0,
                                                        "grip_timeconst": 0.1}),
]
GRID = 5


def scenarios():
    """The two short scenarios of the reference (lift 11 frames, fling 15 frames over 1.0 s)."""
    return {"lift": lift_scenario(None, n_frames=11), "fling": fling_scenario(n_frames=15, duration=1.0)}


def rollouts(rescale=None):
    """``{key: vertices (T, N, 3) m}`` for every case, with ``key = scenario/effects``; ``rescale``
    ``{parameter: factor}`` multiplies effect parameters (for deliberate changes of meaning)."""
    rescale = rescale or {}
    sim = MujocoFlex(grid=GRID)
    out = {}
    for sc_name, effects, values in CASES:
        sc = scenarios()[sc_name]
        theta = {**sim.param_space(sc).midpoint(), **{k: v * rescale.get(k, 1.0) for k, v in values.items()}}
        ro = sim.simulate(sc, theta, effects=effects.split("+"))
        assert ro.ok, ro.reason
        out[f"{sc_name}/{effects}"] = ro.vertices
    return out


if __name__ == "__main__":
    commit = os.environ.get("REF_COMMIT") or subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True,
                                                           text=True).stdout.strip()
    np.savez_compressed(sys.argv[1], commit=np.array(commit), **rollouts())
