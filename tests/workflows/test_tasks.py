"""A task is trained once: a fit's first round is stored as the task and conditioned, not trained, for every later
recording of it; ``task train`` trains one with its training report, and the CLI lists, shows and deletes them."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from softsbi.core.results.fitreport import TrainingReport

pytestmark = pytest.mark.integration


def _cfg(**kw):
    from softsbi.workflows.fit.run import FitConfig
    base = dict(backend="toy-gauss", rounds=1, sims_per_round=40, workers=1, n_points=16, n_dense=64, n_eval=5,
                estimator="mdnn", estimator_options={"max_epochs": 8})
    return FitConfig(**{**base, **kw})


def _counting_fits(monkeypatch):
    from softsbi.plugins import registry
    cls = registry().estimator("mdnn")
    calls = []
    original = cls.fit
    monkeypatch.setattr(cls, "fit", lambda self, *a, **k: calls.append(len(a[0])) or original(self, *a, **k))
    return calls


def test_a_later_recording_of_a_task_conditions_the_stored_first_round_instead_of_training_it(tmp_path, monkeypatch):
    pytest.importorskip("softsbi_toy.plugin")
    from toy_helpers import toy_measurement
    from softsbi.workflows.fit.run import run_fit
    from softsbi.workflows.fit.rounds import round_posterior
    from softsbi.workflows.fit.task_store import TaskStore
    monkeypatch.setenv("SOFTSBI_SIM_BANK", str(tmp_path / "bank"))
    calls = _counting_fits(monkeypatch)
    run_fit(tmp_path / "a", toy_measurement(truth=(0.3, -0.4)), _cfg(), make_plots=False)
    assert calls == [40] and len(TaskStore(tmp_path / "bank" / "tasks").list()) == 1
    rec = toy_measurement(truth=(-0.2, 0.1))
    b = run_fit(tmp_path / "b", rec, _cfg(), make_plots=False)
    assert calls == [40]  # the second recording trained nothing
    auto = run_fit(tmp_path / "b4", rec, _cfg(rounds=None, sims_per_round=40), make_plots=False)
    assert auto.report.rounds == 4  # a task stored by a fit starts the sequential rounds; it is not the posterior
    info = b.store.round_attrs(0)["info"]
    assert info["trained_here"] is False and info["task"] == TaskStore(tmp_path / "bank" / "tasks").list()[0].digest
    assert b.report.per_round[0].task == info["task"]  # the report names the task that served the round
    assert calls == [40, 80, 120, 160]  # its rounds 2-4 trained on all so far, round 1 not
    scratch = run_fit(tmp_path / "c", rec, _cfg(sim_bank="off"), make_plots=False)  # no bank: no stored task
    assert len(calls) == 5
    qb = round_posterior(b.store, 0, _cfg())
    qc = round_posterior(scratch.store, 0, _cfg())
    np.testing.assert_allclose(qb.mean(), qc.mean(), atol=1e-8)  # the stored task is what training would give
    # another prior is another task: trained, and stored beside the first
    run_fit(tmp_path / "d", rec, _cfg(bounds={"a": (-2.0, 2.0)}), make_plots=False)
    assert len(calls) == 6 and len(TaskStore(tmp_path / "bank" / "tasks").list()) == 2


def test_task_train_stores_a_training_report_and_a_fit_starts_from_its_prior_simulations(tmp_path, monkeypatch):
    pytest.importorskip("softsbi_toy.plugin")
    from toy_helpers import toy_measurement
    from softsbi.workflows.fit.run import run_fit
    from softsbi.workflows.tasks.training import train_task
    monkeypatch.setenv("SOFTSBI_SIM_BANK", str(tmp_path / "bank"))
    rec = toy_measurement(truth=(0.3, -0.4))
    said = []
    (task,) = train_task(rec, _cfg(), 80, candidates=[], n_test=30, n_draws=50, check_null=0, message=said.append)
    # its cost, said before it starts: the simulations and the time one of them took, and totals per model
    assert said[0].startswith("task train plan: 1 model x (80 prior + 30 held-out simulations) = 110 simulations at "
                              "most; one simulation took ") and " on 1 worker, plus the training" in said[0]
    assert said[1] == "model 1 of 1: nominal (simulations 1-110 of 110 at most)"
    rep = task.report
    assert task.n_prior == 80 and rep.n_test == 30 and set(rep.contraction) == {"a", "b"}
    assert len(rep.sbc.rejects) == 2 and 0 <= rep.coverage.at_90 <= 1 and rep.verdict
    assert TrainingReport.from_json(rep.to_json()) == rep  # stored and read back as it was
    calls = _counting_fits(monkeypatch)
    said.clear()
    again = train_task(rec, _cfg(), 80, candidates=[], n_test=30, n_draws=50, check_null=0, message=said.append)[0]
    # the bank holds its first simulation, so the plan times one outside the bank (a bank read measures nothing)
    assert " one simulation took " in said[0] and "unknown" not in said[0], said[0]
    assert calls == [] and again.digest == task.digest  # stored with its report: not trained again
    rec2 = toy_measurement(truth=(-0.1, 0.2))
    res = run_fit(tmp_path / "run", rec2, _cfg(sims_per_round=20, rounds=None), make_plots=False)
    # by default a stored task's posterior alone: one round, whose 20 draws are the first of the task's 80, no training
    assert calls == [] and res.report.rounds == 1 and len(res.store.round_data(0)["status"]) == 20
    np.testing.assert_array_equal(res.store.round_data(0)["u"], np.random.default_rng([0, 0, 0]).random((80, 2))[:20])
    # calibrate names the training report of the task that served round 1 (the sentence, with its numbers:
    # tests/report/test_fit_text.py); a run whose first round was trained here has none
    from softsbi.workflows.tasks.calibrate import trained_task_line
    from softsbi.workflows.fit.task_store import served_by_task
    info = res.store.round_attrs(0)["info"]
    assert served_by_task(info) and info["task"] == task.digest
    line = trained_task_line(info, "default")
    assert line is not None and task.digest[:12] in line and rep.verdict in line
    scratch = run_fit(tmp_path / "scratch", rec2, _cfg(sims_per_round=10, rounds=None, sim_bank="off"),
                      make_plots=False)
    assert scratch.report.rounds == 4 and len(calls) == 4  # no stored task: the sequential default
    assert trained_task_line(scratch.store.round_attrs(0)["info"], "default") is None
    # a first round larger than the task's prior simulations cannot use it: said, not silent
    from softsbi.workflows.fit.run import FitCallbacks
    said = []

    class Told(FitCallbacks):
        def message(self, text):
            said.append(text)

    run_fit(tmp_path / "more", rec2, _cfg(sims_per_round=90, rounds=1), callbacks=Told(), make_plots=False)
    assert any(f"stored task {task.digest[:12]} was trained on 80 prior simulations, fewer than this round's 90: "
               f"not used" in m for m in said), said


def test_a_fit_of_the_stored_tasks_posterior_alone_draws_no_simulation_of_a_round(tmp_path, monkeypatch):
    """``task_only`` (what an amortised refit stores): round 1 is the trained task conditioned on the recording, with
    no simulation of its own, neither simulated nor read from the bank; its posterior is the one-round fit's that
    reads them; it resumes as stored, and what needs a round's simulations says it has none."""
    pytest.importorskip("softsbi_toy.plugin")
    from toy_helpers import toy_measurement
    from softsbi.core.errors import SoftsbiError
    from softsbi.workflows.fit import jobs
    from softsbi.workflows.fit.run import run_fit
    from softsbi.workflows.fit.runs import open_run
    from softsbi.workflows.tasks.calibrate import calibrate_run
    from softsbi.workflows.tasks.training import train_task
    monkeypatch.setenv("SOFTSBI_SIM_BANK", str(tmp_path / "bank"))
    rec = toy_measurement(truth=(-0.1, 0.2))
    with pytest.raises(SoftsbiError, match="no trained task"):  # nothing stored yet: refused before any simulation
        run_fit(tmp_path / "none", rec, _cfg(rounds=None), make_plots=False, task_only=True)
    (task,) = train_task(toy_measurement(), _cfg(), 80, candidates=[], n_test=20, n_draws=50, check_null=0)
    seeds = []
    simulate = jobs.simulate_job
    monkeypatch.setattr(jobs, "simulate_job", lambda ctx, item, batch=None: seeds.append(item.seed)
                        or simulate(ctx, item, batch))
    res = run_fit(tmp_path / "alone", rec, _cfg(rounds=None), make_plots=True, task_only=True)
    # its 5 posterior-predictive rollouts, nothing of round 1 (task train's prior seeds)
    assert sorted(seeds) == sorted(jobs.evaluation_seeds(0, 1, 5).tolist())
    assert res.report.rounds == 1 and res.report.simulations == 5 and res.report.chamfer_prior_m is None
    assert len(res.store.round_data(0)["status"]) == 0 and res.report.per_round[0].task == task.digest
    read = run_fit(tmp_path / "read", rec, _cfg(rounds=None), make_plots=False)  # reads round 1 from the bank
    assert len(read.store.round_data(0)["status"]) == 40 and read.report.chamfer_prior_m is not None
    a, b = open_run(tmp_path / "alone").posterior, open_run(tmp_path / "read").posterior
    np.testing.assert_allclose(a.unit.chain.qs[0].mean(), b.unit.chain.qs[0].mean())  # one posterior
    np.testing.assert_allclose(list(a.mean.values()), list(b.mean.values()), atol=0.02)
    seeds.clear()
    again = run_fit(tmp_path / "alone", rec, _cfg(rounds=None), make_plots=False)  # resumed: all stored
    assert again.report.simulations == 5 and len(again.store.round_data(0)["status"]) == 0
    with pytest.raises(SoftsbiError, match="holds no simulations of its own"):
        calibrate_run(tmp_path / "alone", n_test=20, n_draws=50, workers=1)
    with pytest.raises(SoftsbiError, match="one round"):
        run_fit(tmp_path / "two", rec, _cfg(rounds=2), make_plots=False, task_only=True)


