"""The rig's and the fabric's candidate effects (issue 79): anisotropic stretch (a model edit of the compiled
membrane), the arm's mask and the offset between the two merged cameras (observation transforms). Each is exactly
the nominal model when off (``tests/effects/test_candidates.py`` parametrises that over every built-in) and changes
what is simulated or seen in the direction and by the amount its docstring states (mujoco-flex, 5x5 cloth)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from softsbi.backends.mujoco_flex import MujocoFlex
from softsbi.backends.mujoco_flex.model import apply_anisotropy, orthotropic_stiffness, spec_to_xml
from softsbi.core.errors import ParameterError
from softsbi.effects.material import MATERIAL_EFFECTS, AnisotropicStretch
from softsbi.effects.rig import RIG_EFFECTS, ArmMask, CameraOffset, side_share
from softsbi.perception.clouds import arm_distance, arm_view, effect_views, rollout_clouds
from softsbi.plugins import registry
from softsbi.scenarios.builtin import lift_scenario, winding_scenario

SIM = MujocoFlex(grid=5)
LIFT = lift_scenario(None, n_frames=11)
#: a soft cloth (stretch 10 N/m, DiffCloud's lifts fit 13 +- 4 N/m), so that the membrane's stiffness shows
SOFT = {**SIM.param_space(LIFT).midpoint(), "stretch": 10.0}
REPO = Path(__file__).resolve().parents[2]


def _run(effects=(), seed=0, sc=LIFT, **values):
    theta = {**SOFT, **values}
    for e in effects:
        theta = {**registry().effect(e)().nominal(), **theta}
    ro = SIM.simulate(sc, theta, effects=list(effects), seed=seed)
    assert ro.ok, ro.reason
    return ro


@pytest.fixture(scope="module")
def nominal():
    return _run()


def _compiled(theta, effects=(), sc=LIFT):
    """The lift's compiled model at ``theta`` (MjModel, MjData at rest, the spec), anisotropy applied."""
    import mujoco
    spec = SIM.build_spec(sc, theta, list(effects))
    m = mujoco.MjModel.from_xml_string(spec_to_xml(spec))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    apply_anisotropy(m, d, spec)
    mujoco.mj_forward(m, d)
    return m, d, spec


def test_registered_documented_and_applied_by_mujoco_flex_through_their_doors():
    reg = registry()
    for cls in MATERIAL_EFFECTS + RIG_EFFECTS:
        assert reg.effect(cls.name) is cls and cls.__doc__
        assert MujocoFlex.supports(cls) is None, cls.name
    assert [c.kind for c in MATERIAL_EFFECTS + RIG_EFFECTS] == ["physics", "sensor", "sensor"]
    assert AnisotropicStretch().doors("mujoco-flex") == ("model-edit",)
    assert ArmMask().doors("mujoco-flex") == CameraOffset().doors("mujoco-flex") == ("observation",)
    # pybullet applies the observation transforms, not mujoco-flex's membrane edit
    pb = reg.simulator("pybullet-massspring")
    assert pb.supports(ArmMask) is None and pb.supports(CameraOffset) is None
    assert "model edit registered for 'pybullet-massspring'" in pb.supports(AnisotropicStretch)
    # off values: the ratio 1 at the log prior's midpoint, no mask, no offset
    assert AnisotropicStretch().nominal() == {"warp_weft_ratio": 1.0}
    assert ArmMask().nominal() == {"mask_radius": 0.0}
    assert CameraOffset().nominal() == {"side_dx": 0.0, "side_dy": 0.0, "side_dz": 0.0}
    (p,) = AnisotropicStretch().param_space().params
    assert (p.low, p.high, p.log) == (0.25, 4.0, True)


# -- aniso-stretch ------------------------------------------------------------------------------------------------


def test_the_orthotropic_stiffness_at_ratio_one_is_mujocos_own_membrane():
    """The derivation of the edited stiffness reproduces MuJoCo's compiled isotropic membrane (to machine
    precision), so at another ratio only the constitutive matrix differs."""
    m, d, spec = _compiled(SOFT)
    el = spec["elasticity"]
    nel = int(m.flex_elemnum[0])
    elements = np.asarray(m.flex_elem[:3 * nel]).reshape(nel, 3)
    rest = np.asarray(d.flexvert_xpos).reshape(-1, 3)
    mine = orthotropic_stiffness(rest, elements, spec["warp"], el["young"] * el["thickness"], el["poisson"], 1.0)
    theirs = np.asarray(m.flex_stiffness).reshape(nel, 21)
    np.testing.assert_allclose(mine, theirs[:, :6], rtol=1e-12, atol=1e-12 * np.abs(theirs).max())
    assert not theirs[:, 6:].any()


