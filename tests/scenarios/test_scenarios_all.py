"""The four scenarios (lift, wipe, winding, fling) roll out on both backends at the prior midpoint."""
from __future__ import annotations

import numpy as np
import pytest

from softsbi.backends.mujoco_flex import MujocoFlex
from softsbi.backends.pybullet_massspring import PybulletMassSpring
from softsbi.scenarios.builtin import SCENARIOS, make_scenario

pytestmark = pytest.mark.integration

BACKENDS = {"mujoco-flex": lambda: MujocoFlex(grid=6, rope_nodes=16),
            "pybullet-massspring": lambda: PybulletMassSpring(grid=6, rope_nodes=16)}


@pytest.mark.parametrize("backend", sorted(BACKENDS))
@pytest.mark.parametrize("name", SCENARIOS)
def test_midpoint_rollout(backend, name):
    sc = make_scenario(name)
    sim = BACKENDS[backend]()
    r = sim.simulate(sc, sim.param_space(sc).midpoint())
    assert r.ok, r.reason
    r.validate()
    assert r.vertices.shape[0] == sc.n_frames and np.all(np.isfinite(r.vertices))
    # the grasped vertex (0) follows the gripper
    assert np.linalg.norm(r.vertices[:, 0] - r.gripper, axis=1).max() < 0.03
    assert r.vertices[..., 2].min() > sc.table_z - 0.02
    if name == "winding":
        assert r.faces.shape == (0, 3)
        # the rope wraps: some vertices end within 1.5 cm of the spool surface
        sp = sc.object["spool"]
        rad = np.linalg.norm(r.vertices[-1, :, :2] - np.asarray(sp["centre"]), axis=1)
        assert (rad < sp["radius"] + 0.015).sum() >= 2
    else:
        assert r.faces.shape == (2 * 25, 3)


def test_make_scenario_errors():
    with pytest.raises(ValueError, match="Did you mean 'wipe'.*Valid scenarios: fling, lift, winding, wipe"):
        make_scenario("wip")
    with pytest.raises(ValueError, match="takes no recording"):
        make_scenario("wipe", recording="x")


@pytest.mark.parametrize("name", ["wipe", "winding", "fling"])
def test_synthetic_paths(name):
    sc = make_scenario(name)
    assert sc.name == name and sc.table_z == 0.0
    assert np.all(np.diff(sc.times) > 0) and sc.gripper.shape == (sc.n_frames, 3)
    # continuous: no jump between frames larger than 6 cm (12 cm in the fast fling)
    assert np.linalg.norm(np.diff(sc.gripper, axis=0), axis=1).max() < (0.12 if name == "fling" else 0.06)
    assert sc.gripper[:, 2].min() >= sc.table_z