def test_task_train_s_plan_and_the_advice_on_a_model_that_is_not_calibrated():
    """The cost of a task of 13 models with check's calibration, and what to do about uncalibrated models (and
    that fits use them anyway), from fixed numbers and reports."""
    from types import SimpleNamespace

    from softsbi.workflows.tasks.training import calibration_advice, training_plan
    # the nominal model's replicates calibrate the detection (screened); each candidate model's its refit's check
    # (the omnibus test alone, not screened)
    assert training_plan(13, 2000, 200, 100, 1.2, 8, null_rollouts=30, screening=60, refit_null=19) == (
        "task train plan: 13 models x (2000 prior + 200 held-out simulations) + 100 replicate recordings x 91 for the "
        "nominal check's calibration + 12 x 19 x 31 for the refits' checks = 44768 simulations at most; one "
        "simulation took 1.2 s, so about 1.9 h on 8 workers, plus the training (fewer when stored models or the "
        "simulation bank hold some)")
    assert training_plan(18, 1000, 200, 40, None, 2, null_rollouts=30, screening=60, refit_null=19,
                         sensor_models=5).startswith(
        "task train plan: 13 models x (1000 prior + 200 held-out simulations) (and 5 sensor models, whose simulations "
        "are the nominal model's) + 40 replicate recordings x 91 for the nominal check's calibration + 17 x 19 x 31 "
        "for the refits' checks = 29253 simulations at most")
    assert training_plan(2, 100, 0, 0, None, 1) == (
        "task train plan: 2 models x (100 prior + 0 held-out simulations) = 200 simulations at most (one "
        "simulation's time unknown: it failed)")
    assert training_plan(1, 100, 0, 40, None, 1, null_rollouts=30, refit_null=19).endswith(
        "+ 40 replicate recordings x 31 for the nominal check's calibration = 1340 simulations at most (one "
        "simulation's time unknown: it failed)")  # no candidate: no refit's replicates

    # the README's one-liner says what a default task train costs, with the built-in effects
    from pathlib import Path

    from softsbi.plugins import registry
    from softsbi.core import defaults as D
    from softsbi.workflows.tasks.training import candidate_models
    models = [m for m in candidate_models(_cfg(backend=D.BACKEND), None)
              if all(registry().effect(e).__module__.startswith("softsbi.") for e in m)]
    from softsbi.scenarios.builtin import make_scenario
    from softsbi.workflows.criticism.screening import screening_size
    from softsbi.workflows.fit.config import fit_param_space
    from softsbi.workflows.tasks.training import replicate_family
    lift = make_scenario(D.SCENARIO)
    family = replicate_family(_cfg(backend=D.BACKEND), SimpleNamespace(scenario=lift), [m[-1] for m in models[1:]])
    per = D.N_NULL + 1 + screening_size(fit_param_space(_cfg(backend=D.BACKEND), lift)[1].dim, family)
    refit = D.REFIT_REPLICATES * (D.N_NULL + 1)
    from softsbi.workflows.fit.jobs import sensor_parameters
    sensor = sum({p.name for p in registry().effect(m[-1])().param_space()} <= sensor_parameters(D.BACKEND, m)
                 for m in models[1:])
    readme = " ".join((Path(__file__).parents[2] / "README.md").read_text().replace("#", " ").split())
    assert (f"{len(models) - sensor} models x {D.TASK_PRIOR_SIMS + D.N_TEST} simulations (the {sensor} sensor models' "
            f"are the nominal model's) + {D.CHECK_REPLICATES * per} (the nominal check's calibration) + "
            f"{len(models) - 1} x {refit} (the refits' checks)") in readme
    total = (len(models) - sensor) * (D.TASK_PRIOR_SIMS + D.N_TEST) + D.CHECK_REPLICATES * per + \
        (len(models) - 1) * refit
    assert f"at most {round(total, -2):,} simulations" in readme
    # the nominal's replicates are screened as a check screens a recording: their finite differences are counted
    assert "40 replicate recordings x 91 for the nominal check's calibration" in training_plan(
        17, 1000, 200, 40, None, 2, null_rollouts=30, screening=60)

    def task(model, calibrated):
        return SimpleNamespace(model=model, n_prior=2000, report=SimpleNamespace(calibrated=calibrated))
    assert calibration_advice([task("nominal", True), SimpleNamespace(model="x", n_prior=40, report=None)]) is None
    assert calibration_advice([task("nominal", True), task("nominal+wind", False)]) == (
        "1 of the 2 models is not calibrated on its held-out simulations (nominal+wind). Fits of the task use it "
        "anyway (a fit of a new recording stops at the stored posterior after one round), so its intervals may be too "
        "narrow or too wide: train again on more prior simulations (`softsbi task train ... --prior-sims 4000` "
        "retrains it), or delete it (`softsbi task delete KEY`) so that fits run their own sequential rounds.")


