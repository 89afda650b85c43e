"""``FitConfig.sensor_draws``: one simulation observed at several values of the sensor effects' parameters
(mujoco-flex rope winding, small budgets)."""
from __future__ import annotations

import types

import numpy as np
import pytest

from softsbi.core.errors import SchemaError
from softsbi.core.store import RunStore
from softsbi.core.types import STATUS_OK
from softsbi.scenarios.builtin import winding_scenario
from softsbi.workflows.fit.run import FitConfig, SensorDraws, fit_param_space, run_fit
from softsbi.workflows.fit.jobs import JobItem, SimContext, simulate_job
from softsbi.workflows.measurement import simulate_recording

pytestmark = pytest.mark.integration

SC = winding_scenario(n_frames=8)
TRUTH = {"young": 1e6, "friction": 0.4, "scale": 0.4, "mass": 0.03, "time_offset": 0.06}


def _ctx(effects):
    return SimContext(backend="mujoco-flex", backend_options={}, scenario=SC.to_json(), effects=list(effects),
                      observer="pointcloud", observer_options={"n_points": 16}, param_names=list(TRUTH),
                      fixed={}, dense=None, n_dense=100)


def test_one_simulation_observed_at_each_draw_gives_what_separate_simulations_give():
    """The primary observation is the job's without draws (same x); each draw's observation is the job's at that
    time offset (the offset is deterministic and the observer's sampling is the primary's)."""
    ctx = _ctx(["time-offset"])
    plain = simulate_job(ctx, JobItem(TRUTH, 5))
    draws = {"effects": ["time-offset"], "draws": [{"time_offset": 0.06}, {"time_offset": -0.08}]}
    res = simulate_job(ctx, JobItem(TRUTH, 5, sensor_draws=draws))
    assert res.status == STATUS_OK and res.sensor_x.shape == (2, *plain.x.shape)
    np.testing.assert_array_equal(res.x, plain.x)
    np.testing.assert_array_equal(res.sensor_x[0], plain.x)
    other = simulate_job(ctx, JobItem({**TRUTH, "time_offset": -0.08}, 5))
    np.testing.assert_array_equal(res.sensor_x[1], other.x)
    assert np.abs(res.sensor_x[1] - res.x).max() > 1e-3  # the offset moves the observed rope


def test_with_a_bank_a_sensor_effect_reads_the_nominal_rollout_and_observes_what_simulating_it_gives(tmp_path):
    """A model with an observation-only effect (time-offset) reads the rollout the nominal model stored in the bank
    (its physics does not depend on the sensor) and observes exactly what simulating with the effect gives."""
    from dataclasses import replace
    from softsbi.workflows.fit.bank import HIT
    nominal = replace(_ctx([]), bank=str(tmp_path / "bank"))
    values = {k: v for k, v in TRUTH.items() if k != "time_offset"}
    assert simulate_job(nominal, JobItem(values, 5)).bank != HIT
    banked = simulate_job(replace(_ctx(["time-offset"]), bank=str(tmp_path / "bank")), JobItem(TRUTH, 5))
    assert banked.bank == HIT
    np.testing.assert_array_equal(banked.x, simulate_job(_ctx(["time-offset"]), JobItem(TRUTH, 5)).x)


def test_draws_change_only_the_sensor_parameters_and_stay_in_the_proposal():
    """Rows keep their physics parameters; the sensor dimensions are uniform (the prior) or inside the
    truncated proposal's region."""
    space = types.SimpleNamespace(names=["a", "b", "s"])
    sd = SensorDraws(3, ["time-offset"], [2], space)
    u = np.random.default_rng(0).random((50, 3))
    rng = np.random.default_rng(1)
    prior = sd.draw(u, None, rng)
    assert prior.shape == (50, 3, 3)
    np.testing.assert_array_equal(prior[:, :, :2], np.repeat(u[:, None, :2], 3, axis=1))
    assert prior[:, :, 2].std() > 0.2  # uniform on [0, 1], not the row's own value

    class Region:  # a truncated proposal: s < 0.3
        @staticmethod
        def in_region(x):
            return x[:, 2] < 0.3

    inside = sd.draw(u, Region, rng)
    assert (inside[:, :, 2] < 0.3).all() and len(np.unique(inside[:, :, 2])) == 150
    np.testing.assert_array_equal(inside[:, :, :2], np.repeat(u[:, None, :2], 3, axis=1))


