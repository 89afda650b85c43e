"""Recording directories: writer/reader round trip, the DiffCloud importer (lift and fold), bad input."""
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from softsbi.core.errors import DataError
from softsbi.data.recording import read_recording, write_recording
from softsbi.workflows.measurement import import_diffcloud, load_recording

REPO = Path(__file__).resolve().parents[2]
DATA = REPO.parent / "shared" / "data"
LIFT, FOLD = DATA / "diffcloud_lift", DATA / "diffcloud_fold"
FOLD_YAML = REPO / "examples" / "fold.yaml"
needs_data = pytest.mark.skipif(not (LIFT / "lift_tan").is_dir() or not (FOLD / "fold_tan").is_dir(),
                                reason="shared/data/diffcloud_{lift,fold} not present")


def _meta(n, **kw):
    m = {"scenario": {"name": "wipe"}, "times": list(np.linspace(0.0, 1.5, n)),
         "transform": {"matrix": np.eye(4).tolist()}}
    m.update(kw)
    return m


def test_round_trip_any_points_per_frame_and_transform(tmp_path):
    rng = np.random.default_rng(0)
    clouds = [rng.normal(size=(50 + 7 * i, 3)) for i in range(31)]  # P_t differs per frame
    shift = np.eye(4)
    shift[:3, 3] = [0.1, -0.2, 0.3]
    write_recording(tmp_path / "r", _meta(31, transform={"matrix": shift.tolist()}, truth={"bend": 1e-4}),
                    clouds)
    data = read_recording(tmp_path / "r")
    assert [len(c) for c in data.clouds] == [len(c) for c in clouds]
    np.testing.assert_allclose(data.clouds[3], clouds[3] + [0.1, -0.2, 0.3])
    assert data.meta.truth == {"bend": 1e-4} and len(data.times) == 31
    rec = load_recording(tmp_path / "r", n_points=16, n_dense=100)
    assert rec.scenario.name == "wipe" and rec.x.shape == (31, 17, 3) and rec.dense.shape == (31, 100, 3)


def test_times_disagreeing_with_frames_writes_nothing(tmp_path):
    clouds = [np.zeros((5, 3))] * 31
    with pytest.raises(DataError, match=r"recording\.yaml: field 'times' has 30 entries for 31 clouds; give one "
                                        r"time per frame"):
        write_recording(tmp_path / "r", _meta(30), clouds)
    assert not (tmp_path / "r").exists() and not list(tmp_path.iterdir())


def test_missing_transform_and_unknown_field_are_one_line(tmp_path):
    write_recording(tmp_path / "r", _meta(31), [np.zeros((5, 3))] * 31)
    meta_file = tmp_path / "r" / "recording.yaml"
    meta = yaml.safe_load(meta_file.read_text())
    del meta["transform"]
    meta_file.write_text(yaml.safe_dump(meta))
    with pytest.raises(DataError, match=r"r/recording\.yaml: field 'transform' is missing; add it, the map of the "
                                        r"clouds into the scenario frame, e\.g\. transform: \{matrix: ") as err:
        read_recording(tmp_path / "r")
    assert "\n" not in str(err.value)
    meta["transform"] = {"matrix": np.eye(4).tolist()}
    meta["tiems"] = [0.0]
    meta_file.write_text(yaml.safe_dump(meta))
    with pytest.raises(DataError, match=r"recording\.yaml: unknown field 'tiems'; remove it"):
        read_recording(tmp_path / "r")


def test_a_hand_written_recording_yaml_may_name_its_scenario_in_one_word(tmp_path):
    """`scenario: wipe` (what the README's "scenario name, file or inline" suggests) was refused with a pydantic
    type error; a plain string is a name, or a file when it ends in .yaml."""
    write_recording(tmp_path / "r", _meta(31), [np.zeros((5, 3))] * 31)
    meta_file = tmp_path / "r" / "recording.yaml"
    meta = yaml.safe_load(meta_file.read_text())
    meta["scenario"] = "wipe"
    meta_file.write_text(yaml.safe_dump(meta))
    assert read_recording(tmp_path / "r").meta.scenario.name == "wipe"
    assert load_recording(tmp_path / "r", n_points=8, n_dense=50).scenario.name == "wipe"
    shutil.copy(FOLD_YAML, tmp_path / "r" / "task.yaml")
    meta["scenario"] = "task.yaml"
    meta_file.write_text(yaml.safe_dump(meta))
    assert read_recording(tmp_path / "r").meta.scenario.file == "task.yaml"
    del meta["times"]
    meta_file.write_text(yaml.safe_dump(meta))
    with pytest.raises(DataError, match=r"field 'times' is missing; add it, one time per frame in s, e\.g\. times: "):
        read_recording(tmp_path / "r")