def test_the_cli_lists_shows_and_deletes_stored_tasks(tmp_path, monkeypatch):
    pytest.importorskip("softsbi_toy.plugin")
    from toy_helpers import toy_measurement
    from softsbi.workflows.fit.run import run_fit
    monkeypatch.setenv("SOFTSBI_SIM_BANK", str(tmp_path / "bank"))
    run_fit(tmp_path / "a", toy_measurement(), _cfg(), make_plots=False)

    def cli(*args):
        return subprocess.run([sys.executable, "-m", "softsbi.cli", "task", *args], capture_output=True, text=True)

    listed = json.loads(cli("list", "--json").stdout)
    assert len(listed) == 1 and listed[0]["model"] == "nominal" and listed[0]["n_prior"] == 40
    key = listed[0]["key"]
    shown = cli("show", key[:8])
    assert shown.returncode == 0 and key in shown.stdout
    doc = json.loads(cli("show", key[:4], "--json").stdout)  # the first 4 characters of the key suffice
    assert doc["key"] == key and doc["report"] is None  # stored by a fit: no training report
    bad = cli("show", key[:3], "--json")  # fewer are refused, even when they match one task
    assert bad.returncode != 0 and json.loads(bad.stdout)["type"] == "SoftsbiError"
    assert cli("delete", key[:8]).returncode == 0
    assert json.loads(cli("list", "--json").stdout) == []


