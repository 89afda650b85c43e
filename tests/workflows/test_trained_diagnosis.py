"""The diagnosis of a fit on a task trained with its candidate models (the toy plugin, tests/plugins/softsbi_toy): a
trained candidate's refit is its amortised posterior (no rounds simulated), stored as a run the other commands read,
and checked against the candidate's own replicates; ``--refit-rounds`` still refits sequentially. The
posterior-predictive summaries are computed in the simulation jobs, and each stored task is read once."""
from __future__ import annotations

import collections

import numpy as np
import pytest

from softsbi.core.defaults import DiagnoseSettings
from softsbi.workflows.criticism.diagnose import diagnose_run
from softsbi.workflows.fit.run import FitConfig, run_fit
from softsbi.workflows.measurement import simulate_recording

pytestmark = pytest.mark.integration

MAGNET = "toy-magnet"
CANDIDATES = ["toy-drift", MAGNET]
#: replicates of each trained model: the fewest that can reject at the default level (check_null.MIN_REPLICATES)
REPLICATES = 19


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A toy task trained with its candidate models (and check's replicates), its bank on for this module only, and
    a nominal fit of a recording with a hidden magnet (pull 0.45 m mid-motion, where this small task's posterior
    excludes the pull 0 that switches it off) that stops at the trained task.
    Yields ``(nominal run directory, the stored tasks: nominal first)``."""
    from softsbi.plugins.manager import registry
    from softsbi.workflows.tasks.training import train_task
    toy = pytest.importorskip("softsbi_toy.plugin")
    root = tmp_path_factory.mktemp("trained")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SOFTSBI_PLUGINS", "softsbi_toy.shifts")
        mp.setenv("SOFTSBI_SIM_BANK", str(root / "bank"))
        registry.cache_clear()
        rec = simulate_recording("toy-gauss", toy.toy_scenario(8), {"a": 0.3, "b": -0.4, "pull": 0.45},
                                 effects=[MAGNET], n_points=16, n_dense=64, seed=5, backend_options={"sigma": 0.02})
        cfg = FitConfig(backend="toy-gauss", backend_options={"sigma": 0.02}, sims_per_round=80, workers=1,
                        n_points=16, n_dense=64, n_eval=30, estimator_options={"max_epochs": 60, "hidden": [64, 64]})
        tasks = train_task(rec, cfg, 120, candidates=CANDIDATES, n_test=20, n_draws=50, check_null=REPLICATES)
        run_fit(root / "nominal", rec, cfg, make_plots=False)  # stops at the trained task: one round
        yield root / "nominal", tasks
    registry.cache_clear()


@pytest.fixture(scope="module")
def diagnosed(trained):
    """The diagnosis of the nominal fit (one refit), with every simulation job it ran: ``(Diagnosis, jobs)``, each
    job ``(effects, seed)``."""
    from softsbi.workflows.fit import jobs as job_module
    run_dir, _ = trained
    ran = []
    simulate = job_module.simulate_job

    def recorded(ctx, item, batch=None):
        ran.append((tuple(item.effects if item.effects is not None else ctx.effects), int(item.seed)))
        return simulate(ctx, item, batch)

    with pytest.MonkeyPatch.context() as mp:  # workers=1 runs the jobs in this process
        mp.setattr(job_module, "simulate_job", recorded)
        d = diagnose_run(run_dir, effects=CANDIDATES, plots=False, recompute=True,
                         settings=DiagnoseSettings(confirm=1, workers=1))
    return d, ran


def test_task_train_stores_check_s_replicates_for_every_model_not_only_the_nominal(trained):
    from softsbi.core.defaults import N_NULL
    from softsbi.workflows.criticism.check_null import stored_check_null
    _, tasks = trained
    assert [t.model for t in tasks] == ["nominal", "nominal+toy-drift", f"nominal+{MAGNET}"]
    for t in tasks:
        null = stored_check_null(t, N_NULL, 64)
        assert null is not None and len(null.statistics) == REPLICATES, t.model
        # the nominal model's are screened (the detection's two tests); a candidate model's are not (--refit-null)
        assert (null.directional is None) == (t.model != "nominal"), t.model


def test_a_trained_candidates_refit_is_its_amortised_posterior_and_simulates_no_rounds(trained, diagnosed):
    """The refit of the named candidate is its stored task's posterior conditioned on the recording: its run holds no
    simulation of a round, no job of the diagnosis was one of the task's prior simulations (neither simulated nor read
    from the bank), and its score is its amortised score (the same rollouts)."""
    from softsbi.core.store import RunStore
    from softsbi.workflows.fit.jobs import _round_seeds
    from softsbi.workflows.fit.runs import read_fit_report
    _, tasks = trained
    d, ran = diagnosed
    assert d.test.misspecified and d.verdict == "missing-effect" and d.decision.named == (MAGNET,)
    (refit,) = d.refits
    assert refit.effects == (MAGNET,) and refit.amortised and (refit.rounds, refit.sims_per_round) == (1, 0)
    store = RunStore.open(f"{refit.run}/run.zarr", mode="r")
    assert store.round_ids() == [0] and len(store.round_data(0)["status"]) == 0
    report = read_fit_report(refit.run)
    # its fit evaluated the race's first stage; its score and check extended them to the check's 30
    assert report.per_round[0].task == tasks[2].digest and report.simulations == 10 and report.bank_hits == 0
    prior_seeds = set(_round_seeds(0, 0, 120).tolist())  # the task's prior simulations (task train's round 1)
    assert ran and not prior_seeds & {seed for _, seed in ran}
    # the candidate's model was simulated: its posterior-predictive rollouts, scored and checked
    assert sum(1 for effects, _ in ran if MAGNET in effects) >= 30
    amortised = next(c.amortised for c in d.ranking if c.effect == MAGNET)
    assert refit.score == amortised and amortised.n == 30
    # the drift's decision was made on the race's first stage (futile, or outranked by the magnet for the one refit)
    assert next(c.amortised for c in d.ranking if c.effect == "toy-drift").n == 10
    # the candidates the task does not inform are those whose training reports leave every own parameter wide
    widths = {t.model.split("+")[1]: t.report.contraction[p].width_ratio
              for t, p in zip(tasks[1:], ("drift", "pull"))}
    assert d.uninformed == {e: w for e, w in widths.items() if w > 0.5}


def test_compare_check_and_view_read_an_amortised_refit_as_any_refit(trained, diagnosed, tmp_path):
    from softsbi.core.results.comparison import Metric
    from softsbi.core.defaults import CheckSettings
    from softsbi.workflows.criticism.check import check_run
    from softsbi.workflows.criticism.compare import compare_runs
    from softsbi.workflows.fit.runs import open_run
    from softsbi.workflows.view import write_view
    run_dir, _ = trained
    d, _ = diagnosed
    refit = d.refit((MAGNET,))
    said = []
    again = check_run(refit.run, CheckSettings(workers=1), plot=False, effects=["toy-drift"], message=said.append)
    assert again.test == refit.test and any(s.startswith("reused") for s in said)  # the diagnosis's check, stored
    post = open_run(refit.run).posterior
    assert set(post.names) == {"a", "b", "pull"} and post.interval()["pull"][0] > 0  # the magnet is on
    res = compare_runs(run_dir, refit.run, tmp_path / "cmp", CheckSettings(workers=1))
    chamfer = next(r for r in res.rows if r.metric == Metric.CHAMFER)
    assert chamfer.b < chamfer.a  # the posterior-predictive Chamfer falls with the magnet
    view = write_view(refit.run, n_eval=2, workers=1, gif=True, rrd=False)
    assert view["gif"].is_file() and view["n_rollouts"] == 2


def test_an_amortised_refits_check_is_calibrated_against_its_models_replicates(trained, diagnosed, tmp_path):
    """The refit is judged with the power the nominal fit was rejected with: its omnibus statistic against its own
    model's 19 replicates (p >= 1/20); without them, the uncalibrated test as before."""
    from softsbi.core.defaults import N_NULL
    from softsbi.workflows.criticism.check_null import NULL_FILE, stored_check_null
    run_dir, tasks = trained
    d, _ = diagnosed
    assert d.test.calibrated  # the detection: the nominal model's replicates
    refit = d.refit((MAGNET,))
    null = stored_check_null(tasks[2], N_NULL, 64)
    assert refit.test.calibrated and refit.test.omnibus == null.p_value(refit.test.statistic)
    assert refit.test.directional is None and refit.test.family == ()  # its replicates calibrate the omnibus alone
    assert refit.test.omnibus.n == REPLICATES and refit.test.p_value >= 1 / (REPLICATES + 1)
    kept = (tasks[2].path / NULL_FILE).read_text()
    (tasks[2].path / NULL_FILE).unlink()
    try:
        bare = diagnose_run(run_dir, effects=CANDIDATES, plots=False, out_dir=tmp_path / "bare",
                            settings=DiagnoseSettings(confirm=1, workers=1))
    finally:
        (tasks[2].path / NULL_FILE).write_text(kept)
    assert bare.refit((MAGNET,)).amortised and not bare.refit((MAGNET,)).test.calibrated