def test_recording_times_vs_clouds_and_scenario(tmp_path):
    write_recording(tmp_path / "r", _meta(31), [np.zeros((5, 3))] * 31)
    meta_file = tmp_path / "r" / "recording.yaml"
    meta = yaml.safe_load(meta_file.read_text())
    meta["times"] = meta["times"][:20]
    meta_file.write_text(yaml.safe_dump(meta))
    with pytest.raises(DataError, match=r"field 'times' has 20 entries but clouds/ holds 31 frames"):
        read_recording(tmp_path / "r")
    # 20 frames of a 31-frame scenario: named, with the fix
    shutil.rmtree(tmp_path / "r")
    write_recording(tmp_path / "r", _meta(20), [np.zeros((5, 3))] * 20)
    with pytest.raises(DataError, match=r"has 20 frames but scenario 'wipe' has 31; make the scenario's frames"):
        load_recording(tmp_path / "r")


@needs_data
def test_import_diffcloud_lift_gives_the_same_recording(tmp_path):
    out = import_diffcloud(LIFT / "lift_tan", tmp_path / "lift_tan")
    assert out == [tmp_path / "lift_tan"]
    a, b = load_recording(LIFT / "lift_tan"), load_recording(tmp_path / "lift_tan")
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.dense, b.dense)
    np.testing.assert_array_equal(a.scenario.gripper, b.scenario.gripper)
    assert b.min_height == 0.01 and b.frames == "auto" and b.scenario.object["yaw_bounds"] == [-45.0, 45.0]
    meta = yaml.safe_load((tmp_path / "lift_tan" / "recording.yaml").read_text())
    # the robot frame maps into the shared lift task: the commanded end effector sits the grasp offset away from
    # the task's gripper (the grasped corner), the same on every frame
    robot = np.asarray(meta["frames_of_reference"]["robot"]["matrix"])
    traj = np.load(LIFT / "lift_traj.npy") @ robot[:3, :3].T + robot[:3, 3]
    apart = b.scenario.gripper - traj
    np.testing.assert_allclose(apart, np.broadcast_to(apart[0], apart.shape), atol=1e-9)
    assert np.linalg.norm(apart[0, :2]) > 0.05 and abs(apart[0, 2]) < 1e-9  # lift_tan: (5.7, 2.4) cm
    # the RealSense calibration beside the lift recordings comes along
    cal = read_recording(tmp_path / "lift_tan").extras["calibration"]
    assert set(cal["cameras"]) == {"overhead", "side"}
    np.testing.assert_allclose(cal["cameras"]["overhead"]["robot_from_camera"], np.load(LIFT / "calib_overhead" / "tcr.npy"))


@needs_data
def test_import_diffcloud_fold_folder(tmp_path):
    with pytest.raises(DataError, match=r"DiffCloud 'fold' recording: give its scenario file"):
        import_diffcloud(FOLD, tmp_path / "fold")
    assert not (tmp_path / "fold").exists()
    out = import_diffcloud(FOLD, tmp_path / "fold", scenario=FOLD_YAML)
    assert sorted(p.name for p in out) == sorted(d.name for d in FOLD.iterdir() if d.is_dir())
    rec = load_recording(tmp_path / "fold" / "fold_navy2", n_points=32)
    assert rec.scenario.name == "fold" and [h.name for h in rec.scenario.handles] == ["grip", "held"]
    # the recording's frame: simulator units x 0.35 m; the grasped corner (vertex 42) rises with the path
    assert rec.dense.shape == (25, 1000, 3)
    assert abs(rec.scenario.gripper[0, 1] - (-0.817829 * 0.35)) < 0.002
    with pytest.raises(DataError, match="exists and is not empty"):
        import_diffcloud(FOLD / "fold_tan", tmp_path / "fold" / "fold_tan", scenario=FOLD_YAML)


