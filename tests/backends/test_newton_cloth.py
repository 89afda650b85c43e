"""Tests of the newton-cloth backend (Newton's VBD cloth on Warp).

The tests that simulate need the optional Newton package (``pip install "softsbi[newton]"``) and skip
without it; the first simulation on a machine compiles Warp kernels (minutes on two cores, cached in
Warp's kernel cache afterwards).
"""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from softsbi.backends.newton_cloth import INSTALL_HINT, NewtonCloth, bend_edge_stiffness, membrane_lame
from softsbi.core.errors import DependencyMissing, ParameterError
from softsbi.scenarios.builtin import make_scenario

pytestmark = pytest.mark.integration

THETA = {"bend": 1e-4, "stretch": 100.0, "friction": 0.5, "scale": 0.25, "mass": 0.2}


@pytest.fixture(scope="module")
def newton():
    return pytest.importorskip("newton", reason='newton-cloth needs Newton: pip install "softsbi[newton]"')


# -- without Newton -------------------------------------------------------------------------------
def test_importing_the_backend_does_not_import_newton():
    code = ("import sys, softsbi.backends.newton_cloth as m; from softsbi.plugins import registry; "
            "registry(); print('newton' in sys.modules, 'warp' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env=dict(os.environ, SOFTSBI_PLUGINS="softsbi.backends.newton_cloth"))
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["False", "False"]


def test_missing_newton_is_one_line_naming_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "newton", None)  # import newton -> ImportError
    monkeypatch.setitem(sys.modules, "warp", None)
    with pytest.raises(DependencyMissing, match='pip install "softsbi\\[newton\\]"') as ei:
        NewtonCloth().simulate(make_scenario("lift"), THETA)
    assert "\n" not in str(ei.value) and INSTALL_HINT in str(ei.value)


def test_a_fit_without_newton_is_refused_before_its_run_directory_is_made(monkeypatch, tmp_path):
    """Not a begun run.zarr that would refuse the next fit there with another backend."""
    from typer.testing import CliRunner

    from softsbi.cli import app
    from toy_helpers import DATA
    monkeypatch.setitem(sys.modules, "newton", None)
    monkeypatch.setitem(sys.modules, "warp", None)
    out = tmp_path / "run"
    res = CliRunner().invoke(app, ["fit", "--observed", str(DATA / "diffcloud_lift" / "lift_tan"), "--backend",
                                   "newton-cloth", "--rounds", "1", "--sims-per-round", "10", "--out", str(out)])
    assert res.exit_code == 2 and INSTALL_HINT in res.output and "Traceback" not in res.output
    assert not out.exists()


def test_parameter_mapping_has_one_physical_meaning():
    mu, lam = membrane_lame(100.0, 0.3)
    # plane-stress Young's modulus of the 2-D Lame pair is the stretch stiffness E t
    assert 4 * mu * (lam + mu) / (lam + 2 * mu) == pytest.approx(100.0)
    assert bend_edge_stiffness(2e-4, 0.025) == pytest.approx(8e-3)
    with pytest.raises(ParameterError):
        membrane_lame(-1.0, 0.3)
    with pytest.raises(ParameterError):
        bend_edge_stiffness(0.0, 0.025)


def test_shared_parameter_space_and_unsupported_scenarios_refused():
    sim = NewtonCloth()
    assert sim.param_space(make_scenario("lift")).names[:5] == ["bend", "stretch", "friction", "scale", "mass"]
    with pytest.raises(ValueError, match="newton-cloth cannot run scenario 'winding'.*rope"):
        sim.param_space(make_scenario("winding"))