@pytest.mark.skipif(not (REPO.parent / "shared" / "data" / "diffcloud_fold" / "fold_tan").is_dir(),
                    reason="shared/data/diffcloud_fold not present")
def test_a_mesh_cloth_gets_the_same_membrane_and_its_warp_is_the_meshs_x_axis_turned_by_the_yaw():
    import mujoco

    import softsbi
    sc = softsbi.load_scenario(REPO / "examples" / "fold.yaml")
    theta = {**SIM.param_space(sc).midpoint(), "yaw": 30.0}
    spec = SIM.build_spec(sc, theta)
    assert spec["warp"] == pytest.approx([np.cos(np.radians(30.0)), np.sin(np.radians(30.0)), 0.0])
    m = mujoco.MjModel.from_xml_string(spec_to_xml(spec))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    spec["anisotropy"] = {"warp_weft_ratio": 2.0}
    apply_anisotropy(m, d, spec)  # checks MuJoCo's own membrane against the derivation first: it would refuse
    assert _run(["aniso-stretch"], sc=sc, **{**theta, "warp_weft_ratio": 2.0}).ok


def _tension(r, axis, eps=0.01):
    """MuJoCo's passive force (N) along ``axis`` (the warp or the weft) on the far edge of the resting cloth
    stretched uniformly by ``eps`` along it."""
    m, d, spec = _compiled({**SOFT, "warp_weft_ratio": r}, ["aniso-stretch"])
    n = int(m.flex_vertnum[0])
    x = np.asarray(d.flexvert_xpos).reshape(-1, 3)[:n].copy()
    warp = np.asarray(spec["warp"])
    u = warp if axis == "warp" else np.cross([0.0, 0.0, 1.0], warp)
    s = (x - x.mean(0)) @ u
    ids = m.flex_vertbodyid[:n]
    jnt = m.body_jntadr[ids][:, None] + np.arange(3)  # each vertex's 3 world-aligned slide joints
    d.qpos[m.jnt_qposadr[jnt]] += eps * s[:, None] * u[None, :]
    mujoco_forward(m, d)
    f = np.asarray(d.qfrc_spring)[m.jnt_dofadr[jnt]]
    return float((f[s > s.max() - 1e-9] @ u).sum())


def mujoco_forward(m, d):
    import mujoco
    mujoco.mj_forward(m, d)


def test_the_membrane_pulled_along_the_warp_pulls_back_sqrt_r_times_harder_and_along_the_weft_1_over_sqrt_r():
    """Huber's orthotropic membrane as MuJoCo integrates it: a uniform 1 % strain along one axis of the 27 cm
    cloth (stretch 10 N/m, nu 0.3) pulls its far edge back by ``k / (1 - nu^2) E (1 + eps) L`` (Green strain
    E = eps + eps^2 / 2) at r = 1, twice that along the warp and half along the weft at r = 4."""
    L, nu, k, eps = SOFT["scale"], SIM.poisson, SOFT["stretch"], 0.01
    iso = _tension(1.0, "warp")
    assert -iso == pytest.approx(k / (1 - nu ** 2) * (eps + eps ** 2 / 2) * (1 + eps) * L, rel=1e-9)
    assert _tension(1.0, "weft") == pytest.approx(iso, rel=1e-9)
    assert _tension(4.0, "warp") == pytest.approx(2.0 * iso, rel=1e-9)
    assert _tension(4.0, "weft") == pytest.approx(0.5 * iso, rel=1e-9)
    assert _tension(0.25, "warp") == pytest.approx(0.5 * iso, rel=1e-9)


def _edge_strain(v):
    """Mean strain (%) of the warp edges (index i) and the weft edges (index j) of a 5x5 grid frame ``(25, 3)``."""
    g = v.reshape(5, 5, 3)
    h = SOFT["scale"] / 4
    warp = np.linalg.norm(g[1:] - g[:-1], axis=-1)
    weft = np.linalg.norm(g[:, 1:] - g[:, :-1], axis=-1)
    return 100 * (warp.mean() / h - 1), 100 * (weft.mean() / h - 1)