def test_refit_rounds_still_refits_a_trained_candidate_sequentially(trained, tmp_path):
    """``--refit-rounds 2``: the refit runs its own rounds (the first from the task's prior simulations, read from
    the bank), in a folder apart from the amortised refit's."""
    from softsbi.core.store import RunStore
    run_dir, _ = trained
    d = diagnose_run(run_dir, effects=CANDIDATES, plots=False, out_dir=tmp_path / "seq",
                     settings=DiagnoseSettings(confirm=1, workers=1, refit_rounds=2))
    (refit,) = d.refits
    assert refit.effects == (MAGNET,) and not refit.amortised and (refit.rounds, refit.sims_per_round) == (2, 80)
    assert refit.run == str(tmp_path / "seq" / f"refit-{MAGNET}-sequential")
    store = RunStore.open(f"{refit.run}/run.zarr", mode="r")
    assert [len(store.round_data(r)["status"]) for r in store.round_ids()] == [80, 80]
    assert d.key["amortised_refits"] == [] and d.verdict == "missing-effect"


def test_the_posterior_predictive_summaries_are_computed_in_the_simulation_jobs(trained, monkeypatch):
    """The pool's summaries come back with the rollouts from the jobs (the worker summarises): the main process's
    summary function is never called, and the numbers are the ones it would compute."""
    from softsbi.core.seeds import surface_seed
    from softsbi.workflows.criticism import stats
    from softsbi.workflows.criticism.screening import screening_of
    run_dir, _ = trained
    pool = stats.PosteriorPredictive(run_dir, workers=1)
    calls = []
    monkeypatch.setattr(stats, "rollout_features", lambda *a: calls.append(a))
    pool.ensure(8)
    screening_of(pool, [])  # the finite differences' summaries too
    assert calls == [] and len(pool.rollouts) == 8
    monkeypatch.undo()
    want = [stats.rollout_features(pool.run, r, surface_seed(r.sample)) for r in pool.rollouts]
    assert np.array_equal(pool.features, np.array(want))


