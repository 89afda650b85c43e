"""Image pipeline end to end: camera model, frames on disk, image observers, `fit --observer heatmap|transporter`."""
from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from softsbi.cli import app
from softsbi.core.camera import Camera, RenderStyle
from softsbi.scenarios.cameras import scenario_camera
from softsbi.scenarios import load_scenario
from softsbi.core.errors import DataError, ShapeError, SoftsbiError
from softsbi.core.types import Observation
from toy_helpers import DATA

pytestmark = pytest.mark.integration


runner = CliRunner()
SIZE = 48


# ---------------------------------------------------------------------------- camera
def test_look_at_puts_up_at_the_image_top_and_right_handed():
    cam = Camera.look_at(eye=(0, 0, 1), target=(0, 0, 0), up=(1, 0, 0), fovy_deg=60, width=64, height=64)
    uv, z = cam.project(np.array([[0.0, 0, 0], [0.2, 0, 0], [0, 0.2, 0]]))
    assert np.allclose(uv[0], [31.5, 31.5]) and np.allclose(z, 1.0)
    assert uv[1, 1] < uv[0, 1] and np.isclose(uv[1, 0], uv[0, 0])  # +x (up) -> towards the top row
    assert uv[2, 0] < uv[0, 0]  # seen from above with x up, +y is to the left (no mirror image)
    assert np.isclose(np.linalg.det(cam.R), 1.0)
    assert np.allclose(cam.position, [0, 0, 1])
    # the focal length gives the requested field of view
    assert np.isclose(cam.fovy_deg, 60.0)


def test_camera_resize_json_and_calibration_files():
    cam = scenario_camera(load_scenario("wipe"), 128)
    small = cam.resized(64, 64)
    p = np.array([[0.1, 0.05, 0.0]])
    assert np.allclose((cam.project(p)[0] + 0.5) / 2 - 0.5, small.project(p)[0])
    assert Camera.from_json(json.loads(json.dumps(cam.to_json()))) == cam
    over = Camera.from_calibration(DATA / "diffcloud_lift" / "calib_overhead")
    assert (over.width, over.height) == (640, 480) and np.isclose(over.fx, 614.9, atol=0.1)
    # the overhead camera of the real rig sits about 0.94 m above the robot base
    assert 0.8 < over.position[2] < 1.1
    with pytest.raises(DataError, match="intrinsics.npy"):
        Camera.from_calibration(DATA)
    with pytest.raises(DataError, match="rotation"):
        Camera(64, 64, 50, 50, 32, 32, ((2, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0)))
    assert RenderStyle.from_json(RenderStyle(cloth=(1, 2, 3)).to_json()).cloth == (1, 2, 3)


def test_observation_state_normalises_2d_keypoints():
    kp = np.array([[[32.0, 16.0], [0.0, 64.0]]])
    o = Observation(points=kp, gripper=np.array([[0.1, 0.2, 0.3]]), times=np.zeros(1), image_size=(64, 32))
    s = o.state()
    assert s.shape == (1, 3, 3)
    assert np.allclose(s[0, 0], [0.1, 0.2, 0.3]) and np.allclose(s[0, 1:], [[0.5, 0.5, 0], [0, 2.0, 0]])
    with pytest.raises(ShapeError, match="image_size"):
        Observation(points=kp, gripper=np.zeros((1, 3)), times=np.zeros(1)).state()


# ---------------------------------------------------------------------------- frames on disk
def test_frames_round_trip_and_bad_folders(tmp_path):
    from softsbi.perception.images import check_images, load_frames, save_frames
    rng = np.random.default_rng(0)
    imgs = rng.integers(0, 255, (3, 20, 30, 3), dtype=np.uint8)
    save_frames(imgs, tmp_path / "f")
    assert np.array_equal(load_frames(tmp_path / "f"), imgs)  # PNG is lossless
    assert load_frames(tmp_path / "f", size=(15, 10)).shape == (3, 10, 15, 3)
    with pytest.raises(DataError, match="distortion"):
        load_frames(tmp_path / "f", size=(20, 20))
    (tmp_path / "f" / "001.png").unlink()
    with pytest.raises(DataError, match="gaps"):
        load_frames(tmp_path / "f")
    with pytest.raises(DataError, match="does not exist"):
        load_frames(tmp_path / "nope")
    with pytest.raises(ShapeError, match="RGBA"):
        check_images(np.zeros((2, 8, 8, 4), np.uint8))
    with pytest.raises(ShapeError, match="uint8"):
        check_images(np.zeros((2, 8, 8, 3), np.float32))