def test_task_train_on_the_command_line_trains_the_nominal_model_and_says_what_it_stored(tmp_path, monkeypatch):
    pytest.importorskip("softsbi_toy.plugin")
    monkeypatch.setenv("SOFTSBI_SIM_BANK", str(tmp_path / "bank"))

    def cli(*args):
        return subprocess.run([sys.executable, "-m", "softsbi.cli", *args], capture_output=True, text=True,
                              cwd=tmp_path)

    assert cli("simulate", "--backend", "toy-gauss", "--out", "rec").returncode == 0
    bad = cli("task", "train", "--observed", "rec", "--backend", "toy-gauss", "--prior-sims", "5")
    assert bad.returncode == 2 and "--prior-sims" in bad.stdout + bad.stderr  # refused before any work
    done = cli("task", "train", "--observed", "rec", "--backend", "toy-gauss", "--prior-sims", "40", "--n-test", "20",
               "--candidates", "none", "--estimator", "mdnn", "--workers", "1", "--check-null", "0", "--json")
    assert done.returncode == 0, done.stderr
    (doc,) = json.loads(done.stdout)
    assert doc["model"] == "nominal" and doc["n_prior"] == 40 and doc["report"]["n_test"] == 20
    assert [t["key"] for t in json.loads(cli("task", "list", "--json").stdout)] == [doc["key"]]


