"""From the CLI: a simulated measurement with a hidden effect, written as a recording, then fitted."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

pytestmark = pytest.mark.integration

REPO = Path(__file__).resolve().parents[2]


def _cli(*args, cwd):
    return subprocess.run([sys.executable, "-m", "softsbi.cli", *args], capture_output=True, text=True, cwd=cwd)


def test_simulate_scenario_file_with_wind_then_fit_the_recording(tmp_path):
    scen = tmp_path / "my_wipe.yaml"  # a user's own scenario file: the wipe, 13 frames
    spec = yaml.safe_load((REPO / "softsbi" / "scenarios" / "files" / "wipe.yaml").read_text())
    spec["name"] = "my-wipe"
    spec["frames"] = {"count": 13, "duration": 1.5}
    scen.write_text(yaml.safe_dump(spec))
    meas = tmp_path / "meas"
    res = _cli("simulate", "--scenario", str(scen), "--effect", "wind", "--theta", "wind_x=1.5", "--out", str(meas),
               "--json", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["status"] == 0 and doc["recording"] == str(meas)
    assert (meas / "rollout.zarr").is_dir() and (meas / "preview.png").is_file()
    meta = yaml.safe_load((meas / "recording.yaml").read_text())
    assert meta["effects"] == ["wind"] and meta["truth"]["wind_x"] == 1.5 and len(meta["times"]) == 13
    assert len(list((meas / "clouds").glob("*.npy"))) == 13
    run = tmp_path / "run"
    res = _cli("fit", "--observed", str(meas), "--out", str(run), "--rounds", "1", "--sims-per-round", "12",
               "--n-eval", "3", "--workers", "1", "--json", cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-2000:]
    rep = json.loads(res.stdout)
    # the nominal fit of a hidden-wind measurement: its posterior is over the nominal parameters only,
    # and the run knows the hidden values of the recording
    assert set(rep["posterior_mean"]) == {"bend", "stretch", "friction", "scale", "mass"}
    assert np.isfinite(rep["chamfer_posterior_m"]) and rep["chamfer_posterior_m"] > 0


def test_bad_scenario_file_from_the_cli_is_one_line(tmp_path):
    scen = tmp_path / "bad.yaml"
    spec = yaml.safe_load((REPO / "softsbi" / "scenarios" / "files" / "wipe.yaml").read_text())
    spec["handles"][0]["grasp"] = {"corner": "zero"}
    scen.write_text(yaml.safe_dump(spec))
    res = _cli("simulate", "--scenario", str(scen), "--out", str(tmp_path / "o"), cwd=tmp_path)
    assert res.returncode == 2
    err = [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]
    assert len(err) == 1 and "bad.yaml" in err[0] and "'handles[0].grasp.corner'" in err[0]  # the file, the field
    assert not (tmp_path / "o").exists()
