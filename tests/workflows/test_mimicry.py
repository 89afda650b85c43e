"""The share of a physics effect's motion that another effect reproduces (softsbi.workflows.mimicry)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from softsbi.core.types import STATUS_DIVERGED, Rollout
from softsbi.effects.sensor import TimeOffset
from softsbi.workflows.mimicry import (
    MIMIC_SHARE,
    PHYSICS_EVALS,
    best_physics_match,
    best_sensor_match,
    motion_distance,
    physics_mimicry,
    standin_of,
)


def _moving_sheet(speed: float = 0.3, frames: int = 25) -> Rollout:
    """A 5 x 5 sheet rising at ``speed`` m/s with a slow sway, frames every 0.04 s."""
    t = np.arange(frames) * 0.04
    gx, gy = np.meshgrid(np.linspace(0, 0.2, 5), np.linspace(0, 0.2, 5))
    base = np.stack([gx.ravel(), gy.ravel(), np.zeros(25)], axis=1)
    verts = np.stack([base + [0.02 * np.sin(3 * ti), 0.0, speed * ti] for ti in t])
    return Rollout(times=t, gripper=verts[:, 0], vertices=verts, faces=np.zeros((0, 3), int))


def test_a_time_offset_is_recovered_from_the_motion_it_shifts():
    src = _moving_sheet()
    target = TimeOffset().observe(src, {"time_offset": -0.06}, np.random.default_rng(0))
    dist, est = best_sensor_match(target, src, "time-offset")
    assert dist < 1e-4 and est["time_offset"] == pytest.approx(-0.06, abs=2e-3)
    # a calibration offset cannot shift the motion in time: it reproduces a part only
    d_cal, _ = best_sensor_match(target, src, "calibration-offset")
    assert d_cal > 10 * dist
    assert motion_distance(target, src) > d_cal


def _refit(effects, pm, frames=None):
    from softsbi.scenarios.builtin import make_scenario
    return SimpleNamespace(report={"posterior_mean": pm}, effects=list(effects),
                           config={"backend": "mujoco-flex", "backend_options": {}}, scenario=make_scenario("lift"),
                           fixed={}, metric_frames=frames)


def test_a_time_offset_reproduces_most_of_a_soft_grasp_in_a_lift_and_little_of_a_wind():
    """Measured with the simulator (BENCHMARKS.md, twenty-ninth session): a time offset stands in for a soft grasp
    (time constant 0.22 s) in the lift, not for a wind."""
    pm = {"bend": 2.4e-4, "stretch": 49.0, "friction": 0.68, "scale": 0.267, "mass": 0.202}
    grip = physics_mimicry(_refit(["grip-compliance"], {**pm, "grip_timeconst": 0.22}), "grip-compliance",
                           "time-offset")
    assert grip["share"] > MIMIC_SHARE and -0.1 <= grip["standin_estimate"]["time_offset"] < -0.03
    assert grip["standin"] == "time-offset" and grip["standin_kind"] == "sensor"
    assert grip["residual_m"] < grip["effect_m"]
    # the nominal fit (no grip) with the screening's estimate of the grip: the same two rollouts, the same share
    nominal = physics_mimicry(_refit([], pm), "grip-compliance", "time-offset", estimate={"grip_timeconst": 0.22})
    assert nominal["share"] == pytest.approx(grip["share"])
    wind = physics_mimicry(_refit(["wind"], {**pm, "wind_x": 1.5, "wind_y": 0.0}), "wind",
                           "time-offset")
    assert wind["share"] < MIMIC_SHARE


def test_a_physics_stand_in_is_fitted_by_simulation_within_its_budget():
    """best_physics_match simulates the stand-in at each evaluation: a motion made by the stand-in itself is found
    again (to the search's tolerance), within PHYSICS_EVALS simulations per parameter; a stand-in whose every
    simulation fails gives no match."""
    src = _moving_sheet()
    calls = []

    def make(p):  # a "physics effect" whose parameter lifts the sheet by wind_x / 100 m
        calls.append(p)
        v = src.vertices + [0.0, 0.0, p["wind_x"] / 100.0]
        return Rollout(times=src.times, gripper=v[:, 0], vertices=v, faces=src.faces)

    target = make({"wind_x": 1.2, "wind_y": 0.0})
    calls.clear()
    dist, est = best_physics_match(target, make, "wind")
    assert dist < 2e-4 and est["wind_x"] == pytest.approx(1.2, abs=0.03)
    assert len(calls) <= 2 * PHYSICS_EVALS + 2  # wind has two parameters
    failed = Rollout(times=np.zeros(1), gripper=np.zeros((1, 3)), vertices=np.zeros((1, 1, 3)),
                     faces=np.zeros((0, 3), int), status=STATUS_DIVERGED)
    assert best_physics_match(target, lambda p: failed, "wind")[0] == float("inf")


def test_extra_damping_stands_in_for_air_drag_in_a_lift_but_a_soft_grasp_does_not():
    """With the simulator: air drag at 4 kg/m3 in the lift, reproduced by extra damping (both slow the cloth in
    proportion to its speed) and not by a soft grasp. The result names its stand-in; an older stored result (keys
    ``sensor``) still reads."""
    pm = {"bend": 2.4e-4, "stretch": 49.0, "friction": 0.68, "scale": 0.267, "mass": 0.202, "air_density": 4.0}
    damp = physics_mimicry(_refit(["air-drag"], pm), "air-drag", "extra-damping")
    assert damp["standin_kind"] == "physics" and damp["share"] > MIMIC_SHARE
    assert damp["standin_estimate"]["damping_rate"] > 0
    grip = physics_mimicry(_refit(["air-drag"], pm), "air-drag", "grip-compliance")
    assert grip["share"] < MIMIC_SHARE
    # the stand-in already in the fit: nothing to compare
    assert physics_mimicry(_refit(["air-drag", "extra-damping"], {**pm, "damping_rate": 1.0}), "air-drag",
                           "extra-damping") is None
    assert standin_of({"sensor": "time-offset", "sensor_estimate": {"time_offset": -0.03}}) == (
        "time-offset", {"time_offset": -0.03})


def test_no_measure_without_an_estimate_the_effect_or_a_rollout():
    pm = {"bend": 2.4e-4, "grip_timeconst": 0.2}
    assert physics_mimicry(_refit(["grip-compliance"], {}), "grip-compliance", "time-offset") is None
    assert physics_mimicry(_refit(["wind"], pm), "grip-compliance", "time-offset") is None
    assert physics_mimicry(_refit([], {}), "grip-compliance", "time-offset", estimate={"grip_timeconst": 0.2}) is None
    failed = Rollout(times=np.zeros(1), gripper=np.zeros((1, 3)), vertices=np.zeros((1, 1, 3)),
                     faces=np.zeros((0, 3), int), status=STATUS_DIVERGED)
    assert physics_mimicry(_refit(["grip-compliance"], pm), "grip-compliance", "time-offset",
                           simulate=lambda theta, effects: failed) is None
    # an effect that moves nothing at the estimate has no share to reproduce
    still = _moving_sheet()
    assert physics_mimicry(_refit(["grip-compliance"], pm), "grip-compliance", "time-offset",
                           simulate=lambda theta, effects: still) is None


def test_the_benchmark_measures_a_hidden_soft_grasp_and_tabulates_it(tmp_path):
    """benchmarks/mimicry.py on a stored benchmark case (mujoco 1324: a soft grasp in a lift, time constant 0.22 s):
    a time offset reproduces most of it, a calibration offset almost nothing; the table marks the share at or above
    MIMIC_SHARE."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location(
        "mimicry_bench", Path(__file__).resolve().parents[2] / "benchmarks" / "mimicry.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    bench.main(["--suite", "mujoco", "--cases", "1324", "--out", str(tmp_path / "m.jsonl")])
    row = __import__("json").loads((tmp_path / "m.jsonl").read_text())
    assert row["effect"] == "grip-compliance" and row["scenario"] == "lift"
    assert row["sensors"]["time-offset"]["share"] > MIMIC_SHARE > row["sensors"]["calibration-offset"]["share"]
    text = bench.table(tmp_path / "m.jsonl")
    assert "| mujoco 1324 | grip-compliance | lift, 0.92 |" in text and text.count("**") == 2