@pytest.mark.slow
def test_a_trained_tasks_check_is_calibrated_against_replicate_recordings_refitted_the_same_way(tmp_path, monkeypatch):
    pytest.importorskip("softsbi_toy.plugin")
    from toy_helpers import toy_measurement
    from softsbi.core.errors import SoftsbiError
    from softsbi.workflows.criticism.check import check_run
    from softsbi.workflows.criticism.check_null import stored_check_null
    from softsbi.core.defaults import N_NULL
    from softsbi.workflows.fit.run import run_fit
    from softsbi.workflows.tasks.training import train_task
    monkeypatch.setenv("SOFTSBI_SIM_BANK", str(tmp_path / "bank"))
    rec = toy_measurement(truth=(0.3, -0.4))
    with pytest.raises(SoftsbiError, match="--check-null 5: .* needs n >= 19"):
        train_task(rec, _cfg(), 60, candidates=[], n_test=0, check_null=5)  # refused before any simulation
    assert not (tmp_path / "bank").exists()
    (task,) = train_task(rec, _cfg(), 60, candidates=[], n_test=20, n_draws=50, check_null=19)
    null = stored_check_null(task, N_NULL, 64)
    assert null is not None and len(null.statistics) == 19 and np.all(np.isfinite(null.statistics))
    assert stored_check_null(task, N_NULL + 1, 64) is None  # other check settings: not this null
    fit = run_fit(tmp_path / "run", toy_measurement(truth=(-0.1, 0.2)), _cfg(sims_per_round=20, rounds=None),
                  make_plots=False)
    assert fit.report.rounds == 1
    chk = check_run(tmp_path / "run", plot=False, effects=[])
    # the run's omnibus statistic on its evaluation rollouts, against the 19 replicates': p >= 1/20
    assert chk.test.calibrated and chk.test.omnibus == null.p_value(chk.test.statistic)
    assert chk.test.omnibus.n == 19 and chk.test.p_value >= 1 / 20
    # both tests against the default family, as the replicates were screened: their min-p combination against the
    # replicates' pairs; another family is not the replicates' procedure, so that check is not calibrated
    assert null.family and len(null.directional) == 19 and len(null.directional[0]) == len(null.family)
    both = check_run(tmp_path / "run", plot=False, recompute=True)
    assert both.test.family == null.family and both.test.directional is not None
    assert both.test.calibrated and both.test.combined is not None and both.test.combined.n == 19
    assert both.test.combined == null.joint_p_value(np.array([both.test.statistic, both.test.directional_statistic]),
                                                    null.family)
    scratch = run_fit(tmp_path / "scratch", rec, _cfg(sims_per_round=20, rounds=2), make_plots=False)
    assert scratch.report.rounds == 2
    assert not check_run(tmp_path / "scratch", plot=False, effects=[]).test.calibrated  # sequential: not the task's


def test_failed_replicates_are_named_and_left_out_when_enough_fitted(tmp_path, monkeypatch):
    """1 of 19 replicates that failed to simulate failed task train at its end in a line that named neither the
    model, the replicate nor its parameters. The calibration needs 19 (a p-value from k replicates is at least
    1/(k+1)): with 18 the line names them all; with 20, the 19 that fitted are kept and the failed one is told."""
    pytest.importorskip("softsbi_toy.plugin")
    from toy_helpers import toy_measurement
    from softsbi.core.defaults import N_NULL
    from softsbi.core.errors import SoftsbiError
    from softsbi.workflows.criticism.check_null import stored_check_null
    from softsbi.workflows.tasks.training import train_task
    monkeypatch.setenv("SOFTSBI_SIM_BANK", str(tmp_path / "bank"))
    monkeypatch.setenv("SOFTSBI_TOY_DIVERGE_ABOVE", "0.95")  # of the first 20 replicates, the 9th (a = 0.984) only
    rec = toy_measurement(truth=(0.3, -0.4))
    failed = "replicate 9 at a=0.9839, b=-0.09692: the measurement simulation failed: toy divergence: a = 0.984 > 0.95"
    with pytest.raises(SoftsbiError) as err:
        train_task(rec, _cfg(), 60, candidates=[], n_test=0, check_null=19)
    line = str(err.value)
    assert "\n" not in line and line.startswith("nominal: only 18 of 19 replicate recordings could be fitted and "
                                                "checked, and check's calibration needs 19 ") and failed in line, line
    assert "--check-null 22" in line and "--bounds" in line
    said = []
    (task,) = train_task(rec, _cfg(), 60, candidates=[], n_test=0, check_null=20, message=said.append)
    null = stored_check_null(task, N_NULL, 64)
    assert null is not None and len(null.statistics) == 19 and len(null.directional) == 19
    (kept,) = [s for s in said if "replicates fitted and checked" in s]
    assert kept.startswith("nominal: 19 of 20 replicates fitted and checked") and f"left out: {failed}" in kept, kept