# ---------------------------------------------------------------------------- end to end
@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """A tiny rendered training set, tiny trained extractors and a rendered measurement on disk."""
    from softsbi.perception.synthdata import render_training_set, visible_corner_labels
    from softsbi.plugins import registry

    root = tmp_path_factory.mktemp("img")
    d = render_training_set("mujoco-flex", "wipe", n_rollouts=2, size=SIZE, seed=0, frames=range(0, 31, 2))
    hm = registry().extractor("heatmap")(input_size=32, layers=[1, 1, 1, 1], width=4, epochs=1, augment=False)
    hm.fit(d["images"], visible_corner_labels(d["corners"], SIZE, SIZE), seed=0)
    hm.save(root / "hm.pt")
    tp = registry().extractor("transporter")(**_tiny_transporter())
    tp.fit(d["images"], None, d["robot_masks"], seed=0, sequence_ids=d["sequence_ids"])
    tp.save(root / "tp.pt")
    res = runner.invoke(app, ["simulate", "--scenario", "wipe", "--render", str(SIZE), "--out", str(root / "meas"),
                              "--theta", "scale=0.3"])
    assert res.exit_code == 0, res.output
    return root, d


def _tiny_transporter() -> dict:
    return {"epochs": 1, "n_keypoints": 4, "image_size": 32, "channels": 8, "hidden": 8}


def test_training_set_labels_and_masks(rendered):
    _, d = rendered
    n = len(d["images"])
    assert d["images"].shape == (n, SIZE, SIZE, 3) and d["corners"].shape == (n, 4, 2)
    assert d["robot_masks"].any() and d["cloth_masks"].any()
    assert set(np.unique(d["sequence_ids"])) == {0, 1}
    # the grasped corner sits under the gripper: it is on or next to robot pixels in the first frame
    uv, _ = scenario_camera(load_scenario("wipe"), SIZE).project(np.array([[0.0, 0.0, 0.0]]))
    assert np.min(np.linalg.norm(d["corners"][0] - uv[0], axis=1)) < 2.0


def test_fit_on_rendered_frames_with_heatmap_then_resume(rendered, tmp_path):
    root, _ = rendered
    args = ["fit", "--observed", str(root / "meas" / "frames"), "--scenario", "wipe", "--observer", "heatmap",
            "--extractor", str(root / "hm.pt"), "--image-size", str(SIZE), "--out", str(tmp_path / "run"),
            "--rounds", "1", "--sims-per-round", "10", "--n-eval", "4", "--workers", "1",
            "--estimator-opt", "max_epochs=40"]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    assert rep["metric"] == "mask_chamfer_px" and rep["chamfer_prior_m"] is None
    assert 0 < rep["mask_chamfer_prior_px"] < SIZE and 0 < rep["mask_chamfer_posterior_px"] < SIZE
    assert rep["truth"]["scale"] == pytest.approx(0.3)  # truth.json written by simulate --render
    assert (tmp_path / "run" / "frames.png").exists() and (tmp_path / "run" / "chamfer_rounds.png").exists()
    import zarr
    obs = zarr.open_group(str(tmp_path / "run" / "run.zarr" / "observed"), mode="r")
    assert obs["x"].shape == (31, 1 + 4, 3) and obs["masks"].shape == (31, SIZE, SIZE)
    # resume: nothing is simulated again
    res2 = runner.invoke(app, args)
    assert res2.exit_code == 0 and "resuming" in res2.output
    rep2 = json.loads((tmp_path / "run" / "report.json").read_text())
    assert rep2["mask_chamfer_prior_px"] == rep["mask_chamfer_prior_px"]
    # the 3-D diagnostics say clearly that they need a point-cloud fit
    from softsbi.workflows.fit.runs import load_run
    with pytest.raises(SoftsbiError, match="image fit"):
        load_run(tmp_path / "run")


def test_fit_with_transporter_observer_python_api(rendered, tmp_path):
    from softsbi.scenarios.builtin import make_scenario
    from softsbi.workflows.fit.run import FitConfig, run_fit
    from softsbi.workflows.measurement import load_image_recording
    root, _ = rendered
    meas = load_image_recording(root / "meas" / "frames", scenario=make_scenario("wipe"), size=SIZE)
    cfg = FitConfig(observer="transporter", observer_options={"extractor": str(root / "tp.pt"), "size": SIZE},
                    rounds=1, sims_per_round=10, n_eval=3, workers=1, estimator_options={"max_epochs": 40})
    res = run_fit(tmp_path / "tp", meas, cfg, make_plots=False)
    assert res.report.metric == "mask_chamfer_px"
    x = res.store.round_data(0)["x"]
    ok = res.store.round_data(0)["status"] == 0
    assert ok.sum() >= 8 and np.all(np.isfinite(x[ok]))
    # transporter keypoints are normalised image coordinates (z = 0) behind the gripper row
    assert np.all(x[ok][:, :, 1:, 2] == 0) and np.all((x[ok][:, :, 1:, :2] > -0.5) & (x[ok][:, :, 1:, :2] < 1.5))


