"""Rendering in both backends (``simulate_images``) and the helpers of softsbi.perception.render."""
from __future__ import annotations

import numpy as np
import pytest

from softsbi.backends.mujoco_flex import MujocoFlex, grid_corners
from softsbi.backends.pybullet_massspring import PybulletMassSpring
from softsbi.scenarios.builtin import wipe_scenario
from softsbi.core.camera import Camera, RenderStyle
from softsbi.scenarios.cameras import scenario_camera
from softsbi.core.errors import DataError, ShapeError
from softsbi.core.interfaces import Simulator
from softsbi.core.types import SEG_OBJECT, SEG_ROBOT, Param, ParamSpace, Rollout
from softsbi.perception.masks import hsv_mask
from softsbi.perception.render import (
    backproject_depth,
    render_rollout,
    robot_mask_from_depth,
    save_frames_png,
    save_gif,
)

pytestmark = pytest.mark.integration

GRID = 5
SIZE = 96
BACKENDS = {"mujoco-flex": MujocoFlex, "pybullet-massspring": PybulletMassSpring}


@pytest.fixture(scope="module")
def scenario():
    return wipe_scenario(n_frames=7)


@pytest.fixture(scope="module")
def camera(scenario):
    return scenario_camera(scenario, SIZE)


@pytest.fixture(scope="module")
def odd_camera(camera):
    """Same pose, but non-square pixels, fx != fy and an off-centre principal point: catches sign and
    half-pixel errors in the intrinsics -> engine conversion."""
    return Camera(88, 72, 0.93 * camera.fx * 88 / SIZE, 1.04 * camera.fy * 88 / SIZE, 47.0, 33.0,
                  camera.world_to_cam)


@pytest.fixture(scope="module", params=sorted(BACKENDS))
def rendered(request, scenario, camera, odd_camera):
    """Per backend: plain rollout, rendered rollout (robot shown), rendered without robot (odd camera)."""
    sim = BACKENDS[request.param](grid=GRID)
    theta = sim.param_space(scenario).midpoint()
    plain = sim.simulate(scenario, theta)
    with_robot = sim.simulate_images(scenario, theta, camera)
    no_robot = sim.simulate_images(scenario, theta, odd_camera, style=RenderStyle(show_robot=False))
    return {"name": request.param, "sim": sim, "theta": theta, "plain": plain, "img": with_robot,
            "bare": no_robot}


def test_shapes_and_dtypes(rendered, scenario, camera):
    ro = rendered["img"]
    assert ro.ok, ro.reason
    T = scenario.n_frames
    assert ro.rgb.shape == (T, SIZE, SIZE, 3) and ro.rgb.dtype == np.uint8
    assert ro.depth.shape == (T, SIZE, SIZE) and ro.depth.dtype == np.float32
    assert ro.segmentation.shape == (T, SIZE, SIZE) and ro.segmentation.dtype == np.uint8
    assert set(np.unique(ro.segmentation)) <= {0, 1, 2}
    assert np.all(np.isfinite(ro.depth)) and ro.depth.min() > 0
    bare = rendered["bare"]
    assert bare.rgb.shape == (T, 72, 88, 3) and bare.segmentation.shape == (T, 72, 88)


def test_simulate_unchanged_and_corners(rendered):
    """simulate_images rolls out exactly like simulate; both report the grid corners."""
    plain, img, bare = rendered["plain"], rendered["img"], rendered["bare"]
    assert np.array_equal(plain.vertices, img.vertices) and np.array_equal(plain.vertices, bare.vertices)
    assert np.array_equal(plain.gripper, img.gripper)
    assert plain.rgb is None and plain.depth is None
    assert plain.info["corners"] == img.info["corners"] == grid_corners(GRID) == [0, 4, 24, 20]


def test_cloth_pixels_green(rendered):
    ro = rendered["img"]
    cloth = ro.segmentation == SEG_OBJECT
    assert cloth.sum(axis=(1, 2)).min() > 200          # the cloth is in view in every frame
    mean = ro.rgb[cloth].mean(axis=0)
    assert mean[1] > mean[0] + 20 and mean[1] > mean[2] + 20, mean
    # the HSV cloth mask finds the rendered cloth (same thresholds as for the real images)
    m = hsv_mask(ro.rgb)
    iou = (m & cloth).sum() / (m | cloth).sum()
    assert iou > 0.9, iou


def _analytic_table_depth(camera, table_z):
    """Depth along the optical axis at which each pixel's ray meets the plane z = table_z."""
    v, u = np.mgrid[0:camera.height, 0:camera.width].astype(float)
    rays = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], -1) @ camera.R
    return (table_z - camera.position[2]) / rays[..., 2]


@pytest.mark.parametrize("which", ["img", "bare"])
def test_table_depth_analytic(rendered, scenario, camera, odd_camera, which):
    ro = rendered[which]
    cam = camera if which == "img" else odd_camera
    table = ro.segmentation == 0
    expect = np.broadcast_to(_analytic_table_depth(cam, scenario.table_z), ro.depth.shape)
    err = np.abs(ro.depth[table] - expect[table])
    assert table.sum() > 1000 and err.max() < 0.01, err.max()


def _near_label(seg, uv, label, r=2):
    u, v = round(float(uv[0])), round(float(uv[1]))
    win = seg[max(v - r, 0):v + r + 1, max(u - r, 0):u + r + 1]
    return win.size > 0 and bool(np.any(win == label))


