"""A two-gripper stretch written as a scenario file rolls out on both backends."""
from pathlib import Path

import numpy as np
import pytest

import softsbi
from softsbi.backends.scenario_build import check_features, required_features

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "stretch_two_grippers.yaml"


@pytest.mark.parametrize("backend", ["mujoco-flex", "pybullet-massspring"])
def test_two_gripper_stretch_rolls_out(backend):
    sc = softsbi.load_scenario(EXAMPLE)
    assert required_features(sc) == ["cloth", "several handles"]
    ro = softsbi.simulate(sc, backend=backend)
    assert ro.ok, ro.reason
    a, c = ro.info["handle_vertices"]
    assert (a, c) == (0, 80)  # corners 0 and 2 of the 9 x 9 grid
    for v, h in ((a, sc.handles[0]), (c, sc.handles[1])):
        # each held corner follows its own path (shifted to start on it) to within 5 mm
        err = np.linalg.norm(ro.vertices[:, v] - (h.path + ro.vertices[0, v] - h.path[0]), axis=1)
        assert err.max() < 0.005, (backend, h.name, err.max())
    gap = np.linalg.norm(ro.vertices[:, a] - ro.vertices[:, c], axis=1)
    # the grippers come 12 cm closer mid-way and pull the diagonal taut again at the end
    assert gap[12] < gap[0] - 0.10 and abs(gap[-1] - gap[0]) < 0.01
    assert ro.vertices[-1, [a, c], 2].min() > sc.table_z + 0.14


def test_missing_feature_is_one_line_naming_it():
    sc = softsbi.load_scenario(EXAMPLE)

    class OneHand:
        name = "one-hand"
        features = ("cloth",)

    with pytest.raises(ValueError, match=r"^one-hand cannot run scenario 'stretch': it lacks several handles "
                                         r"\(it supports cloth\)"):
        check_features(OneHand, sc)