def test_each_stored_task_is_read_once_per_diagnosis(trained, monkeypatch):
    """Detection, the candidates' amortised posteriors, the refit and each check's calibration reach the same
    stored tasks; each is read from the disk once."""
    from softsbi.workflows.fit.task_store import TaskStore
    run_dir, tasks = trained
    reads = collections.Counter()
    read = TaskStore._read

    def counted(self, digest):
        reads[digest] += 1
        return read(self, digest)

    monkeypatch.setattr(TaskStore, "_read", counted)
    d = diagnose_run(run_dir, effects=CANDIDATES, plots=False, recompute=True,
                     settings=DiagnoseSettings(confirm=1, workers=1))
    assert d.refits  # the refit's fit and check reached its task too
    assert reads == {t.digest: 1 for t in tasks}


def test_each_trained_candidate_stores_its_switched_on_null_and_its_amortised_refit_is_tested_against_it(trained,
                                                                                                       diagnosed):
    """task train stores, per candidate model, its posterior's distance from the off value on each of the nominal
    model's held-out simulations; the named magnet's amortised refit is switched on by that calibrated test (its
    pull lies beyond every null posterior's), not by its interval."""
    from softsbi.workflows.criticism.switched_on import stored_off_null
    _, tasks = trained
    assert stored_off_null(tasks[0].path) is None  # the nominal model adds no effect
    nulls = {t.model: stored_off_null(t.path) for t in tasks[1:]}
    assert all(n is not None and len(n) == 20 and np.all(n >= 0) for n in nulls.values()), nulls
    d, _ = diagnosed
    (refit,) = d.refits
    t = refit.off_test
    assert t is not None and t.p_value.n == 20 and t.on
    assert t.statistic > nulls[f"nominal+{MAGNET}"].max() and t.p_value.value == 1 / 21


def test_an_adequate_improving_refit_left_possibly_off_is_refined_by_sequential_rounds_and_then_decides(
        trained, tmp_path, monkeypatch):
    """Were the magnet's calibrated "switched on" test to leave it possibly off, its adequate, improving amortised
    refit is refined: the same model fitted again in 2 sequential rounds of 150 after that posterior (a folder of
    its own), checked and scored, and its estimates decide; the refinement keeps the amortised refit it refines."""
    from softsbi.core.defaults import REFINE_ROUNDS, REFINE_SIMS
    from softsbi.core.results import MCPValue, OffTest
    from softsbi.workflows.criticism import diagnose as diagnose_module
    run_dir, _ = trained
    undecided = OffTest(statistic=0.1, p_value=MCPValue(exceed=150, n=199), level=0.1)
    monkeypatch.setattr(diagnose_module, "off_test", lambda *a, **k: undecided)
    said = []
    d = diagnose_run(run_dir, effects=CANDIDATES, plots=False, out_dir=tmp_path / "refined", progress=said.append,
                     settings=DiagnoseSettings(confirm=1, workers=1))
    refit = d.refit((MAGNET,))
    assert refit.refined_from is not None and refit.refined_from.amortised and refit.refined_from.maybe_off
    # rounds of the task's 120 prior simulations (fewer than REFINE_SIMS), so that round 1 is the stored task
    assert not refit.amortised and (refit.rounds, refit.sims_per_round) == (1 + REFINE_ROUNDS, min(REFINE_SIMS, 120))
    assert refit.run.endswith(f"refit-{MAGNET}-sequential") and refit.off_test is None
    assert any(line.startswith(f"refine: {MAGNET}'s amortised refit is adequate") for line in said)
    pull = next(e for e in refit.estimates if e.name == "pull")
    assert pull.may_be_off is False and pull.q05 > 0  # the refined posterior excludes the magnet's off value
    assert d.verdict == "missing-effect" and d.decision.named == (MAGNET,)
    bare = diagnose_run(run_dir, effects=CANDIDATES, plots=False, out_dir=tmp_path / "not-refined",
                        settings=DiagnoseSettings(confirm=1, workers=1, refine=0))
    assert bare.refit((MAGNET,)).refined_from is None and bare.verdict == "misspecified-unexplained"