@needs_data
def test_the_recordings_robot_calibration_replaces_the_scenarios(tmp_path):
    import_diffcloud(FOLD / "fold_tan", tmp_path / "r", scenario=FOLD_YAML)
    base = load_recording(tmp_path / "r", n_points=8).scenario.gripper
    f = tmp_path / "r" / "recording.yaml"
    meta = yaml.safe_load(f.read_text())
    meta["frames_of_reference"]["robot"]["diffcloud"]["translation"][0] += 0.02  # robot base 2 cm further in x
    f.write_text(yaml.safe_dump(meta))
    moved = load_recording(tmp_path / "r", n_points=8).scenario.gripper
    # p_scenario = (p + c - t) @ Rz(90 deg): t_x + 2 cm moves every path point by (-0.02, 0, 0) @ Rz = (0, +0.02, 0)
    np.testing.assert_allclose(moved - base, np.tile([0.0, 0.02, 0.0], (25, 1)), atol=1e-12)


def test_rendered_simulation_is_an_image_recording(tmp_path):
    from softsbi.workflows.measurement import load_image_recording
    from softsbi.workflows.simulate import simulate_to_folder
    try:
        doc = simulate_to_folder(tmp_path / "m", scenario="wipe", render=24)
    except Exception as exc:
        if type(exc).__name__ == "RenderingUnavailable":
            pytest.skip(str(exc))
        raise
    assert doc["recording"] == str(tmp_path / "m") and len(list((tmp_path / "m" / "images").glob("*.png"))) == 31
    rec = load_image_recording(tmp_path / "m", scenario=None, size=24)
    assert rec.images.shape == (31, 24, 24, 3) and rec.scenario.name == "wipe"
    assert rec.truth == doc["theta"]


def test_a_missing_recording_yaml_a_shifted_frame_and_a_file_as_source_are_named(tmp_path):
    """A recording without recording.yaml was "holds no frames"; a frame shifted by 1e6 m was fitted ("Chamfer
    4041456 cm"); a file given as the DiffCloud source "does not exist"."""
    pytest.importorskip("softsbi_toy.plugin", reason="install tests/plugins/softsbi_toy (pip install -e)")
    from softsbi.workflows.measurement import import_diffcloud, load_recording
    from softsbi.workflows.simulate import simulate_to_folder
    rec = tmp_path / "rec"
    simulate_to_folder(rec, backend="toy-gauss")  # lift
    meta = (rec / "recording.yaml").read_bytes()
    (rec / "recording.yaml").unlink()
    with pytest.raises(DataError, match=r"holds clouds/ but no recording\.yaml, which says what they are"):
        load_recording(rec)
    (rec / "recording.yaml").write_bytes(meta)
    c = np.load(rec / "clouds" / "005.npy")
    np.save(rec / "clouds" / "005.npy", c + [1e6, 0, 0])
    with pytest.raises(DataError, match=r"frame 5's points lie 1e\+06 m from the gripper \(median\), more than 5 "
                                        r"times the object's extent .* check the recording's transform and that its "
                                        r"units are metres"):
        load_recording(rec)
    with pytest.raises(DataError, match=r"'.*005\.npy' is a file; give a DiffCloud recording folder"):
        import_diffcloud(rec / "clouds" / "005.npy", tmp_path / "dst")


def test_a_diffcloud_recording_imported_with_another_tasks_scenario_is_refused(tmp_path):
    """A lift imported with examples/fold.yaml was fitted silently as the wrong task: the scenario's gripper path
    is now compared with the path the recording's robot followed (<task>_traj.npy beside it)."""
    root = tmp_path / "diffcloud_lift"
    rec = root / "lift_x"
    rec.mkdir(parents=True)
    t = np.linspace(0, 1, 25)[:, None]
    np.save(root / "lift_traj.npy", [0.56, 0.15, 0.08] + t * [0.2, 0.0, 0.3])  # up and back (robot frame)
    (rec / "lift_real2sim.yaml").write_text("z_rotation: 90\ntranslation: [0.67, 0.15, 0.0]\nscale: 0.35\n"
                                            "compensation_factor: [0.0, 0.0, 0.0]\n")
    for i in range(25):
        np.save(rec / f"{i:03d}.npy", np.random.default_rng(i).normal(0, 0.05, (50, 3)))

    def scenario(path):
        f = tmp_path / "task.yaml"
        f.write_text(yaml.safe_dump({
            "format": "softsbi-scenario/1", "name": "task", "object": {"kind": "cloth", "size": 0.28},
            "handles": [{"name": "grip", "grasp": {"corner": 0}, "path": dict(path, frame="robot")}],
            "frames": {"count": 25, "dt": 0.04}}))
        return f
    across = scenario({"keyframes": [{"t": 0.0, "p": [0.84, 0.18, 0.10]}, {"t": 0.96, "p": [0.55, 0.18, 0.14]}]})
    with pytest.raises(DataError, match=r"is a DiffCloud lift recording, but the gripper of scenario 'task' .* does "
                                        r"not follow its robot's path \(lift_traj\.npy\): they part by up to 0\.\d+ m"):
        import_diffcloud(rec, tmp_path / "out", scenario=across)
    assert not (tmp_path / "out").exists()
    same = scenario({"file": str(root / "lift_traj.npy")})
    assert import_diffcloud(rec, tmp_path / "out", scenario=same) == [tmp_path / "out"]


