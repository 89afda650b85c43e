"""Bad scenario files: one line naming the file, the field and the fix."""
from pathlib import Path

import numpy as np
import pytest
import yaml

import softsbi
from softsbi.core.errors import DataError
from softsbi.scenarios import load_scenario


def _grid_obj(path: Path, n: int = 3, extra_face: bool = False) -> Path:
    g = np.linspace(0.0, 0.3, n)
    v = [(x, y, 0.0) for x in g for y in g]
    f = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
            f += [(a, b, c), (a, c, d)]
    if extra_face:  # a fin: a third triangle on edge 0-4 (shared by two grid triangles already)
        v.append((0.1, 0.1, 0.2))
        f.append((0, 4, len(v) - 1))
    path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in v) + "".join(f"f {a + 1} {b + 1} {c + 1}\n"
                                                                          for a, b, c in f))
    return path


def _spec(tmp_path: Path, **change) -> Path:
    _grid_obj(tmp_path / "sheet.obj")
    spec = {"format": "softsbi-scenario/1", "name": "pull",
            "object": {"kind": "cloth", "mesh": {"file": "sheet.obj"}},
            "handles": [{"name": "grip", "grasp": {"vertex": 8},
                         "path": {"keyframes": [{"t": 0.0, "p": [0.3, 0.3, 0.0]}, {"t": 0.5, "p": [0.4, 0.3, 0.1]}]}},
                        {"name": "held", "grasp": {"vertex": 0}, "pinned": True}],
            "frames": {"count": 11, "dt": 0.05}}
    for k, v in change.items():
        spec[k] = v
    p = tmp_path / "pull.yaml"
    p.write_text(yaml.safe_dump(spec))
    return p


def _one_line(exc) -> str:
    s = str(exc.value)
    assert "\n" not in s
    return s


def test_a_valid_mesh_file_builds_and_runs(tmp_path):
    sc = load_scenario(_spec(tmp_path))
    assert sc.object["mesh"]["pivot"] == 8 and [h.pinned for h in sc.handles] == [False, True]
    ro = softsbi.simulate(sc, backend="mujoco-flex")
    assert ro.ok and ro.vertices.shape == (11, 9, 3)
    np.testing.assert_allclose(ro.vertices[-1, 0], ro.vertices[0, 0], atol=2e-3)  # the pinned vertex stays


def test_unknown_field(tmp_path):
    p = _spec(tmp_path, object={"kind": "cloth", "mesh": {"file": "sheet.obj"}, "colour": "red"})
    with pytest.raises(DataError) as err:
        load_scenario(p)
    msg = _one_line(err)
    assert msg.startswith(f"{p}: ") and "'object.colour'" in msg  # the file and the field


def test_wrong_type(tmp_path):
    p = _spec(tmp_path, frames={"count": "eleven", "dt": 0.05})
    with pytest.raises(DataError) as err:
        load_scenario(p)
    msg = _one_line(err)
    assert msg.startswith(f"{p}: field 'frames.count'") and "'eleven'" in msg  # the file, the field, the value


def test_handle_vertex_out_of_range(tmp_path):
    p = _spec(tmp_path)
    spec = yaml.safe_load(p.read_text())
    spec["handles"][1]["grasp"] = {"vertex": 9}
    p.write_text(yaml.safe_dump(spec))
    with pytest.raises(DataError) as err:
        load_scenario(p)
    msg = _one_line(err)
    assert msg.startswith(f"{p}: field 'handles[1].grasp.vertex'") and "9" in msg and "(0..8)" in msg  # the range


def test_path_length_disagrees_with_frames(tmp_path):
    p = _spec(tmp_path)
    np.save(tmp_path / "path.npy", np.zeros((7, 3)))
    spec = yaml.safe_load(p.read_text())
    spec["handles"][0]["path"] = {"file": "path.npy"}
    p.write_text(yaml.safe_dump(spec))
    with pytest.raises(DataError) as err:
        load_scenario(p)
    msg = _one_line(err)
    assert msg.startswith(f"{p}: field 'handles[0].path.file': ")
    assert "7" in msg and "11" in msg and "frames.count" in msg  # the rows, the frames and the field to change


def test_non_manifold_mesh(tmp_path):
    p = _spec(tmp_path)
    _grid_obj(tmp_path / "sheet.obj", extra_face=True)
    with pytest.raises(DataError) as err:
        load_scenario(p)
    msg = _one_line(err)
    assert msg.startswith(f"{p}: field 'object.mesh.file': ") and str(tmp_path / "sheet.obj") in msg
    assert "0-4" in msg  # the edge