def test_which_fits_draw_sensor_parameters():
    """Only point-cloud fits with a pure observation-transform effect, truncated proposals or bulk estimators, and
    sensor_draws >= 1."""
    def of(effects, k=2, usable=True):
        cfg = FitConfig(effects=effects, sensor_draws=k)
        _, space = fit_param_space(cfg, SC)
        return SensorDraws.of(cfg, space, _ctx(effects), usable)

    sd = of(["wind", "time-offset"])
    assert sd is not None and sd.effects == ["time-offset"] and sd.k == 2
    assert of(["wind"]) is None and of(["time-offset"], k=0) is None and of(["time-offset"], usable=False) is None


def test_a_fit_trains_on_the_draws_stores_them_and_resumes(tmp_path):
    """A 2-round fit with time-offset and sensor_draws = 2: each round stores its draws and their observations,
    trains on 3 x its usable simulations; the same command resumes; another sensor_draws is refused."""
    meas = simulate_recording("mujoco-flex", SC, TRUTH, effects=["time-offset"], n_points=16, n_dense=100, seed=3)
    cfg = FitConfig(effects=["time-offset"], rounds=2, sims_per_round=12, n_eval=4, n_points=16, n_dense=100,
                    workers=1, seed=0, sensor_draws=2, estimator_options={"max_epochs": 5, "ensemble": 1,
                                                                          "recalibrate": False})
    run_fit(tmp_path / "run", meas, cfg, make_plots=False)
    store = RunStore.open(tmp_path / "run" / "run.zarr")
    for r in (0, 1):
        assert "sensor_x" not in store.round_data(r)  # read only where asked for
        d = store.round_data(r, ("status", "sensor_u", "sensor_x"))
        ok = d["status"] == STATUS_OK
        assert d["sensor_u"].shape == (12, 2, 5) and np.isfinite(d["sensor_x"][ok]).all()
        info = store.round_attrs(r)["info"]
        assert info["sensor_pairs"] == 2 * sum(info["usable_per_round"])
        assert info["n_train_total"] == 3 * sum(info["usable_per_round"])
        assert info["held_out_by_simulation"] is True
    run_fit(tmp_path / "run", meas, cfg, make_plots=False)  # resumes: nothing to do
    with pytest.raises(SchemaError, match="sensor_draws"):
        run_fit(tmp_path / "run", meas, FitConfig(**{**cfg.__dict__, "sensor_draws": 3}), make_plots=False)


def test_a_grouped_split_holds_out_whole_simulations():
    """With groups, no simulation has samples on both sides; the held-out share is about the asked one; without
    groups the split is the plain permutation's (unchanged)."""
    from softsbi.inference.training import train_val_split
    groups = np.repeat(np.arange(40), 5)  # 40 simulations observed 5 times each
    tr, va = train_val_split(200, 0.1, np.random.default_rng(0), min_train=2, groups=groups)
    assert len(tr) + len(va) == 200 and set(tr).isdisjoint(va)
    assert not set(groups[tr]) & set(groups[va]) and 20 <= len(va) <= 25
    tr0, va0 = train_val_split(200, 0.1, np.random.default_rng(0), min_train=2)
    np.testing.assert_array_equal(np.r_[va0, tr0], np.random.default_rng(0).permutation(200))
    with pytest.raises(ValueError, match="groups must have shape"):
        train_val_split(10, 0.1, np.random.default_rng(0), groups=np.zeros(9))
