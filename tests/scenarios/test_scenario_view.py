"""What a scenario gets for being seen (its camera, the figures' view, the visual arm's place) comes from its
scenario file: the built-ins declare what they got by name before, and a user's file can declare the same."""
from __future__ import annotations

import numpy as np
import pytest

from softsbi.backends.common import robot_base
from softsbi.core.camera import Camera
from softsbi.core.errors import DataError
from softsbi.scenarios import builtin as b
from softsbi.scenarios import load_scenario
from softsbi.scenarios.cameras import scenario_camera
from softsbi.scenarios.spec import load_scenario_file
from toy_helpers import DATA

#: the cameras the built-in scenarios had by name before their files declared them (look-at arguments)
OLD_CAMERAS = {
    "wipe": dict(eye=(-0.08, 0.075, 1.0), target=(-0.08, 0.075, 0.0), up=(1, 0, 0), fovy_deg=52.0),
    "fling": dict(eye=(0.0, -0.9, 0.75), target=(0.0, 0.0, 0.2), up=(0, 0, 1), fovy_deg=55.0),
    "lift": dict(eye=(0.0, 0.0, 1.2), target=(0.0, 0.0, 0.1), up=(1, 0, 0), fovy_deg=50.0),
    "wind": dict(eye=(0.0, -0.8, 0.6), target=(0.0, 0.0, 0.15), up=(0, 0, 1), fovy_deg=50.0),
}
OLD_VIEWS = {"lift": "yz", "wind": "xy", "wipe": "xz", "fling": "xz"}


def old_robot_base(sc) -> np.ndarray:
    """Where the visual arm stood before scenarios declared it (chosen by the scenario's name)."""
    g, tz = sc.gripper, float(sc.table_z)
    if sc.name == "lift":
        return b.real_to_lift_frame(np.array([0.0, 0.0, 0.33]), sc.options.get("transform", b.DEFAULT_TRANSFORM))
    if sc.name == "wipe":
        return np.array([g[:, 0].max() + 0.45, g[:, 1].mean(), tz + 0.5])
    return np.array([g[:, 0].mean(), g[:, 1].max() + 0.55, tz + 0.5])


def _as_before(name, sc, size):
    cam = scenario_camera(sc, size)
    assert cam == Camera.look_at(width=size, height=size, **OLD_CAMERAS[name]), name
    assert sc.view == OLD_VIEWS[name], name
    np.testing.assert_allclose(robot_base(sc), old_robot_base(sc), rtol=0, atol=1e-12, err_msg=name)
    # what a run stores of the scenario keeps them
    again = type(sc).from_json(sc.to_json())
    assert again.view == sc.view and scenario_camera(again, size) == cam


@pytest.mark.parametrize("size", [128, 64])
@pytest.mark.parametrize("name", sorted(OLD_CAMERAS))
def test_built_in_scenarios_render_and_draw_as_they_did_by_name(name, size):
    _as_before(name, load_scenario(name), size)  # the built-in file
    _as_before(name, b.make_scenario(name, n_frames=9), size)  # its reference constructor, other arguments


@pytest.mark.skipif(not (DATA / "diffcloud_lift" / "lift_tan").is_dir(), reason="needs ../shared/data/diffcloud_lift")
def test_a_lift_recording_renders_and_draws_as_it_did_by_name():
    _as_before("lift", b.lift_scenario(DATA / "diffcloud_lift" / "lift_tan"), 128)


USER = """
format: softsbi-scenario/1
name: sweep
object: {kind: cloth, size: 0.2}
placement: {corner: [0.0, 0.0], direction: [-1.0, 0.0]}
handles:
  - name: grip
    grasp: {corner: 0}
    path:
      frame: robot
      keyframes: [{t: 0.0, p: [0.5, 0.0, 0.0]}, {t: 0.4, p: [0.6, 0.0, 0.05]}]
frames: {count: 4, duration: 0.4}
transforms:
  robot: {matrix: [[1, 0, 0, -0.5], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}
world: {table_z: 0.0}
CAMERAS
view: yz
robot: {base: [0.5, 0.4, 0.3], frame: robot}
"""
CALIBRATED = """cameras:
  - name: rig
    intrinsics: {fx: 40.0, fy: 42.0, cx: 19.5, cy: 15.5}
    world_to_cam: [[0, 1, 0, 0], [1, 0, 0, 0], [0, 0, -1, 0.8]]
    width: 40
    height: 32
"""


def test_a_users_scenario_file_declares_its_camera_view_and_arm(tmp_path):
    f = tmp_path / "sweep.yaml"
    f.write_text(USER.replace("CAMERAS", CALIBRATED))
    sc = load_scenario_file(f)
    rig = Camera(40, 32, 40.0, 42.0, 19.5, 15.5, ((0, 1, 0, 0), (1, 0, 0, 0), (0, 0, -1, 0.8)))
    assert scenario_camera(sc, None) == rig
    assert scenario_camera(sc, 80) == rig.resized(80, 64)  # rescaled, aspect ratio kept
    assert sc.view == "yz"
    np.testing.assert_allclose(robot_base(sc), [0.0, 0.4, 0.3])  # declared in the robot frame, mapped

    from softsbi.perception.render import render_rollout
    ro = render_rollout("mujoco-flex", sc, size=None, grid=4)  # no camera given: the scenario's own
    assert ro.rgb.shape == (4, 32, 40, 3)
    from softsbi.backends.mujoco_flex import MujocoFlex
    sim = MujocoFlex(grid=4)
    same = sim.simulate_images(sc, sim.param_space(sc).midpoint(), rig)
    np.testing.assert_array_equal(ro.rgb, same.rgb)


def test_a_scenario_without_a_camera_says_how_to_declare_one(tmp_path):
    f = tmp_path / "sweep.yaml"
    f.write_text(USER.replace("CAMERAS", ""))
    sc = load_scenario_file(f)
    with pytest.raises(DataError, match=r"^scenario 'sweep' declares no camera; add one under 'cameras:'") as info:
        scenario_camera(sc)
    assert "\n" not in str(info.value)
    f.write_text(USER.replace("CAMERAS", CALIBRATED.replace("    width: 40", "    eye: [0, 0, 1]\n    width: 40")))
    with pytest.raises(DataError, match=r"cameras.*either 'eye' and 'target' \(look-at\) or 'intrinsics'"):
        load_scenario_file(f)
    f.write_text(USER.replace("CAMERAS", "").replace("frame: robot}", "frame: arm}"))
    with pytest.raises(DataError, match=r"field 'robot.frame': unknown frame 'arm'"):
        load_scenario_file(f)
