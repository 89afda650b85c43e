"""A rope task's figures and words: a user's rope dragged past a block (and the built-in winding round its spool).
The preview draws the scenario's obstacles and names the effects switched on with their values; the check's regions
are segments along the rope from its grasped end, none greyed as unseen when the sensor sees them, and the figure
speaks of the rope; ``params`` words the friction from the task's own obstacles (no spool the task lacks)."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pytest

from result_helpers import check_result, joint
from softsbi.core.results.comparison import CompareResult
from softsbi.core.types import Rollout
from softsbi.report import figures as R
from softsbi.scenarios import load_scenario
from softsbi.scenarios.spec import load_scenario_file

#: the user's rope task of the rope diagnosis tests, "VIEW" where a test puts its figures' view
ROPE_DRAG = (Path(__file__).parents[1] / "workflows" / "rope_drag.yaml").read_text() + "VIEW"
#: vertices of the rope (a mujoco-flex rope's count), vertex 0 at the grasped end
N = 24


@pytest.fixture
def rope_drag(tmp_path):
    def make(view: str = ""):
        f = tmp_path / "rope_drag.yaml"
        f.write_text(ROPE_DRAG.replace("VIEW", view))
        return load_scenario_file(f)
    return make


def _rope_rollout(sc, reverse: bool = False) -> Rollout:
    """A straight rope 0.30 m long on the table behind its grasped end, dragged rigidly along the gripper's path
    (no simulation: the figures draw what they are given). ``reverse``: its vertices numbered from the free end."""
    rest = np.stack([-np.linspace(0, 0.30, N), np.zeros(N), np.full(N, 0.004)], 1)
    rest = rest[::-1] if reverse else rest
    shift = sc.gripper - sc.gripper[0]
    verts = rest[None] + np.concatenate([shift[:, :2], np.zeros((len(shift), 1))], 1)[:, None]
    return Rollout(times=sc.times, gripper=sc.gripper, vertices=verts, faces=np.zeros((0, 3), int))


def _texts(fig) -> list[str]:
    out = [t.get_text() for t in fig.texts]
    for ax in fig.axes:
        out += [ax.get_title(), ax.get_xlabel(), ax.get_ylabel()]
        out += [t.get_text() for t in ax.get_yticklabels() + ax.get_xticklabels()]
    for leg in fig.legends:
        out += [t.get_text() for t in leg.get_texts()]
    return out


def test_the_preview_draws_the_scenario_s_obstacles_and_names_the_effect_switched_on(rope_drag):
    sc = rope_drag("view: xy")
    fig = R.rollout_preview_figure(_rope_rollout(sc), "mujoco-flex rope-drag", sc, {"snag": {"snag_k": (6.0, "N/m")}})
    texts = _texts(fig)
    assert "with snag: snag_k = 6 N/m" in texts
    assert "block (box)" in texts  # named in the legend
    for ax in fig.axes:  # the block from above in the rest pose and in every frame: its 6 x 4 cm footprint
        (poly,) = ax.patches
        xy = poly.get_xy()
        assert xy[:, 0].min() == pytest.approx(0.02) and xy[:, 0].max() == pytest.approx(0.08)
        assert xy[:, 1].min() == pytest.approx(-0.08) and xy[:, 1].max() == pytest.approx(-0.04)
        lo, hi = ax.get_xlim()
        assert lo < 0.02 and hi > 0.08  # inside the view
    plt.close(fig)
    # from the side (x-z), the block stands on the table 4 cm high
    sc = rope_drag()
    fig = R.rollout_preview_figure(_rope_rollout(sc), "mujoco-flex rope-drag", sc)
    xy = fig.axes[1].patches[0].get_xy()
    assert xy[:, 1].min() == pytest.approx(0.0) and xy[:, 1].max() == pytest.approx(0.04)
    assert "no effect switched on" in _texts(fig)
    plt.close(fig)


def test_the_winding_preview_draws_its_spool():
    sc = load_scenario("winding")
    fig = R.rollout_preview_figure(_rope_rollout(sc), "mujoco-flex winding", sc, {"wind": {"wind_x": (1.5, "m/s"),
                                                                                           "wind_y": (0.0, "m/s")}})
    texts = _texts(fig)
    assert "spool (cylinder)" in texts and "with wind: wind_x = 1.5 m/s, wind_y = 0 m/s" in texts
    xy = fig.axes[1].patches[0].get_xy()  # its 3 cm radius round the origin, from above
    np.testing.assert_allclose(np.linalg.norm(xy, axis=1), 0.03, atol=1e-9)
    plt.close(fig)


@pytest.mark.integration
def test_simulate_s_preview_is_given_the_effects_values_and_units(rope_drag, tmp_path):
    from unittest import mock

    from softsbi.workflows import simulate as S
    sc = rope_drag()
    seen = {}
    with mock.patch.object(S, "plot_rollout_preview", lambda ro, path, title, scenario, effects: seen.update(
            title=title, effects=effects, obstacles=scenario.world.get("obstacles"))):
        S.simulate_to_folder(tmp_path / "out", scenario=str(tmp_path / "rope_drag.yaml"), effects=["wind"],
                             theta={"wind_x": 1.5}, cloud_points=50)
    assert seen["title"] == f"mujoco-flex {sc.name}"
    assert seen["effects"] == {"wind": {"wind_x": (1.5, "m/s"), "wind_y": (0.0, "m/s")}}
    assert seen["obstacles"][0]["name"] == "block"


def _rope_check(sc, reverse: bool = False):
    """A check of the rope drag computed as check_run computes its regions: the rope's material regions, then each
    region's error against a measurement 5 mm off the rollout, under the full clouds (no sensor model)."""
    from softsbi.workflows.criticism.check import material_regions, region_errors
    ro = _rope_rollout(sc, reverse)
    labels, names = material_regions(ro.vertices[0], sc.gripper[0])
    dense = [v + np.array([0.0, 0.005, 0.0]) for v in ro.vertices]
    reg = region_errors(ro.vertices, ro.faces, labels, dense, len(names))
    base = check_result(T=len(sc.times), test=joint(150, 150))
    return labels, names, dataclasses.replace(
        base, times_s=tuple(sc.times.tolist()), regions=tuple(names), region_error_m=tuple(map(tuple, reg.tolist())),
        region_compared=tuple(map(tuple, np.isfinite(reg).tolist())),
        region_mean_m=dict(zip(names, reg.mean(0).tolist())), worst_regions=(names[-1], names[-2]))


