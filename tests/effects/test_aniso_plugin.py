"""Round trip of a third-party force-field effect (``tests/plugins/softsbi_aniso``, installed editable: anisotropic
table friction, the plugin-shape example; the built-in ``aniso-stretch``, a model edit of the membrane, is another
effect, tested in ``tests/effects/test_rig.py``):
listed by ``softsbi plugins``, applied by mujoco-flex without knowing it (``simulate``/``fit --effect``),
and, hidden in a measurement, diagnosed among the candidates and refitted."""
from __future__ import annotations

import json

import numpy as np
import pytest
import zarr
from typer.testing import CliRunner

from softsbi.cli import app
from softsbi.plugins import registry
from softsbi.core.defaults import DiagnoseSettings

runner = CliRunner()
NAME = "aniso-friction"

pytestmark = [pytest.mark.integration,
              pytest.mark.skipif(NAME not in registry().tables["effect"],
                                 reason="pip install -e tests/plugins/softsbi_aniso (README's install line)")]


def test_listed_by_plugins():
    res = runner.invoke(app, ["plugins", "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    row = next(e for e in doc["effects"] if e["name"] == NAME)
    assert row["package"].startswith("softsbi-aniso") and row["class"] == "softsbi_aniso.plugin.AnisotropicFriction"
    assert row["kind"] == "physics" and row["generic"] is False
    # a force field: every backend with the force door applies it, though softsbi's backends do not know its name
    assert row["backends"] == ["mujoco-flex", "newton-cloth"] and row["doors"] == ["force"]
    assert row["parameters"][0]["name"] == "rib_friction" and row["parameters"][0]["prior"] == [0.0, 3.0]
    assert {r["name"]: r["kind"] for r in doc["effects"]}["point-noise"] == "sensor"
    sims = {s["name"]: s for s in doc["simulators"]}
    assert NAME in sims["mujoco-flex"]["effects"] and NAME not in sims["pybullet-massspring"]["effects"]
    assert sims["mujoco-flex"]["effect_kinds"] == ["force", "model-edit", "observation"]


def _simulate(tmp_path, *extra):
    out = tmp_path / ("on" if extra else "off")
    res = runner.invoke(app, ["simulate", "--scenario", "wipe", "--backend-opt", "grid=5", "--out", str(out), "--json",
                              *extra])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    assert doc["status"] == 0, doc
    return doc, zarr.open_group(str(out / "rollout.zarr"), mode="r")["vertices"][...]


def test_simulate_applies_it(tmp_path):
    doc, on = _simulate(tmp_path, "--effect", NAME, "--theta", "rib_friction=1.5")
    _, off = _simulate(tmp_path)
    assert doc["theta"]["rib_friction"] == 1.5
    # dragged along +x over the ribbed table, the cloth lags behind along x
    assert (on[-1, :, 0] - off[-1, :, 0]).mean() < -0.005


def test_pybullet_refuses_it_naming_the_door(tmp_path):
    res = runner.invoke(app, ["simulate", "--backend", "pybullet-massspring", "--effect", NAME, "--out",
                              str(tmp_path / "pb")])
    assert res.exit_code == 2
    assert f"'{NAME}'" in res.output and "force field" in res.output  # the effect and the door it needs


def test_fit_infers_its_parameter(tmp_path, lift_dir):
    out = tmp_path / "fit"
    res = runner.invoke(app, ["fit", "--observed", str(lift_dir / "lift_tan"), "--out", str(out), "--effect", NAME,
                              "--rounds", "1", "--sims-per-round", "10", "--n-eval", "3", "--points", "16",
                              "--backend-opt", "grid=5", "--estimator-opt", "max_epochs=5", "--workers", "1",
                              "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert doc["effects"] == [NAME] and "rib_friction" in [p["name"] for p in doc["parameters"]]
    report = json.loads((out / "report.json").read_text())
    assert 0.0 <= report["posterior_mean"]["rib_friction"] <= 1.5


@pytest.mark.slow
def test_diagnose_screens_it(tmp_path, lift_dir):
    """``diagnose --effect aniso-friction`` on a (tiny) nominal fit screens it like any built-in (a null of 12
    posterior-predictive rollouts, grown to at most 39: the smallest that resolves the level 0.05)."""
    out = tmp_path / "nominal"
    res = runner.invoke(app, ["fit", "--observed", str(lift_dir / "lift_tan"), "--out", str(out), "--rounds", "1",
                              "--sims-per-round", "10", "--n-eval", "6", "--points", "16", "--backend-opt", "grid=5",
                              "--estimator-opt", "max_epochs=5", "--workers", "1", "--json"])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["diagnose", str(out), "--effect", NAME, "--effect", "air-drag", "--confirm", "0",
                              "--n-null", "12", "--max-null", "39", "--workers", "1", "--json"])
    assert res.exit_code == 0, res.output
    d = json.loads((out / "diagnosis.json").read_text())
    assert json.loads(res.stdout) == d and d["candidates"] == [NAME, "air-drag"] and d["refits"] == []
    rows = {r["effect"]: r for r in d["ranking"]}
    assert set(rows) == {NAME, "air-drag"} and set(d["test"]["family"]) == {NAME, "air-drag"}
    assert "rib_friction" in rows[NAME]["estimate"] and np.isfinite(rows[NAME]["explained"])


#: the fast round trip's measurement: a wipe on a ribbed table (friction 0.3 along y, 0.3 + 3.0 along x)
RIBBED = {"friction": 0.3, "rib_friction": 3.0}


def hidden_aniso_round_trip(tmp_path, seed: int = 0, refit_rounds: int = 2, refit_sims: int = 20,
                            nominal_sims: int = 20) -> dict:
    """The default suite's round trip at a small budget: the effect hidden in a simulated wipe
    (grid 5, 16 frames, 32 observed points), the nominal model fitted with only the isotropic friction
    inferred (the other nominal parameters held at the truth: ``fixed``), one round of 20 simulations;
    ``diagnose`` screens aniso-friction and wind against 12 posterior-predictive rollouts (screening only, at a
    level those 12 resolve: 2/13 <= 0.2); then the refit with the effect switched on (``refit_model``, what
    ``diagnose --confirm`` runs: 2 rounds x 20, truncated proposal) and check's test of the refit, over the
    family less the effect. Returns the diagnosis and the refit."""
    from softsbi.backends.mujoco_flex import MujocoFlex
    from softsbi.scenarios.builtin import wipe_scenario
    from softsbi.workflows.criticism.diagnose import diagnose_run, refit_model
    from softsbi.workflows.fit.run import FitConfig, run_fit
    from softsbi.workflows.measurement import simulate_recording
    from softsbi.workflows.fit.runs import load_run

    sc = wipe_scenario(n_frames=16)
    mid = MujocoFlex(grid=5).param_space(sc).midpoint()
    truth = {**mid, **RIBBED}
    meas = simulate_recording("mujoco-flex", sc, truth, backend_options={"grid": 5}, effects=[NAME], n_points=32,
                              n_dense=200, seed=7 + seed)
    cfg = FitConfig(backend="mujoco-flex", backend_options={"grid": 5}, rounds=1, sims_per_round=nominal_sims, n_eval=12,
                    n_points=32, n_dense=200, workers=1, seed=seed, proposal="truncated",
                    fixed={k: v for k, v in mid.items() if k != "friction"},
                    estimator_options={"max_epochs": 60, "ensemble": 1, "recalibrate": False})
    run = tmp_path / "nominal"
    run_fit(run, meas, cfg, make_plots=False)
    d = diagnose_run(
        run,
        effects=[NAME, "wind"],
        plots=False,
        settings=DiagnoseSettings(alpha=0.2, n_null=12, max_null=12, workers=1, confirm=0, seed=seed),
    )
    refit = refit_model(
        load_run(run),
        [NAME],
        d.candidates,
        rounds=refit_rounds,
        sims_per_round=refit_sims,
        plots=False,
        settings=DiagnoseSettings(alpha=0.2, n_null=12, max_null=12, workers=1),
    )
    return {"diagnosis": d, "refit": refit}


def test_hidden_aniso_is_screened_and_its_refit_lowers_the_error(tmp_path):
    """The third-party effect's round trip in the default suite (~40 s on 2 busy cores): hidden in the
    measurement, the nominal model cannot fit it (check's omnibus test: beyond all 12 rollouts), ``diagnose``
    screens it among the candidates (it explains part of the residual, with a linearised estimate), and
    the refit with it switched on lowers the posterior-predictive Chamfer (the sticking cloth that no
    isotropic friction produces) to a model whose rollouts no longer all lie inside the measurement's
    deviation, with a large rib friction.

    Measured over 14 seeds (0-13, this budget): misspecified beyond all rollouts 14/14; refit Chamfer
    drop 9-47% (median 30%) 14/14 > 5%; refit's omnibus check p >= 2/13 14/14; refit posterior mean rib_friction
    1.25-2.75 14/14 > 1.0 (truth 3.0); aniso-friction ranked first of the two candidates by the screening
    13/14 (explained 1-11% of the residual: the effect switches on abruptly above ~2.5, beyond what a
    finite difference at the nominal value sees), so the ranking is asserted in the slow version only."""
    from softsbi.workflows.fit.runs import load_run
    r = hidden_aniso_round_trip(tmp_path)
    d, refit = r["diagnosis"], r["refit"]
    m = d.test
    assert m.omnibus.value == pytest.approx(1 / 13) and m.n_null == 12  # beyond all 12 rollouts
    # the two tests' min-p combination against the same 12 rollouts: never below 1/13 nor above Bonferroni's
    assert m.p_value == m.combined.value and 1 / 13 <= m.p_value <= min(1.0, 2 * min(m.omnibus.value,
                                                                                    m.directional.value))
    rows = {c.effect: c for c in d.ranking}
    assert set(rows) == {NAME, "wind"} and rows[NAME].explained > 0
    assert rows[NAME].adjusted.value >= 1 / 13 and "rib_friction" in rows[NAME].estimate
    before = load_run(tmp_path / "nominal").report.chamfer_posterior_m
    assert refit.chamfer_m < 0.95 * before, (refit.chamfer_m, before)
    # check's test of the refit, over the family less the effect: the measurement no longer beyond all 12 rollouts
    # in the omnibus test (the joint p's resolution at 12 nulls is 1/13)
    after = refit.test
    assert after.family == ("wind",) and after.alpha == 0.2
    assert after.omnibus.value > 1 / 13 and after.n_null == 12, after
    assert after.p_value >= 2 / 13
    (rib,) = refit.estimates
    assert rib.name == "rib_friction" and rib.mean > 1.0, rib


@pytest.mark.slow
def test_hidden_aniso_is_diagnosed_and_refitted(tmp_path):
    """Wipe measured on a ribbed table (friction 0.3 along y, 0.3 + 3.0 along x) with the effect hidden;
    the nominal fit (4 rounds x 60, truncated proposals) is diagnosed with aniso-friction among 4
    candidates: it ranks in the top two of the screening, so it is refitted (--confirm 2); its refit lowers the
    posterior-predictive error by more than 10% and explains the misfit, so it is named (alone, or with a refit the
    data cannot tell from it). ~200 s on 2 busy cores."""
    from softsbi.backends.mujoco_flex import MujocoFlex
    from softsbi.scenarios.builtin import wipe_scenario
    from softsbi.workflows.criticism.diagnose import diagnose_run
    from softsbi.workflows.fit.run import FitConfig, run_fit
    from softsbi.workflows.measurement import simulate_recording

    sc = wipe_scenario(n_frames=16)
    truth = {**MujocoFlex(grid=5).param_space(sc).midpoint(), "friction": 0.3, "rib_friction": 3.0}
    meas = simulate_recording("mujoco-flex", sc, truth, backend_options={"grid": 5}, effects=[NAME], n_points=32,
                              n_dense=200, seed=7)
    cfg = FitConfig(backend="mujoco-flex", backend_options={"grid": 5}, rounds=4, sims_per_round=60, n_eval=10,
                    n_points=32, n_dense=200, workers=1, seed=0,
                    # one network, as when this round trip was measured (the calibrated ensemble default widens
                    # the posterior predictive: its refit drop was 6.9%, measured after the issue-16 merge)
                    estimator_options={"max_epochs": 60, "ensemble": 1, "recalibrate": False},
                    proposal="truncated")
    run = tmp_path / "nominal"
    run_fit(run, meas, cfg, make_plots=False)
    d = diagnose_run(
        run,
        effects=[NAME, "air-drag", "heavy-hem", "wind"],
        plots=False,
        settings=DiagnoseSettings(n_null=30, workers=1, confirm=2, refit_rounds=4, refit_sims=60),
    )
    ranked = [c.effect for c in d.ranking]
    assert NAME in ranked[:2], ranked
    r = d.refit((NAME,))
    assert r is not None, d.refits
    assert r.score.value < d.nominal.value, (r.score, d.nominal)
    assert d.verdict == "missing-effect", d.decision
    assert d.decision.named == (NAME,) or (NAME,) in d.decision.alternatives, d.decision