def test_image_fit_bad_input(rendered, tmp_path):
    root, _ = rendered
    frames = str(root / "meas" / "frames")
    res = runner.invoke(app, ["fit", "--observed", frames, "--scenario", "wipe", "--observer", "heatmap",
                              "--out", str(tmp_path / "a")])
    assert res.exit_code == 2 and "--extractor" in res.output
    res = runner.invoke(app, ["fit", "--observed", frames, "--scenario", "wipe", "--out", str(tmp_path / "b")])
    assert res.exit_code == 2 and "image" in res.output
    res = runner.invoke(app, ["fit", "--observed", frames, "--scenario", "fling", "--observer", "heatmap",
                              "--extractor", str(root / "hm.pt"), "--image-size", str(SIZE), "--out", str(tmp_path / "c")])
    assert res.exit_code == 2 and "frames" in res.output  # 31 wipe frames are not a 36-frame fling
    res = runner.invoke(app, ["fit", "--observed", frames, "--scenario", "wipe", "--observer", "heatmap",
                              "--extractor", str(tmp_path / "missing.pt"), "--out", str(tmp_path / "d")])
    assert res.exit_code == 2 and "missing.pt" in res.output
    assert not (tmp_path / "a").exists() or not any((tmp_path / "a").iterdir())


# ---------------------------------------------------------------------------- train-extractor
def test_train_extractor_from_an_annotated_folder(tmp_path):
    """`--data`: contiguous-block split, training, test error on held-out frames, checkpoint + summary."""
    import cv2
    rng = np.random.default_rng(0)
    (tmp_path / "d" / "images").mkdir(parents=True)
    (tmp_path / "d" / "keypoints").mkdir()
    for i in range(20):
        img = np.full((64, 64, 3), (200, 100, 100), np.uint8)
        kp = rng.integers(8, 56, (2, 2))
        for (x, y) in kp:
            cv2.circle(img, (int(x), int(y)), 3, (20, 200, 20), -1)
        cv2.imwrite(str(tmp_path / "d" / "images" / f"{i:05d}.png"), img[..., ::-1])
        np.save(tmp_path / "d" / "keypoints" / f"{i:05d}.npy", kp)
    out = tmp_path / "hm.pt"
    res = runner.invoke(app, ["train-extractor", "heatmap", "--data", str(tmp_path / "d"), "--out", str(out),
                              "--opt", "input_size=32,layers=[1,1,1,1],width=4,epochs=2,augment=false"])
    assert res.exit_code == 0, res.output
    assert "trained heatmap: 2 epochs, " in res.output  # the extractor's promised training info (epochs, seconds)
    summary = json.loads(out.with_suffix(".json").read_text())
    assert summary["test"]["n_frames"] >= 2 and np.isfinite(summary["test"]["hungarian_mean_px"])
    from softsbi.perception.keypoints.heatmap import HeatmapExtractor
    assert HeatmapExtractor.load(out).n_keypoints == 2
    # a keypoint file that does not match its image
    np.save(tmp_path / "d" / "keypoints" / "00003.npy", np.zeros((3, 2)))
    res = runner.invoke(app, ["train-extractor", "heatmap", "--data", str(tmp_path / "d"), "--out", str(out)])
    assert res.exit_code == 2 and "00003" in res.output


def test_train_extractor_on_rendered_rollouts_and_bad_choices(tmp_path):
    out = tmp_path / "tp.pt"
    res = runner.invoke(app, ["train-extractor", "transporter", "--simulate", "wipe", "--rollouts", "2",
                              "--image-size", "32", "--out", str(out),
                              "--opt", "image_size=32,epochs=1,n_keypoints=3,channels=8,hidden=8"])
    assert res.exit_code == 0, res.output
    assert json.loads(out.with_suffix(".json").read_text())["frames"] == 62
    from softsbi.perception.keypoints.transporter import TransporterExtractor
    assert TransporterExtractor.load(out).n_keypoints == 3
    res = runner.invoke(app, ["train-extractor", "heatmap", "--out", str(tmp_path / "x.pt")])
    assert res.exit_code == 2 and "--data" in res.output and "--simulate" in res.output  # the two flags
    res = runner.invoke(app, ["train-extractor", "heatmapp", "--simulate", "wipe", "--out", str(tmp_path / "x.pt")])
    assert res.exit_code == 2 and "'heatmap'" in res.output  # the name meant
    res = runner.invoke(app, ["train-extractor", "heatmap", "--simulate", "wipe", "--out", str(tmp_path / "x.pt"),
                              "--opt", "input_sise=32"])
    assert res.exit_code == 2 and "input_size" in res.output
