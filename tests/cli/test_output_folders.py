"""Output folders are checked before any work: `simulate` never mixes two simulations in one folder, an
`--out` that is a file is one line for every command that writes one."""
import json

import pytest
from typer.testing import CliRunner

from softsbi.cli import app

pytestmark = pytest.mark.integration

pytest.importorskip("softsbi_toy.plugin", reason="install tests/plugins/softsbi_toy (pip install -e)")

runner = CliRunner()
SIM = ["simulate", "--backend", "toy-gauss", "--scenario", "lift"]


def _one_line(res, code=2):
    assert res.exit_code == code, res.output
    assert "Traceback" not in res.output and len(res.output.strip().splitlines()) == 1, res.output
    return " ".join(res.output.split())


def test_simulate_refuses_a_non_empty_out_and_overwrite_replaces_its_contents(tmp_path):
    out = tmp_path / "meas"
    assert runner.invoke(app, [*SIM, "--out", str(out)]).exit_code == 0
    (out / "frames").mkdir()
    (out / "frames" / "000.png").write_bytes(b"an earlier simulation's frame")
    line = _one_line(runner.invoke(app, [*SIM, "--theta", "a=0.5", "--out", str(out)]))
    assert f"--out '{out}'" in line and "--overwrite" in line
    assert (out / "frames" / "000.png").exists()  # refused: nothing touched
    res = runner.invoke(app, [*SIM, "--theta", "a=0.5", "--out", str(out), "--overwrite"])
    assert res.exit_code == 0, res.output
    assert not (out / "frames").exists()  # the old simulation's files are gone, the new one is whole
    assert {p.name for p in out.iterdir()} == {"rollout.zarr", "preview.png", "recording.yaml", "clouds"}
    assert "a: 0.5" in (out / "recording.yaml").read_text()
    assert [p.name for p in tmp_path.iterdir()] == ["meas"]  # no temporary folder left beside it


def test_an_out_that_is_a_file_or_a_bad_render_cap_is_refused_before_simulating(tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("x")
    src = tmp_path / "src"  # a DiffCloud folder by its layout (the destination is checked before its contents)
    src.mkdir()
    (src / "lift_real2sim.yaml").write_text("z_rotation: 0\n")
    (src / "000.npy").write_bytes(b"")
    line = _one_line(runner.invoke(app, [*SIM, "--out", str(afile)]))
    assert f"--out '{afile}'" in line
    line = _one_line(runner.invoke(app, [*SIM, "--out", str(afile / "sub")]))
    assert f"'{afile / 'sub'}'" in line and f"'{afile}'" in line  # the folder asked for and the file in its way
    line = _one_line(runner.invoke(app, ["import", "diffcloud", str(src), str(afile)]))
    assert f"'{afile}'" in line
    res = runner.invoke(app, [*SIM, "--render", "16", "--render-memory-gb", "-1", "--out", str(tmp_path / "r")])
    assert res.exit_code == 2 and "Traceback" not in res.output, res.output  # refused when the flags are parsed
    msg = " ".join(res.output.replace("│", " ").split())
    assert "'--render-memory-gb'" in msg and "> 0" in msg and "-1" in msg  # the flag, its bound and the value
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "src"]


def _run_dir(path):
    """A folder that holds a run (what tells a run directory: its ``run.zarr``)."""
    (path / "run.zarr").mkdir(parents=True)
    return path


def test_an_out_that_would_mix_two_runs_is_refused_before_any_work(tmp_path):
    a, b = _run_dir(tmp_path / "a"), _run_dir(tmp_path / "b")
    (b / "diagnosis.json").write_text('{"run": "b"}')
    refit = _run_dir(a / "refit-wind")
    for out in (b, refit, refit / "sub"):  # another run, a refit folder of the run, a folder inside a refit
        line = _one_line(runner.invoke(app, ["diagnose", str(a), "--out", str(out)]))
        assert f"--out '{out}'" in line and "another fit" in line and "diagnose" in line
    assert (b / "diagnosis.json").read_text() == '{"run": "b"}' and not (b / "refit-wind").exists()
    other = tmp_path / "d"  # a folder of its own that holds the diagnosis of another run
    other.mkdir()
    (other / "diagnosis.json").write_text(json.dumps({"run": str(b)}))
    line = _one_line(runner.invoke(app, ["diagnose", str(a), "--out", str(other)]))
    assert "diagnosis of another run" in line and str(b) in line
    rec = tmp_path / "rec"
    rec.mkdir()
    line = _one_line(runner.invoke(app, ["fit", "--observed", str(rec), "--out", str(rec), "--backend", "toy-gauss"]))
    assert f"--out '{rec}' is the recording folder" in line
    assert list(rec.iterdir()) == []
    line = _one_line(runner.invoke(app, ["demo", "--quick", "--backend", "toy-gauss", "--out", str(a)]))
    assert f"--out '{a}' is the run directory of another fit" in line and not (a / "nominal").exists()


def test_the_guard_lets_a_run_keep_its_own_folders(tmp_path):
    from softsbi.workflows.lock import check_out_apart
    a = _run_dir(tmp_path / "a")
    refit = _run_dir(a / "refit-wind")
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "diagnosis.json").write_text(json.dumps({"run": str(a)}))
    for out, run in ((a, a), (tmp_path / "d", a), (tmp_path / "new", a), (refit, refit),
                     (refit / "d2", refit)):
        # the run itself, its own diagnosis, a new folder, a refit diagnosed into itself or a folder of its own
        assert check_out_apart(out, "diagnose", run=run) == out
    assert check_out_apart(tmp_path / "demo", "demo") == tmp_path / "demo"