def test_a_replicate_its_fit_could_not_check_is_no_replicate():
    """A recording whose posterior puts no mass in the prior box (its fit fails) gives no statistic."""
    pytest.importorskip("softsbi_toy.plugin")
    from toy_helpers import toy_measurement
    from softsbi.core.distributions import MixtureOfGaussians
    from softsbi.workflows.criticism.check_null import case_statistics
    from softsbi.workflows.fit.config import fit_param_space
    from softsbi.workflows.fit.task_store import first_round_context
    rec = toy_measurement()
    cfg = _cfg().resolved(rec)
    _, space = fit_param_space(cfg, rec.scenario)

    class Outside:  # every posterior far outside the unit box
        def posterior_at(self, x):
            return MixtureOfGaussians(np.ones(1), np.full((1, 2), 9.0), 0.01 * np.eye(2)[None])

    st = case_statistics([rec], Outside(), cfg, space, first_round_context(cfg, rec, space), 30, [1], 1)
    assert st.shape == (1, 2) and np.isnan(st).all()


def test_task_train_times_a_warm_simulation_outside_the_bank(tmp_path, monkeypatch):
    """A worker's start-up (the engine's construction) is paid once per worker, not per simulation, and timing it
    overstated a lift's training about 5 times; and after any fit the bank holds the prior simulations task train
    would time, and a bank read measures nothing. The plan times a simulation in a warm worker, outside the bank,
    and stores nothing."""
    pytest.importorskip("softsbi_toy.plugin")
    from toy_helpers import toy_measurement
    from softsbi.workflows.fit import jobs
    from softsbi.workflows.tasks.training import pilot_seconds
    bank = tmp_path / "bank"
    monkeypatch.setenv("SOFTSBI_SIM_BANK", str(bank))
    jobs._WORKER_CACHE.clear()  # a cold worker: its first simulation builds the engine
    monkeypatch.setenv("SOFTSBI_TOY_SLEEP", "0.3")
    monkeypatch.setenv("SOFTSBI_TOY_START_SLEEP", "2")
    seconds = pilot_seconds(toy_measurement(), _cfg())
    assert seconds is not None and 0.3 <= seconds < 2  # a simulation run here, without the worker's start-up
    assert not [p for p in bank.rglob("*") if p.is_file() and p.relative_to(bank).parts[0] != "tasks"]


def test_a_task_trained_without_held_out_simulations_is_listed_as_such_and_reused(tmp_path, monkeypatch):
    """`task train --n-test 0` stored a task that `task list` called "stored by a fit"; it is trained by task
    train, without a calibration report, and a second `--n-test 0` reuses it."""
    pytest.importorskip("softsbi_toy.plugin")
    from typer.testing import CliRunner
    from toy_helpers import toy_measurement
    from softsbi.cli import app
    from softsbi.workflows.fit.run import run_fit
    from softsbi.workflows.tasks.training import train_task
    bank = tmp_path / "bank"
    monkeypatch.setenv("SOFTSBI_SIM_BANK", str(bank))
    rec = toy_measurement()
    (task,) = train_task(rec, _cfg(), 40, candidates=[], n_test=0, check_null=0)
    assert task.report is None
    fit = run_fit(tmp_path / "fit", rec, _cfg(bounds={"a": (-2.0, 2.0)}), make_plots=False)  # another task's first
    by_fit = fit.store.round_attrs(0)["info"]["task"]
    res = CliRunner().invoke(app, ["task", "list", "--sim-bank", str(bank)])
    assert res.exit_code == 0, res.output
    rows = {key: " ".join(ln.split()) for ln in res.output.splitlines() for key in (task.digest, by_fit)
            if key[:12] in ln}
    assert "trained without a calibration report (--n-test 0)" in rows[task.digest], res.output
    assert "no training report (stored by a fit)" in rows[by_fit], res.output
    shown = " ".join(CliRunner().invoke(app, ["task", "show", task.digest[:8], "--sim-bank", str(bank)]).output.split())
    assert "trained without a calibration report (--n-test 0): fits of the task start their sequential rounds" in shown
    calls, said = _counting_fits(monkeypatch), []
    (again,) = train_task(rec, _cfg(), 40, candidates=[], n_test=0, check_null=0, message=said.append)
    assert calls == [] and again.digest == task.digest and any("reused" in s for s in said), said