@pytest.mark.parametrize("reverse", [False, True])
def test_the_check_s_regions_follow_the_rope_from_its_grasped_end(rope_drag, reverse):
    """The cloth's 3 x 3 grid on a rope's rest pose left five of nine regions empty (greyed as unseen by the sensor)
    and the rest out of order along the rope."""
    sc = rope_drag()
    labels, names, out = _rope_check(sc, reverse)
    assert names == ["R1 (grasped end)"] + [f"R{r}" for r in range(2, 9)] + ["R9 (far end)"]
    along = labels[::-1] if reverse else labels  # from the grasped end (vertex 0 at x = 0, the grasp)
    assert along[0] == 0 and along[-1] == 8 and (np.diff(along) >= 0).all()
    assert sorted(np.bincount(labels)) == [2, 2, 2, 3, 3, 3, 3, 3, 3]  # equal segments, none empty
    assert np.array(out.region_compared).all()
    fig = R.check_figure(out)
    heat = fig.axes[1]
    assert heat.get_title() == "Error per segment of the rope (dashed: phase boundaries)"  # nothing greyed
    assert not np.ma.getmaskarray(heat.images[0].get_array()).any()
    assert heat.get_ylabel() == "segment of the rope (R1 at the grasp)"
    ticks = [t.get_text() for t in heat.get_yticklabels()]
    assert ticks[0] == "R1 grasped end" and ticks[-1] == "R9 far end"
    assert not [t for t in _texts(fig) if "cloth" in t]
    plt.close(fig)
    res = CompareResult(run_a="a", run_b="b", label_a="nominal", label_b="+ snag", rows=(), same_sensor=True,
                        check_a=out, check_b=out)
    fig = R.compare_figure(res)
    assert fig.axes[1].get_title() == "Error per segment of the rope"
    assert not [t for t in _texts(fig) if "cloth" in t]
    plt.close(fig)


def test_a_cloth_s_regions_stay_a_grid():
    from softsbi.workflows.criticism.check import material_regions
    xs = np.linspace(0, 0.2, 7)
    rest = np.array([[x, y, 0.0] for x in xs for y in xs])
    labels, names = material_regions(rest, np.zeros(3))
    assert names[0] == "R1 (at the grasp)" and names[-1] == "R9 (farthest from the grasp)"
    assert len(set(labels.tolist())) == 9 and labels[0] == 0
    fig = R.check_figure(check_result())
    assert fig.axes[1].get_title() == "Error per region of the cloth (dashed: phase boundaries)"
    plt.close(fig)


@pytest.mark.parametrize("backend", ["mujoco-flex", "pybullet-massspring"])
def test_params_words_the_rope_s_friction_from_the_task_s_own_obstacles(rope_drag, tmp_path, backend):
    from softsbi.plugins import registry
    sim = registry().simulator(backend)()
    assert sim.param_space(rope_drag())["friction"].description == "rope-table and rope-block friction coefficient"
    assert sim.param_space(load_scenario("winding"))["friction"].description == \
        "rope-table and rope-spool friction coefficient"
    bare = tmp_path / "bare.yaml"
    bare.write_text(ROPE_DRAG.replace("VIEW", "").split("  obstacles:")[0])
    assert sim.param_space(load_scenario_file(bare))["friction"].description == "rope-table friction coefficient"
