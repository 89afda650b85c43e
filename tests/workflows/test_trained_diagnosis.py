"""The diagnosis of a fit on a task trained with its candidate models (the toy plugin, tests/plugins/softsbi_toy):
the posterior-predictive summaries are computed in the simulation jobs, and each stored task is read once."""
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
    a nominal fit of a recording with a hidden magnet (pull 0.3 m mid-motion) that stops at the trained task.
    Yields ``(nominal run directory, the stored tasks: nominal first)``."""
    from softsbi.plugins.manager import registry
    from softsbi.workflows.tasks.training import train_task
    toy = pytest.importorskip("softsbi_toy.plugin")
    root = tmp_path_factory.mktemp("trained")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SOFTSBI_PLUGINS", "softsbi_toy.shifts")
        mp.setenv("SOFTSBI_SIM_BANK", str(root / "bank"))
        registry.cache_clear()
        rec = simulate_recording("toy-gauss", toy.toy_scenario(8), {"a": 0.3, "b": -0.4, "pull": 0.3},
                                 effects=[MAGNET], n_points=16, n_dense=64, seed=5, backend_options={"sigma": 0.02})
        cfg = FitConfig(backend="toy-gauss", backend_options={"sigma": 0.02}, sims_per_round=80, workers=1,
                        n_points=16, n_dense=64, n_eval=30, estimator_options={"max_epochs": 60, "hidden": [64, 64]})
        tasks = train_task(rec, cfg, 120, candidates=CANDIDATES, n_test=20, n_draws=50, check_null=REPLICATES)
        run_fit(root / "nominal", rec, cfg, make_plots=False)  # stops at the trained task: one round
        yield root / "nominal", tasks
    registry.cache_clear()


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
