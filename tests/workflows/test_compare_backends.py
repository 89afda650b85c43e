"""Cross-simulator comparison (compare_backends and the `softsbi compare-backends` command)."""
from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from softsbi.workflows.compare_backends import compare_backends
from softsbi.scenarios.builtin import make_scenario
from softsbi.cli import app
from softsbi.core.errors import ParameterError, PluginNotFound

pytestmark = pytest.mark.integration

BACKENDS = ("mujoco-flex", "pybullet-massspring")
SMALL = ["--backends", ",".join(BACKENDS), "--backend-opt", "mujoco-flex:grid=5",
         "--backend-opt", "pybullet-massspring:grid=5"]


def test_cli_writes_json_and_png(tmp_path):
    out = tmp_path / "cmp"
    res = CliRunner().invoke(app, ["compare-backends", "--scenario", "lift", "--theta", "friction=0.5",
                                   "--theta", "scale=0.25", "--out", str(out)] + SMALL)
    assert res.exit_code == 0, res.output
    rep = json.loads((out / "compare.json").read_text())
    assert (out / "compare.png").stat().st_size > 1000
    ch = np.asarray(rep["chamfer_m"]["mujoco-flex|pybullet-massspring"])
    assert ch.shape == (25,) and np.all(np.isfinite(ch)) and np.all(ch > 0)
    for b in ("mujoco-flex", "pybullet-massspring"):
        assert rep["backends"][b]["status"] == "ok"
        assert rep["backends"][b]["theta"]["friction"] == 0.5
        assert rep["backends"][b]["theta_source"]["scale"] == "given"


def test_cli_bad_input(tmp_path):
    r = CliRunner().invoke(app, ["compare-backends", "--scenario", "wip", "--out", str(tmp_path)])
    assert r.exit_code == 2 and "'wip'" in r.output and "wipe" in r.output  # the name given and the one meant
    r = CliRunner().invoke(app, ["compare-backends", "--theta", "bendd=1", "--out", str(tmp_path)])
    assert r.exit_code == 2 and "'bendd'" in r.output and "bend" in r.output.replace("bendd", "")


def test_api_errors_and_unit_match():
    sc = make_scenario("lift")
    with pytest.raises(PluginNotFound, match="pybullet-massspring"):
        compare_backends(sc, {}, ("mujoco-flex", "pybullet-masspring"))
    with pytest.raises(ParameterError, match="outside its physical limits"):
        compare_backends(sc, {"friction": -0.1}, BACKENDS,
                         backend_options={"mujoco-flex": {"grid": 4}, "pybullet-massspring": {"grid": 4}})
    rep = compare_backends(sc, {"bend": 0.0}, BACKENDS, match="unit",
                           backend_options={"mujoco-flex": {"grid": 4}, "pybullet-massspring": {"grid": 4}})
    assert rep["backends"]["mujoco-flex"]["theta"]["bend"] == pytest.approx(1e-6)
    assert rep["backends"]["pybullet-massspring"]["theta"]["bend"] == pytest.approx(1e-6)  # same unit now


def test_default_is_the_shared_physical_midpoint():
    """Unset parameters sit at the shared prior midpoint: the same physical value on both engines."""
    from softsbi.backends.mujoco_flex import MujocoFlex
    from softsbi.backends.pybullet_massspring import PybulletMassSpring
    from softsbi.workflows.compare_backends import shared_space
    sc = make_scenario("lift")
    sh = shared_space([MujocoFlex().param_space(sc), PybulletMassSpring().param_space(sc)])
    assert sh.names == ["bend", "stretch", "friction", "scale", "mass"]
    assert (sh["stretch"].low, sh["stretch"].high) == (20.0, 200.0)  # intersection of 5-1000 and 20-200
    rep = compare_backends(sc, {"friction": 0.4}, BACKENDS,
                           backend_options={"mujoco-flex": {"grid": 4}, "pybullet-massspring": {"grid": 4}})
    mj, pb = (rep["backends"][b] for b in BACKENDS)
    assert mj["theta"] == pb["theta"]
    assert mj["theta"]["stretch"] == pytest.approx(np.sqrt(20.0 * 200.0))
    assert mj["theta_source"]["bend"] == "shared-midpoint" and mj["theta_source"]["friction"] == "given"
    assert rep["max_chamfer_m"]["mujoco-flex|pybullet-massspring"] >= rep["mean_chamfer_m"][
        "mujoco-flex|pybullet-massspring"] > 0
    # wind: the rope knobs are engine-only (pb_rope_*, mujoco's Young's modulus 'young') and sit at each
    # engine's midpoint; no parameter name means two things
    wind = compare_backends(make_scenario("winding"), {}, BACKENDS,
                            backend_options={"mujoco-flex": {"rope_nodes": 8}, "pybullet-massspring": {"rope_nodes": 8}})
    assert wind["shared_params"] == ["friction", "scale", "mass"]
    assert wind["backends"]["pybullet-massspring"]["theta_source"]["pb_rope_bend"] == "midpoint"
    assert wind["backends"]["mujoco-flex"]["theta_source"]["young"] == "midpoint"


def test_a_figure_that_is_a_folder_is_refused_before_simulating(tmp_path):
    (tmp_path / "compare.png").mkdir()
    r = CliRunner().invoke(app, ["compare-backends", "--scenario", "lift", "--out", str(tmp_path)] + SMALL)
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert f"'{tmp_path / 'compare.png'}' is a folder" in " ".join(r.output.split())
    assert not (tmp_path / "compare.json").exists()
