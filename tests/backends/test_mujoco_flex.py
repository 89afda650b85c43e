"""Tests of the mujoco-flex cloth lift backend."""
from __future__ import annotations

import itertools
import multiprocessing as mp
import pickle

import numpy as np
import pytest

from softsbi.backends.mujoco_flex import MujocoFlex, grid_faces, plate_mapping
from softsbi.scenarios.builtin import lift_scenario
from softsbi.core.errors import ParameterError
from softsbi.core.types import STATUS_DIVERGED, STATUS_IMPLAUSIBLE, STATUS_OK, Scenario

pytestmark = pytest.mark.integration

GRID = 6


@pytest.fixture(scope="module")
def scenario() -> Scenario:
    return lift_scenario(None)


@pytest.fixture(scope="module")
def sim() -> MujocoFlex:
    return MujocoFlex(grid=GRID)


@pytest.fixture(scope="module")
def theta(sim, scenario) -> dict[str, float]:
    return sim.param_space(scenario).midpoint()


@pytest.fixture(scope="module")
def base(sim, scenario, theta):
    return sim.simulate(scenario, theta)


def test_registered():
    from softsbi.plugins import registry
    assert registry().simulator("mujoco-flex") is MujocoFlex


def test_param_space(sim, scenario):
    sp = sim.param_space(scenario)
    assert {"bend", "stretch", "friction", "scale"} <= set(sp.names)
    assert sp["bend"].log and sp["stretch"].log
    assert sp["bend"].unit == "N*m" and sp["stretch"].unit == "N/m" and sp["scale"].unit == "m"
    # the real cloth (DiffCloud nominal 0.278 m) lies inside the scale prior
    assert sp["scale"].low < scenario.object["size"] < sp["scale"].high
    # fabric densities of shared/data/fabric_materials (0.113 - 0.324 kg/m^2) are inside the mass prior
    assert sp["mass"].low <= 0.113 and sp["mass"].high >= 0.324


def test_plate_mapping():
    E, t = plate_mapping(1e-5, 100.0, 0.3)
    assert E * t == pytest.approx(100.0)
    assert E * t ** 3 / (12 * (1 - 0.09)) == pytest.approx(1e-5)


def test_rollout_shapes(base, scenario):
    r = base
    assert r.status == STATUS_OK, r.reason
    r.validate()
    T, N = scenario.n_frames, GRID * GRID
    assert r.vertices.shape == (T, N, 3)
    assert r.faces.shape == (2 * (GRID - 1) ** 2, 3) and r.faces.max() == N - 1
    np.testing.assert_array_equal(r.faces, grid_faces(GRID))
    np.testing.assert_allclose(r.times, scenario.times)
    assert r.info["wall_s"] > 0 and r.info["steps"] == round(scenario.times[-1] / 0.004)
    assert np.all(np.isfinite(r.vertices))


def test_initial_placement(base, scenario, theta):
    v0 = base.vertices[0]
    L = theta["scale"]
    # flat on the table, grasped corner (vertex 0) at object["corner"], diagonal along "direction"
    assert np.ptp(v0[:, 2]) < 1e-9
    assert 0.0 < v0[0, 2] - scenario.table_z < 0.01
    np.testing.assert_allclose(v0[0, :2], scenario.object["corner"], atol=1e-9)
    far = v0[np.argmax(np.linalg.norm(v0[:, :2] - v0[0, :2], axis=1))]
    np.testing.assert_allclose(far[:2] - v0[0, :2], np.asarray(scenario.object["direction"]) * L * np.sqrt(2),
                               atol=1e-9)
    # grid spacing = scale / (grid - 1)
    edges = np.linalg.norm(v0[base.faces[:, 0]] - v0[base.faces[:, 1]], axis=1)
    assert edges.min() == pytest.approx(L / (GRID - 1))


def test_gripper_follows_path(base, scenario):
    # the grasp target is the scenario path shifted by a constant (the corner lies on the table)
    off = base.gripper - scenario.gripper
    np.testing.assert_allclose(off, np.broadcast_to(off[0], off.shape), atol=1e-12)
    assert np.abs(off[0]).max() < 0.01
    # the grasped corner follows it within 1 cm and the cloth is lifted off the table
    assert np.linalg.norm(base.vertices[:, 0] - base.gripper, axis=1).max() < 0.01
    assert base.vertices[-1, :, 2].max() > scenario.table_z + 0.25


