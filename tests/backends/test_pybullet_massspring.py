"""Tests of the pybullet-massspring backend (PyBullet deformable mass-spring cloth and rope)."""
from __future__ import annotations

import pickle

import numpy as np
import pytest

from softsbi.backends.common import grid_faces
from softsbi.backends.mujoco_flex import MujocoFlex
from softsbi.backends.pybullet_massspring import PybulletMassSpring
from softsbi.backends.pybullet_massspring.model import C_BEND, C_STRETCH, spring_constants
from softsbi.scenarios.builtin import lift_scenario, make_scenario
from softsbi.core.errors import ParameterError
from softsbi.executors.local import LocalExecutor
from softsbi.core.types import STATUS_DIVERGED, STATUS_IMPLAUSIBLE, STATUS_OK, Scenario

pytestmark = pytest.mark.integration

GRID = 6


@pytest.fixture(scope="module")
def scenario() -> Scenario:
    return lift_scenario(None)


@pytest.fixture(scope="module")
def sim() -> PybulletMassSpring:
    return PybulletMassSpring(grid=GRID)


@pytest.fixture(scope="module")
def theta(sim, scenario):
    return sim.param_space(scenario).midpoint()


@pytest.fixture(scope="module")
def base(sim, scenario, theta):
    return sim.simulate(scenario, theta)


def test_registered():
    from softsbi.plugins import registry
    assert registry().simulator("pybullet-massspring") is PybulletMassSpring
    assert PybulletMassSpring.aliases == ("pybullet-fem",)  # the former name, still accepted


def test_old_name_warns():
    """``pybullet-fem`` (the model is mass-spring, not FEM) resolves to the same class with a FutureWarning."""
    from softsbi.plugins import registry
    with pytest.warns(FutureWarning, match="pybullet-fem"):
        assert registry().simulator("pybullet-fem") is PybulletMassSpring


def test_param_space_names_units(sim, scenario):
    sp = sim.param_space(scenario)
    assert sp.names == ["bend", "stretch", "friction", "scale", "mass"]
    # the shared physical parameters: mujoco-flex's names, units and (bend, friction, size) bounds
    assert sp["bend"].unit == "N*m" and sp["stretch"].unit == "N/m" and sp["mass"].unit == "kg/m^2"
    mj = MujocoFlex().param_space(scenario)
    for name in ("bend", "friction", "scale", "mass"):
        assert (sp[name].low, sp[name].high, sp[name].unit) == (mj[name].low, mj[name].high, mj[name].unit)
    assert mj["stretch"].low <= sp["stretch"].low < sp["stretch"].high <= mj["stretch"].high
    assert all(p.description for p in sp)
    rope = sim.param_space(make_scenario("winding"))
    assert rope.names == ["pb_rope_bend", "pb_rope_stretch", "friction", "scale", "mass"]
    assert rope["mass"].unit == "kg/m" and rope["scale"].unit == "m"  # scale is the rope's length


def test_spring_constants_mapping():
    """k_el = stretch (lattice membrane stiffness, mesh independent), k_be = C_BEND D / h^2."""
    k_el, k_be = spring_constants(2e-4, 80.0, 0.025)
    assert k_el == pytest.approx(80.0 * C_STRETCH)
    assert k_be == pytest.approx(C_BEND * 2e-4 / 0.025 ** 2)
    k_el2, k_be2 = spring_constants(2e-4, 80.0, 0.05)  # coarser mesh: same membrane, softer hinges
    assert k_el2 == k_el and k_be2 == pytest.approx(k_be / 4)
    with pytest.raises(ParameterError, match="must be > 0"):
        spring_constants(0.0, 80.0, 0.025)


def test_rollout_uses_the_mapping(sim, scenario, theta, base):
    h = theta["scale"] / (GRID - 1)
    k_el, k_be = spring_constants(theta["bend"], theta["stretch"], h)
    assert base.info["springElasticStiffness"] == pytest.approx(k_el)
    assert base.info["springBendingStiffness"] == pytest.approx(k_be)


def test_old_parameter_units_give_one_line_errors(sim, scenario, theta):
    with pytest.raises(ParameterError, match="now the bending rigidity in N.m.*old per-spring"):
        sim.simulate(scenario, dict(theta, bend=2.0))
    wind = make_scenario("winding")
    th = sim.param_space(wind).midpoint()
    with pytest.raises(ParameterError, match="bend -> pb_rope_bend, stretch -> pb_rope_stretch"):
        sim.simulate(wind, dict({k: v for k, v in th.items() if not k.startswith("pb_")}, bend=1.0, stretch=200.0))