def test_a_misnamed_frame_is_named_with_the_name_it_needs(tmp_path):
    """``5.npy`` among 000.npy ... gave "numbering ... (missing [])", naming neither the file nor the fix; the same
    naming rule holds for a recording's clouds/ and depth/, a DiffCloud folder and a folder of images."""
    from softsbi.data.frames import load_frames, save_frames
    from softsbi.perception.pointcloud import load_cloud_frames
    write_recording(tmp_path / "r", _meta(8), [np.zeros((5, 3))] * 8)
    clouds = tmp_path / "r" / "clouds"
    (clouds / "005.npy").rename(clouds / "5.npy")
    with pytest.raises(DataError, match=r"'.*clouds/5\.npy' is misnamed: frames are named by their index with three "
                                        r"digits or more \(000\.npy, 001\.npy, \.\.\.\); rename it to 005\.npy$"):
        read_recording(tmp_path / "r")
    shutil.copy(clouds / "5.npy", clouds / "005.npy")
    with pytest.raises(DataError, match=r"rename it to 005\.npy \(005\.npy is there too: remove one of them\)$"):
        read_recording(tmp_path / "r")
    (clouds / "5.npy").unlink()
    (clouds / "003.npy").unlink()
    with pytest.raises(DataError, match=r"numbering must run 000, 001, \.\.\. without gaps \(missing 003\)"):
        read_recording(tmp_path / "r")
    for i in (3, 11):
        np.save(tmp_path / f"{i}.npy", np.zeros((5, 3)))
    with pytest.raises(DataError, match=r"'.*3\.npy' is misnamed.*rename it to 003\.npy; so are 11\.npy$"):
        load_cloud_frames(tmp_path)
    save_frames(np.zeros((3, 4, 4, 3), np.uint8), tmp_path / "img")
    (tmp_path / "img" / "002.png").rename(tmp_path / "img" / "0002.png")
    with pytest.raises(DataError, match=r"'.*0002\.png' is misnamed.*rename it to 002\.png$"):
        load_frames(tmp_path / "img")


def test_frames_out_of_range_are_blamed_on_where_they_were_given(tmp_path):
    """recording.yaml's ``sensor: frames`` selecting a frame the recording lacks was blamed on a ``--frames`` flag
    the user never gave."""
    from dataclasses import replace

    from softsbi.core.errors import SoftsbiError
    from softsbi.workflows.fit.config import FitConfig
    write_recording(tmp_path / "r", _meta(8, sensor={"frames": [3, 40]}), [np.zeros((5, 3))] * 8)
    with pytest.raises(DataError) as err:
        read_recording(tmp_path / "r")
    assert str(err.value) == (f"{tmp_path / 'r' / 'recording.yaml'}: field 'sensor.frames' selects frame 40, but the "
                              f"recording has 8 frames (0 to 7); give frames within them, or all or auto")
    pytest.importorskip("softsbi_toy.plugin", reason="install tests/plugins/softsbi_toy (pip install -e)")
    from toy_helpers import toy_measurement
    rec = replace(toy_measurement(T=3), frames=[0, 9])  # a recording built in code
    with pytest.raises(SoftsbiError, match=r"^the recording's sensor\.frames 0,9 selects frame 9, but the recording "
                                           r"has 3 frames \(0 to 2\); give frames within them, or override them with "
                                           r"--frames$"):
        FitConfig(backend="toy-gauss").resolved(rec)
    with pytest.raises(SoftsbiError, match=r"^--frames 1,5 selects frame 5, .* e\.g\. --frames 1:3$"):
        FitConfig(backend="toy-gauss", frames=[1, 5]).resolved(rec)