@pytest.mark.slow
def test_sigint_stops_task_train_even_when_started_ignoring_it_and_no_stopped_phase_is_done(tmp_path):
    """A script's background job inherits SIGINT ignored: `kill -INT` left `task train` running. A phase stopped by
    it printed "done in N s"."""
    import os
    import signal
    pytest.importorskip("softsbi_toy.plugin")
    from toy_helpers import REPO
    env = dict(os.environ, SOFTSBI_TOY_SLEEP="0.2",
               PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    assert subprocess.run([sys.executable, "-m", "softsbi.cli", "simulate", "--backend", "toy-gauss", "--out", "rec"],
                          cwd=tmp_path, capture_output=True, env=env, check=False).returncode == 0
    proc = subprocess.Popen([sys.executable, "-m", "softsbi.cli", "task", "train", "--observed", "rec", "--backend",
                             "toy-gauss", "--prior-sims", "100", "--n-test", "0", "--check-null", "0", "--candidates",
                             "none", "--workers", "1", "--sim-bank", "bank"], cwd=tmp_path, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    said = []
    for line in proc.stderr:  # until the prior simulations have begun
        said.append(line)
        if "prior simulations: 100 simulations" in line:
            break
    proc.send_signal(signal.SIGINT)
    _, rest = proc.communicate(timeout=60)
    err = "".join(said) + rest
    assert proc.returncode == 130, err
    # the phase the interrupt stopped is not said to be done (the timed first simulation before it is)
    assert "interrupted; finished simulations are kept" in err and "Traceback" not in err
    assert "prior simulations: done in" not in err


def test_task_train_refuses_contradictory_or_empty_candidates_and_too_few_test_simulations(tmp_path):
    """`--candidates ',,'` meant none, a candidate named twice was trained twice, and `--n-test 5` got a
    "calibrated" report: each is one line before any work."""
    pytest.importorskip("softsbi_toy.plugin")
    from typer.testing import CliRunner
    from softsbi.cli import app
    from softsbi.core.errors import SoftsbiError
    from softsbi.workflows.tasks.training import candidate_models
    rec = tmp_path / "rec"
    assert CliRunner().invoke(app, ["simulate", "--backend", "toy-gauss", "--out", str(rec)]).exit_code == 0
    base = ["task", "train", "--observed", str(rec), "--backend", "toy-gauss", "--sim-bank", str(tmp_path / "bank"),
            "--workers", "1"]
    for args, message in ((["--candidates", ",,"], "--candidates ',,' names no effect"),
                          (["--candidates", "toy-wind,toy-wind"], "--candidates names toy-wind more than once"),
                          (["--n-test", "5"], "'--n-test': must be 0 (no training report) or >= 20 (got 5)")):
        res = CliRunner().invoke(app, base + args)
        assert res.exit_code == 2 and message in " ".join(res.output.replace("│", " ").split()), res.output
        assert "Traceback" not in res.output
    assert not (tmp_path / "bank" / "tasks").exists()  # nothing trained
    with pytest.raises(SoftsbiError, match="more than once"):
        candidate_models(_cfg(), ["toy-wind", "toy-wind"])
    assert candidate_models(_cfg(), ["toy-wind"]) == [[], ["toy-wind"]]


def test_task_list_names_the_backend_options():
    from softsbi.cli.task_cmd import _backend
    assert _backend({"backend": "newton-cloth", "backend_options": {"grid": 8, "damping": 0.1}}) == \
        "newton-cloth (damping=0.1, grid=8)"
    assert _backend({"backend": "toy-gauss", "backend_options": {}}) == "toy-gauss"


def test_a_task_store_that_cannot_take_the_task_is_refused_before_training(tmp_path, monkeypatch):
    """`tasks/tmp` a file, `check-null.json` a folder and a full disk failed only after all the training."""
    pytest.importorskip("softsbi_toy.plugin")
    from toy_helpers import toy_measurement
    from softsbi.core.errors import SoftsbiError, StorageError
    from softsbi.workflows.tasks.training import train_task
    calls = _counting_fits(monkeypatch)
    rec = toy_measurement(truth=(0.3, -0.4))
    bank = tmp_path / "bank"
    (bank / "tasks").mkdir(parents=True)
    (bank / "tasks" / "tmp").write_text("")
    with pytest.raises(SoftsbiError, match=r"tasks/tmp' is a file where the task store writes its entries"):
        train_task(rec, _cfg(sim_bank=str(bank)), 40, candidates=[], n_test=0, check_null=0)
    assert calls == [] and len(list(bank.iterdir())) == 1  # no training, no simulation stored
    (bank / "tasks" / "tmp").unlink()
    (task,) = train_task(rec, _cfg(sim_bank=str(bank)), 40, candidates=[], n_test=20, n_draws=50, check_null=0)
    (task.path / "check-null.json").mkdir()
    with pytest.raises(SoftsbiError, match="check-null.json' is a folder"):  # refused before the replicates
        train_task(rec, _cfg(sim_bank=str(bank)), 40, candidates=[], n_test=20, n_draws=50, check_null=19)
    assert calls == [40]
    disk = tmp_path / "disk"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(disk)], capture_output=True,
                      check=False).returncode:
        return  # a full disk needs a tmpfs (root); the refusals above hold without one
    try:
        with open(disk / "filler", "wb") as fh:
            with pytest.raises(OSError):
                while True:
                    fh.write(b"\0" * 65536)
                    fh.flush()
        with pytest.raises(StorageError, match="no space left on the device"):
            train_task(rec, _cfg(sim_bank=str(disk / "bank")), 40, candidates=[], n_test=0, check_null=0)
        assert calls == [40]
    finally:
        subprocess.run(["umount", "-l", str(disk)], capture_output=True, check=False)