def test_corner_projection_on_cloth(rendered, camera, odd_camera):
    """Camera.project of the 4 corner vertices lands on cloth pixels (within 2 px), in every frame, for
    the off-centre camera without robot and, where not under the gripper, for the default camera."""
    for key, cam in (("bare", odd_camera), ("img", camera)):
        ro = rendered[key]
        corners = ro.info["corners"]
        checked = 0
        for k in range(len(ro.times)):
            uv, _ = cam.project(ro.vertices[k, corners])
            for c, p in zip(corners, uv):
                if not (0 <= p[0] < cam.width and 0 <= p[1] < cam.height):
                    continue
                if key == "img" and _near_label(ro.segmentation[k], p, SEG_ROBOT, r=3):
                    continue  # hidden under the gripper
                assert _near_label(ro.segmentation[k], p, SEG_OBJECT), (key, k, c, p)
                checked += 1
        assert checked >= 2 * len(ro.times)


def test_robot_mask_from_depth_matches_segmentation(rendered, scenario, camera):
    ro = rendered["img"]
    robot = ro.segmentation == SEG_ROBOT
    est = robot_mask_from_depth(ro.depth, camera, scenario.table_z)
    assert est.shape == robot.shape and est.dtype == bool
    for k in range(len(ro.times)):
        iou = (est[k] & robot[k]).sum() / max((est[k] | robot[k]).sum(), 1)
        assert robot[k].sum() > 30 and iou > 0.8, (k, iou)


def test_hidden_robot(rendered, scenario, odd_camera):
    ro = rendered["bare"]
    assert not np.any(ro.segmentation == SEG_ROBOT)
    assert not np.any(robot_mask_from_depth(ro.depth, odd_camera, scenario.table_z))


def test_bad_camera_or_style(rendered, scenario):
    sim, theta = rendered["sim"], rendered["theta"]
    with pytest.raises(DataError, match="Camera"):
        sim.simulate_images(scenario, theta, camera="top")
    with pytest.raises(DataError, match="RenderStyle"):
        sim.simulate_images(scenario, theta, scenario_camera(wipe_scenario(n_frames=7), 32), style={"cloth": (0, 255, 0)})
    cam = scenario_camera(wipe_scenario(n_frames=7), 32)
    with pytest.raises(DataError, match="reflection"):  # a mirrored camera is refused when it is built
        Camera(32, 32, cam.fx, cam.fy, cam.cx, cam.cy, np.diag([-1.0, 1.0, 1.0]) @ np.asarray(cam.world_to_cam))


class _NoRender(Simulator):
    name = "no-render"
    scenarios = ("wipe",)

    def param_space(self, scenario):
        return ParamSpace([Param("a", 0.0, 1.0)])

    def simulate(self, scenario, theta, effects=(), seed=0):
        T = scenario.n_frames
        return Rollout(scenario.times, scenario.gripper, np.zeros((T, 1, 3)), np.zeros((0, 3), int))


def test_backend_without_rendering(scenario, camera):
    with pytest.raises(NotImplementedError, match="no-render.*cannot render"):
        _NoRender().simulate_images(scenario, {"a": 0.5}, camera)
    from softsbi.plugins import registry
    if "toy-gauss" in registry().tables["simulator"]:
        from softsbi.scenarios.builtin import lift_scenario
        with pytest.raises(NotImplementedError, match="toy-gauss"):
            render_rollout("toy-gauss", lift_scenario(None, n_frames=3), {"a": 0.0, "b": 0.0}, size=32)


def test_render_rollout_convenience_and_outputs(tmp_path):
    ro = render_rollout("mujoco-flex", wipe_scenario(n_frames=3), size=48, grid=4)
    assert ro.ok and ro.rgb.shape == (3, 48, 48, 3)
    png = save_frames_png(ro.rgb, tmp_path / "sheet" / "wipe.png", ncols=2)
    assert png.is_file() and png.stat().st_size > 1000
    assert save_frames_png(ro.segmentation == SEG_OBJECT, tmp_path / "masks.png").is_file()
    gif = save_gif(ro.rgb, tmp_path / "wipe.gif", fps=5)
    assert gif.read_bytes()[:3] == b"GIF"
    with pytest.raises(ShapeError):
        save_frames_png(ro.rgb[0], tmp_path / "bad.png")
    with pytest.raises(ShapeError):
        save_frames_png(ro.rgb, tmp_path / "bad.png", labels=["a"])
    with pytest.raises(ShapeError):
        robot_mask_from_depth(ro.depth[:, :10], scenario_camera(wipe_scenario(n_frames=7), 48), 0.0)


def test_backproject_depth_inverts_project():
    cam = Camera.look_at((0.3, -0.5, 0.6), (0.0, 0.0, 0.0), fovy_deg=50, width=40, height=30)
    pts = np.array([[0.05, 0.02, 0.0], [-0.1, 0.1, 0.03]])
    uv, z = cam.project(pts)
    # put each point's depth at its (rounded) pixel and compare the back-projection there
    depth = np.ones((30, 40))
    for (u, v), d in zip(np.round(uv).astype(int), z):
        depth[v, u] = d
    world = backproject_depth(depth, cam)
    for (u, v), p in zip(np.round(uv).astype(int), pts):
        # the rounded pixel shifts the point by < 1 px at its depth
        assert np.linalg.norm(world[v, u] - p) < 2 * z.max() / cam.fx


def test_failed_rollout_has_no_images(scenario):
    """A diverged rollout is returned (not raised) without images, and the GL context is released."""
    sim = MujocoFlex(grid=GRID, integrator="Euler", overrides={"young": 1e10})
    theta = sim.param_space(scenario).midpoint()
    ro = sim.simulate_images(scenario, theta, scenario_camera(wipe_scenario(n_frames=7), 32))
    assert not ro.ok and ro.rgb is None and ro.depth is None and ro.segmentation is None