def test_unknown_frame_and_format(tmp_path):
    p = _spec(tmp_path)
    spec = yaml.safe_load(p.read_text())
    spec["handles"][0]["path"]["frame"] = "robot"
    p.write_text(yaml.safe_dump(spec))
    with pytest.raises(DataError, match=r"field 'handles\[0\]\.path\.frame': unknown frame 'robot'; use 'scenario' "
                                        r"or one of the names under 'transforms'"):
        load_scenario(p)
    spec["format"] = "softsbi-scenario/9"
    p.write_text(yaml.safe_dump(spec))
    with pytest.raises(DataError, match=r"field 'format' is 'softsbi-scenario/9'; this softsbi reads "
                                        r"softsbi-scenario/1"):
        load_scenario(p)


def test_a_folder_a_nan_vertex_an_absurd_gravity_or_frame_count_is_named_as_what_it_is(tmp_path):
    """A folder given as the mesh read "does not exist"; a NaN vertex was reported as a bad 'direction'; gravity
    1e9 or NaN simulated a failure and exited 0; count: 1000000 ran with no warning."""
    (tmp_path / "meshdir").mkdir()
    cases = [({"object": {"kind": "cloth", "mesh": {"file": "meshdir"}}}, "object.mesh.file",
              "meshdir is a folder; give a .obj file"),
             ({"world": {"gravity": [0, 0, -1e9]}}, "world", "is 1e+09 m/s^2, more than 100; give it in m/s^2"),
             ({"world": {"gravity": [0, 0, float("nan")]}}, "world.gravity[2]", "Input should be a finite number"),
             ({"frames": {"count": 1000000, "dt": 0.05}}, "frames.count", "less than or equal to 10000")]
    for change, field, message in cases:
        with pytest.raises(DataError) as err:
            load_scenario(_spec(tmp_path, **change))
        line = str(err.value)
        assert f"field '{field}" in line and message in line and "\n" not in line, (change, line)
    spec = _spec(tmp_path)
    obj = tmp_path / "sheet.obj"
    obj.write_text(obj.read_text().replace("v 0.0 0.0 0.0", "v nan 0.0 0.0", 1))
    with pytest.raises(DataError, match=r"sheet\.obj has a NaN or infinite coordinate \(vertex 0\); fix the \.obj"):
        load_scenario(spec)


def test_a_keyframe_far_beyond_a_task_and_two_positions_at_one_time_are_refused(tmp_path):
    """A keyframe at 1e9 m was accepted (the simulation then failed while `softsbi simulate` exited 0), and two
    keyframes at one time with different positions were accepted; each is now one line naming the field."""
    from softsbi.scenarios.spec import MAX_POSITION
    grip = {"name": "grip", "grasp": {"vertex": 8}}
    held = {"name": "held", "grasp": {"vertex": 0}, "pinned": True}
    far = _spec(tmp_path, handles=[dict(grip, path={"keyframes": [{"t": 0.0, "p": [0.3, 0.3, 0.0]},
                                                                  {"t": 0.5, "p": [1e9, 0.3, 0.1]}]}), held])
    with pytest.raises(DataError) as err:
        load_scenario(far)
    msg = _one_line(err)
    assert "field 'handles[0].path'" in msg and "1e+09" in msg and "t = 0.5" in msg
    assert f"{MAX_POSITION:g} m" in msg  # the limit
    twice = _spec(tmp_path, handles=[dict(grip, path={"keyframes": [{"t": 0.0, "p": [0.3, 0.3, 0.0]},
                                                                    {"t": 0.25, "p": [0.4, 0.3, 0.1]},
                                                                    {"t": 0.25, "p": [0.2, 0.3, 0.1]}]}), held])
    with pytest.raises(DataError) as err:
        load_scenario(twice)
    msg = _one_line(err)
    assert "field 'handles[0].path'" in msg and "t = 0.25" in msg
    # the same position twice (a pause written out) stays valid
    same = _spec(tmp_path, handles=[dict(grip, path={"keyframes": [{"t": 0.0, "p": [0.3, 0.3, 0.0]},
                                                                   {"t": 0.25, "p": [0.4, 0.3, 0.1]},
                                                                   {"t": 0.25, "p": [0.4, 0.3, 0.1]}]}), held])
    assert load_scenario(same).n_frames == 11