def test_a_lifted_cloth_with_a_stiffer_warp_stretches_less_along_it_and_more_across_it(nominal):
    """Measured (lift, frame 8 of 11, stretch 10 N/m): nominal 2.5 % along both; r = 4: warp 1.0 %, weft 4.7 %;
    r = 1/4 the mirror image (4.5 %, 1.1 %)."""
    warp0, weft0 = _edge_strain(nominal.vertices[8])
    assert 2.0 < warp0 < 3.0 and abs(weft0 - warp0) < 0.2
    warp, weft = _edge_strain(_run(["aniso-stretch"], warp_weft_ratio=4.0).vertices[8])
    assert warp < 0.5 * warp0 and weft > 1.5 * weft0
    warp, weft = _edge_strain(_run(["aniso-stretch"], warp_weft_ratio=0.25).vertices[8])
    assert weft < 0.5 * weft0 and warp > 1.5 * warp0


def test_a_rope_has_no_membrane_to_make_anisotropic():
    sc = winding_scenario(n_frames=5)
    theta = {**SIM.param_space(sc).midpoint(), "warp_weft_ratio": 2.0}
    with pytest.raises(ParameterError, match="2-D flex"):
        SIM.simulate(sc, theta, effects=["aniso-stretch"])


# -- camera-offset ------------------------------------------------------------------------------------------------


def test_the_side_cameras_share_is_how_steep_the_cloth_is():
    """0 for a flat patch, 1 for a vertical one, 1/2 at 45 degrees (|n_h| / (|n_h| + |n_z|)); 1/2 without faces."""
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    sq = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)

    def tilted(a):  # the square turned by a about the x axis
        c, s = np.cos(a), np.sin(a)
        return sq @ np.array([[1, 0, 0], [0, c, s], [0, -s, c]])

    w = side_share(np.stack([sq, tilted(np.pi / 2), tilted(np.pi / 4)]), faces)
    np.testing.assert_allclose(w, [[0.0] * 4, [1.0] * 4, [0.5] * 4], atol=1e-12)
    np.testing.assert_array_equal(side_share(np.zeros((2, 3, 3)), np.zeros((0, 3), int)), 0.5)


def test_the_side_cameras_points_move_by_its_offset_as_the_cloth_is_lifted(nominal):
    """The flat cloth (frame 0) is not moved; every vertex moves by its share of the offset, so the hanging cloth
    moves most: measured mean share 0 at frame 0, 0.21 at frame 5, 0.79 at frame 10 (the lift, stretch 10 N/m)."""
    off = np.array([0.0, 0.02, -0.01])
    ro = _run(["camera-offset"], side_dx=off[0], side_dy=off[1], side_dz=off[2])
    w = side_share(nominal.vertices, nominal.faces)
    np.testing.assert_allclose(ro.vertices - nominal.vertices, w[..., None] * off, atol=1e-15)
    np.testing.assert_array_equal(ro.vertices[0], nominal.vertices[0])
    np.testing.assert_array_equal(ro.gripper, nominal.gripper)
    shift = (ro.vertices - nominal.vertices).mean(1)[:, 1] / off[1]
    assert shift[0] == 0.0 and np.all(np.diff(shift) >= 0) and 0.1 < shift[5] < 0.3 and 0.7 < shift[10] < 0.9


# -- arm-mask -----------------------------------------------------------------------------------------------------


R = 0.08  # m


@pytest.fixture(scope="module")
def masked():
    return _run(["arm-mask"], mask_radius=R)


def test_the_arm_mask_moves_no_vertex_and_hides_the_cloth_near_the_gripper_from_the_observer(nominal, masked):
    from softsbi.perception.pointcloud import PointCloudObserver
    np.testing.assert_array_equal(masked.vertices, nominal.vertices)
    assert masked.info["arm_mask_radius"] == R and "arm_mask_radius" not in nominal.info
    obs = PointCloudObserver(64)
    x = obs.observe(masked, np.random.default_rng(0)).points
    x0 = obs.observe(nominal, np.random.default_rng(0)).points
    d = np.array([arm_distance(x[t], masked.gripper[t]) for t in range(len(x))])
    d0 = np.array([arm_distance(x0[t], nominal.gripper[t]) for t in range(len(x0))])
    assert d.min() >= R and (d0 < R).any(axis=1).all()  # every frame of the nominal shows some of it
    # the nominal observer draws as before (its random stream is not touched by the mask's branch)
    np.testing.assert_array_equal(x0, PointCloudObserver(64).observe(_run(), np.random.default_rng(0)).points)