def test_plugins_lists_newton_cloth_with_the_force_field_effects():
    out = subprocess.run([sys.executable, "-m", "softsbi.cli", "plugins"], capture_output=True, text=True, timeout=300,
                         env=dict(os.environ, SOFTSBI_PLUGINS="softsbi.backends.newton_cloth", COLUMNS="400"))
    assert out.returncode == 0, out.stderr
    rows = {line.split("|")[1].strip(): line for line in out.stdout.splitlines() if line.startswith("|")}
    assert "newton-cloth" in rows
    from softsbi.core.interfaces import FORCE, MODEL_EDIT
    from softsbi.plugins import registry
    # every effect that acts on newton-cloth through the force-field door (and needs no model edit) is applied
    doors = {n: set(e().doors("newton-cloth")) for n, e in registry().tables["effect"].items()}
    force_effects = [n for n, d in doors.items() if FORCE in d and MODEL_EDIT not in d]
    assert {"wind", "air-drag", "extra-damping", "table-slope"} <= set(force_effects)
    for name in force_effects:
        assert "newton-cloth" in rows[name].split("|")[3], name


# -- with Newton ----------------------------------------------------------------------------------
def test_lift_rises_with_the_handle_and_stays_above_the_table(newton):
    sc = make_scenario("lift")
    ro = NewtonCloth().simulate(sc, THETA)
    assert ro.ok, ro.reason
    v = ro.vertices
    assert v.shape == (len(sc.times), 81, 3)
    assert np.allclose(v[:, 0], ro.gripper, atol=1e-5)  # the grasped corner follows the handle
    assert v[..., 2].min() > sc.table_z  # never through the table (radius 3 mm)
    rise = v[-1, :, 2].mean() - v[0, :, 2].mean()
    assert rise > 0.05 and v[-1, :, 2].max() > v[0, :, 2].max() + 0.2  # the cloth is lifted, hanging below the grip
    assert ro.info["batch"] == 1 and ro.info["backend"] == "newton-cloth"


def test_a_batch_of_three_equals_three_single_runs(newton):
    sc = make_scenario("lift")
    sim = NewtonCloth(grid=5, timestep=0.008)
    space = sim.full_space(sc)
    thetas = [dict(THETA), dict(THETA, bend=5e-4, friction=1.0), dict(THETA, scale=0.3, mass=0.3, stretch=500.0)]
    batch = sim.simulate_batch(sc, np.array([[th[n] for n in space.names] for th in thetas]))
    assert [ro.info["batch"] for ro in batch] == [3, 3, 3]
    for th, ro in zip(thetas, batch):
        one = sim.simulate(sc, th)
        assert one.ok and ro.ok, (one.reason, ro.reason)
        assert np.abs(one.vertices - ro.vertices).max() < 1e-4  # float32 worlds stepped together
    assert np.abs(batch[0].vertices - batch[1].vertices).max() > 1e-3  # the worlds differ
    with pytest.raises(ParameterError, match="columns"):
        sim.simulate_batch(sc, np.zeros((2, 3)))
    # one seed per rollout: a sensor effect's noise in rollout b is the single rollout's at seeds[b]
    noisy = [dict(th, noise_std=0.005) for th in thetas[:2]]
    pair = sim.simulate_batch(sc, noisy, ["point-noise"], seed=[5, 9])
    for th, s, ro in zip(noisy, (5, 9), pair):
        one = sim.simulate(sc, th, ["point-noise"], seed=s)
        assert np.abs(one.vertices - ro.vertices).max() < 1e-4
    with pytest.raises(ParameterError, match="1 seeds for 2"):
        sim.simulate_batch(sc, noisy, ["point-noise"], seed=[5])


@pytest.mark.parametrize("name", ["wipe", "fling"])
def test_wipe_and_fling_run(newton, name):
    sc = make_scenario(name)
    ro = NewtonCloth(grid=5, timestep=0.008).simulate(sc, THETA)
    assert ro.ok, ro.reason
    assert np.isfinite(ro.vertices).all() and ro.vertices[..., 2].min() > sc.table_z - 0.005


def test_wind_acts_through_particle_forces(newton):
    sc = make_scenario("lift")
    sim = NewtonCloth(grid=5, timestep=0.008)
    calm = sim.simulate(sc, dict(THETA, wind_x=0.0, wind_y=0.0), effects=["wind"])
    windy = sim.simulate(sc, dict(THETA, wind_x=2.0, wind_y=0.0), effects=["wind"])
    assert calm.ok and windy.ok
    shift = windy.vertices[-1, :, 0].mean() - calm.vertices[-1, :, 0].mean()
    assert shift > 0.005, shift  # blown downwind (+x)