def test_deterministic(sim, scenario, theta, base):
    r2 = sim.simulate(scenario, theta, seed=3)
    np.testing.assert_array_equal(base.vertices, r2.vertices)


@pytest.mark.parametrize("name", ["bend", "stretch", "friction", "scale", "mass"])
def test_each_parameter_changes_outcome(sim, scenario, theta, name):
    p = sim.param_space(scenario)[name]
    lo = sim.simulate(scenario, dict(theta, **{name: p.low}))
    hi = sim.simulate(scenario, dict(theta, **{name: p.high}))
    assert lo.ok and hi.ok, (lo.reason, hi.reason)
    disp = np.linalg.norm(lo.vertices[-1] - hi.vertices[-1], axis=1).mean()
    assert disp > 0.01, f"{name}: low vs high moves the final cloth by only {disp * 100:.2f} cm"


def test_parameter_errors(sim, scenario, theta):
    with pytest.raises(ParameterError, match="outside its physical limits"):
        sim.simulate(scenario, dict(theta, bend=-1.0))
    # beyond the declared prior but physical (a prior widened with --bounds): simulated
    assert sim.simulate(scenario, dict(theta, friction=2.0)).ok
    with pytest.raises(ParameterError, match="unknown parameter"):
        sim.simulate(scenario, dict(theta, bendd=1e-5))
    missing = dict(theta)
    missing.pop("friction")
    with pytest.raises(ParameterError, match="missing"):
        sim.simulate(scenario, missing)
    with pytest.raises(ParameterError, match="effect"):
        sim.simulate(scenario, theta, effects=["toy-wind"])
    # any valid scenario runs; one needing a feature the engine lacks is refused naming it
    bad = Scenario(name="fold", times=scenario.times, gripper=scenario.gripper, table_z=0.0,
                   object={"kind": "jelly"})
    with pytest.raises(ValueError, match="lacks objects of kind 'jelly'"):
        sim.simulate(scenario=bad, theta=theta)
    with pytest.raises(ValueError, match="lacks objects of kind 'jelly'"):
        sim.param_space(bad)


def test_divergence_detected(scenario, theta):
    # explicit Euler with a stiff membrane blows up within a few steps; MuJoCo resets the state
    r = MujocoFlex(grid=GRID, integrator="Euler", overrides={"young": 1e10}).simulate(scenario, theta)
    assert r.status == STATUS_DIVERGED
    assert "BADQACC" in r.reason
    assert r.vertices.shape == (scenario.n_frames, GRID * GRID, 3) and np.all(np.isfinite(r.vertices))


def test_implausible_detected(scenario, theta):
    # a huge step with an absurd young's modulus pushes the cloth through the table
    r = MujocoFlex(grid=GRID, overrides={"young": 1e12, "timestep": 0.05}).simulate(scenario, theta)
    assert r.status in (STATUS_IMPLAUSIBLE, STATUS_DIVERGED) and r.status != STATUS_OK
    assert r.reason


@pytest.mark.slow
def test_prior_corners_stable(scenario):
    """Every corner of the prior box runs without divergence at the default options."""
    sim = MujocoFlex()
    sp = sim.param_space(scenario)
    for corner in itertools.product([0, 1], repeat=sp.dim):
        th = {p.name: (p.high if c else p.low) for p, c in zip(sp, corner)}
        r = sim.simulate(scenario, th)
        assert r.ok, (th, r.reason)
        assert r.vertices[..., 2].min() > scenario.table_z - 0.01, th
        assert np.linalg.norm(r.vertices[:, 0] - r.gripper, axis=1).max() < 0.015, th


def _run(args):
    opts, scenario, theta = args
    return MujocoFlex(**opts).simulate(scenario, theta).vertices


def test_pickle_and_process_pool(sim, scenario, theta, base):
    clone = pickle.loads(pickle.dumps(sim))
    np.testing.assert_array_equal(clone.simulate(scenario, theta).vertices, base.vertices)
    ctx = mp.get_context("spawn")
    with ctx.Pool(1) as pool:
        out = pool.map(_run, [({"grid": GRID}, scenario, theta)])
    np.testing.assert_array_equal(out[0], base.vertices)