def test_a_second_task_train_of_one_task_waits_for_the_first_and_reuses_its_task(tmp_path, monkeypatch):
    import threading
    pytest.importorskip("softsbi_toy.plugin")
    from toy_helpers import toy_measurement
    from softsbi.workflows.fit.task_store import TaskStore
    from softsbi.workflows.tasks.training import train_task
    rec = toy_measurement(truth=(0.3, -0.4))
    (trained,) = train_task(rec, _cfg(sim_bank=str(tmp_path / "a")), 40, candidates=[], n_test=20, n_draws=50,
                            check_null=0)
    store, said, asked = TaskStore(tmp_path / "b" / "tasks"), [], threading.Event()

    def other_process():  # holds the task's lock, and stores the task once the second one waits
        with store.lock(trained.digest):
            held.set()
            asked.wait(60)
            store.put(trained.identity, trained.n_prior, trained.estimator, trained.info, trained.report)

    held = threading.Event()
    other = threading.Thread(target=other_process)
    other.start()
    held.wait(60)
    calls = _counting_fits(monkeypatch)

    def told(text):
        said.append(text)
        if "being trained by another process" in text:
            asked.set()

    (task,) = train_task(rec, _cfg(sim_bank=str(tmp_path / "b")), 40, candidates=[], n_test=20, n_draws=50,
                         check_null=0, message=told)
    other.join()
    assert any(f"task {trained.digest[:12]} is being trained by another process; waiting" in m for m in said), said
    assert calls == [] and task.digest == trained.digest and "reused" in said[-1]


def test_a_sensor_models_prior_and_held_out_simulations_are_the_nominal_models_rollouts(tmp_path, monkeypatch):
    """A model with a sensor effect (an observation transform alone) draws the cloth parameters of the model without
    it, at the same seeds, so its prior and held-out simulations are the nominal model's rollouts read from the bank
    with the transform applied: task train simulates nothing for it. Its own parameters are still drawn uniformly."""
    pytest.importorskip("softsbi_toy.plugin")
    from toy_helpers import toy_measurement
    from softsbi.workflows.fit.jobs import prior_unit_draws, sensor_parameters
    from softsbi.workflows.tasks.training import train_task
    bank = tmp_path / "bank"
    monkeypatch.setenv("SOFTSBI_SIM_BANK", str(bank))

    def rollouts():
        return sorted(p for p in bank.rglob("*") if p.is_file() and p.relative_to(bank).parts[0] != "tasks")
    (nominal,) = train_task(toy_measurement(), _cfg(), 40, candidates=[], n_test=20, check_null=0)
    before = rollouts()
    assert before  # the nominal model's prior and held-out rollouts
    _, noisy = train_task(toy_measurement(), _cfg(), 40, candidates=["point-noise"], n_test=20, check_null=0,
                          refit_null=0)
    assert noisy.model == "nominal+point-noise" and noisy.report is not None
    assert rollouts() == before  # every one of its simulations read from the bank
    assert sensor_parameters("toy-gauss", ["point-noise", "toy-wind"]) == {"noise_std"}
    u = prior_unit_draws([0, 0, 0], 4000, ["a", "noise_std", "b"], {"noise_std"})
    assert np.array_equal(u[:, [0, 2]], np.random.default_rng([0, 0, 0]).random((4000, 2)))
    assert abs(u[:, 1].mean() - 0.5) < 0.02 and abs(np.corrcoef(u[:, 0], u[:, 1])[0, 1]) < 0.05