def test_shapes_and_layout(base, scenario, theta):
    assert base.status == STATUS_OK, base.reason
    base.validate()
    T, N = scenario.n_frames, GRID * GRID
    assert base.vertices.shape == (T, N, 3) and np.all(np.isfinite(base.vertices))
    np.testing.assert_array_equal(base.faces, grid_faces(GRID))
    v0 = base.vertices[0]
    # same layout as mujoco-flex: vertex 0 = grasped corner, x-major grid, spacing scale / (grid - 1)
    np.testing.assert_allclose(v0[0, :2], scenario.object["corner"], atol=1e-6)
    assert np.linalg.norm(v0[1] - v0[0]) == pytest.approx(theta["scale"] / (GRID - 1), rel=1e-5)
    assert np.linalg.norm(base.vertices[:, 0] - base.gripper, axis=1).max() < 0.01
    assert base.vertices[-1, :, 2].max() > scenario.table_z + 0.25


def test_deterministic_and_own_clients(sim, scenario, theta, base):
    np.testing.assert_array_equal(sim.simulate(scenario, theta, seed=5).vertices, base.vertices)
    other = PybulletMassSpring(grid=GRID)
    np.testing.assert_array_equal(other.simulate(scenario, theta).vertices, base.vertices)
    assert other._cid != sim._cid
    clone = pickle.loads(pickle.dumps(sim))
    assert clone._cid is None
    np.testing.assert_array_equal(clone.simulate(scenario, theta).vertices, base.vertices)


@pytest.mark.parametrize("name", ["bend", "stretch", "friction", "scale", "mass"])
def test_each_parameter_changes_outcome(sim, theta, name):
    sc = make_scenario("wipe" if name == "friction" else "lift")
    th = sim.param_space(sc).midpoint()
    p = sim.param_space(sc)[name]
    lo = sim.simulate(sc, dict(th, **{name: p.low}))
    hi = sim.simulate(sc, dict(th, **{name: p.high}))
    assert lo.ok and hi.ok, (lo.reason, hi.reason)
    disp = np.linalg.norm(lo.vertices - hi.vertices, axis=-1).mean()
    # bending springs barely matter for a light cloth in PyBullet (see benchmarks/identifiability.py)
    assert disp > (0.001 if name == "bend" else 0.003), f"{name}: low vs high moves the cloth by only {disp * 100:.2f} cm"


def test_failure_detection_fires(scenario, theta):
    # no automatic substeps and a stiff spring on a light cloth: the mass-spring solver explodes
    r = PybulletMassSpring(grid=GRID, overrides={"springElasticStiffness": 2000.0, "substeps": 1}).simulate(scenario, theta)
    assert r.status in (STATUS_DIVERGED, STATUS_IMPLAUSIBLE), r.reason
    assert r.reason and np.all(np.isfinite(r.vertices))
    # damping 0 explodes (shared/MEASURED.md): never raised, always returned
    r = PybulletMassSpring(grid=GRID, overrides={"springDampingStiffness": 0.0, "substeps": 1}).simulate(scenario, theta)
    assert r.status != STATUS_OK and r.reason


def test_bad_input(sim, scenario, theta):
    with pytest.raises(ParameterError, match="outside its physical limits"):
        sim.simulate(scenario, dict(theta, stretch=-1.0))
    with pytest.raises(ParameterError, match="Valid parameters: bend, stretch"):
        sim.simulate(scenario, dict(theta, bendd=1.0))
    with pytest.raises(ParameterError, match="supported effects"):
        sim.simulate(scenario, theta, effects=["air-drag"])
    # any valid scenario runs; one needing a feature the engine lacks is refused naming it
    bad = Scenario(name="fold", times=scenario.times, gripper=scenario.gripper, table_z=0.0,
                   object={"kind": "jelly"})
    with pytest.raises(ValueError, match="lacks objects of kind .jelly."):
        sim.simulate(bad, theta)
    with pytest.raises(ValueError, match="grid"):
        PybulletMassSpring(grid=2)


def _job(ctx, item):
    sc, th = ctx
    return PybulletMassSpring(grid=item).simulate(sc, th).vertices


def test_worker_processes(scenario, theta, base):
    ex = LocalExecutor(workers=2)
    try:
        out = dict(ex.map_unordered(_job, [GRID, GRID], context=(scenario, theta)))
    finally:
        ex.close()
    for v in out.values():
        assert not isinstance(v, BaseException), v
        np.testing.assert_array_equal(v, base.vertices)


def test_old_class_name_warns():
    import softsbi.backends.pybullet_massspring as mod
    with pytest.warns(FutureWarning, match="PybulletMassSpring"):
        assert mod.PybulletFEM is PybulletMassSpring