def test_the_arm_mask_removes_the_top_of_the_hanging_cloth(masked):
    """Measured (lift, 2000 surface samples per frame): the 8 cm mask hides 4.3-9.1 % of the cloth in every frame
    (a quarter disc of its corner, and more while the corner is lifted off the table); the seen cloth sits lower,
    its mean height 0.8 cm below the full cloth's in the last two frames."""
    clouds = rollout_clouds(masked, 2000, np.random.default_rng(1))
    seen = effect_views(clouds, masked)
    hidden = np.array([1 - len(s) / len(c) for s, c in zip(seen, clouds)])
    assert np.all((0.03 < hidden) & (hidden < 0.12)), hidden
    drop = np.array([c[:, 2].mean() - s[:, 2].mean() for s, c in zip(seen, clouds)])
    assert drop[0] == 0.0 and np.all(drop[5:] > 0.003) and np.all(drop[-2:] > 0.006), drop


def test_the_arm_hides_what_is_near_the_grasp_point_and_above_it():
    grip = np.array([0.0, 0.0, 0.2])
    pts = np.array([[0.05, 0, 0.2], [0.0, 0.0, 0.13], [0.05, 0.05, 0.9], [0.0, 0.09, 0.25], [0.06, 0.0, 0.15]])
    np.testing.assert_allclose(arm_distance(pts, grip), [0.05, 0.07, np.hypot(0.05, 0.05), 0.09,
                                                       np.hypot(0.06, 0.05)])
    np.testing.assert_array_equal(arm_view(pts, grip, 0.08), pts[[3]])
    # everything hidden: the tenth farthest from the arm stands in (at least one point)
    np.testing.assert_array_equal(arm_view(pts, grip, 1.0), pts[[3]])
    assert effect_views([pts], {"info": {}, "gripper": grip[None]}) == [pts]  # no mask: the clouds themselves


def test_the_arm_mask_acts_on_the_metric_the_measurement_and_the_summaries(nominal, masked):
    from softsbi.workflows.criticism.stats import sensor_features
    from softsbi.workflows.fit.jobs import JobItem, SimContext, simulate_job
    from softsbi.workflows.measurement import simulate_recording
    rec = simulate_recording("mujoco-flex", LIFT, {**SOFT, "mask_radius": R}, backend_options={"grid": 5},
                             effects=["arm-mask"], n_points=32, n_dense=200)
    # the synthetic measurement: 200 distinct points per frame, none inside the mask
    assert rec.dense.shape == (11, 200, 3)
    assert all(len(np.unique(c, axis=0)) == 200 and arm_distance(c, g).min() >= R
               for c, g in zip(rec.dense, rec.x[:, 0]))
    kw = dict(backend="mujoco-flex", backend_options={"grid": 5}, scenario=LIFT.to_json(), effects=[],
              observer="pointcloud", observer_options={"n_points": 32}, param_names=SIM.param_space(LIFT).names,
              fixed={}, dense=rec.dense, n_dense=200, keep_rollout=True)
    plain = simulate_job(SimContext(**kw), JobItem(SOFT, 0, effects=[]))
    hidden = simulate_job(SimContext(**kw), JobItem({**SOFT, "mask_radius": R}, 0, effects=["arm-mask"]))
    assert hidden.arm_mask_radius == R and plain.arm_mask_radius is None
    assert hidden.info == {"arm_mask_radius": R} and plain.info == {}
    # the measurement lacks the cloth around the gripper, which the nominal rollout shows: measured mean Chamfer
    # 1.00 cm with the mask, 1.05 cm without (over 11 frames; two 200-point samples of one surface are ~1 cm apart)
    assert hidden.chamfer.mean() < plain.chamfer.mean() - 0.0003, (hidden.chamfer.mean(), plain.chamfer.mean())
    # check's summaries of a kept rollout see through its mask: the last frame's mean height falls
    f_plain = sensor_features(plain, 5, 200, None, None, None).reshape(11, -1)
    f_hidden = sensor_features(hidden, 5, 200, None, None, None).reshape(11, -1)
    assert f_hidden[-1, 2] < f_plain[-1, 2] - 0.005
