"""Executors (issue 7): local process pool and Ray, crashed/hung workers, reproducibility,
resume after SIGKILL on Ray, and the errors of `--executor ray` / `--workers 0`.

Fault injection uses the toy plugin's env hooks: SOFTSBI_TOY_CRASH_ONCE=<dir> (os._exit the
first time per seed), SOFTSBI_TOY_CRASH_ABOVE=<a>, SOFTSBI_TOY_HANG_ABOVE=<a>. Local workers
inherit the environment when they are spawned; Ray workers get it through ``runtime_env``.
"""
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from softsbi.core.errors import DependencyMissing, SoftsbiError
from softsbi.executors.local import LocalExecutor, SimulationTimeout, WorkerCrashed, WorkerStartupError
from softsbi.workflows.fit.run import FitConfig, JobItem, SimContext, run_fit, simulate_job
from softsbi.core.store import RunStore
from softsbi.core.types import STATUS_ERROR, STATUS_OK, STATUS_PENDING

pytestmark = pytest.mark.integration

toy = pytest.importorskip("softsbi_toy.plugin", reason="install tests/plugins/softsbi_toy (pip install -e)")
from toy_helpers import TESTS_DIR, toy_measurement  # noqa: E402

try:
    import ray
except ImportError:  # pragma: no cover - depends on the install
    ray = None
needs_ray = pytest.mark.skipif(ray is None, reason="Ray is not installed (pip install softsbi[ray])")

OK = np.array([0.1, 0.2])
BAD = np.array([0.9, 0.2])  # a > 0.8: crashes / hangs with the hooks below


def toy_ctx():
    sc = toy.toy_scenario(3)
    return SimContext(backend="toy-gauss", backend_options={}, scenario=sc.to_json(), effects=[],
                      observer="pointcloud", observer_options={"n_points": 8}, param_names=["a", "b"], fixed={},
                      dense=None, n_dense=16)


def run_all(ex, items, ctx):
    out = {}
    for i, res in ex.map_unordered(simulate_job, [JobItem(theta, seed) for theta, seed in items], context=ctx):
        assert i not in out, "an item was yielded twice"
        out[i] = res
    assert sorted(out) == list(range(len(items)))
    return out


@pytest.fixture(scope="module")
def ray_cluster():
    if ray is None:
        pytest.skip("Ray is not installed (pip install softsbi[ray])")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level="warning")
    yield ray.get_runtime_context().gcs_address
    ray.shutdown()


# ---------------------------------------------------------------------------------------- local

@pytest.mark.slow
def test_local_worker_crash_is_retried_and_hang_times_out(tmp_path, monkeypatch):
    monkeypatch.setenv("SOFTSBI_TOY_CRASH_ONCE", str(tmp_path))
    monkeypatch.setenv("SOFTSBI_TOY_HANG_ABOVE", "0.8")
    ctx = toy_ctx()
    ex = LocalExecutor(workers=2, timeout=3, retries=1, startup_grace=60)
    try:
        # crash once per seed: each item's worker dies, the item is re-run on a fresh worker
        res = run_all(ex, [(OK, 1), (OK, 2)], ctx)
        assert all(not isinstance(r, BaseException) and r.status == STATUS_OK for r in res.values()), res
        assert ex.stats["crashed"] == 2
        # a hang (seed 1 no longer crashes) on a warm worker: killed after 3 s, reported
        ex.retries = 0
        t0 = time.perf_counter()
        res = run_all(ex, [(OK, 1), (OK, 2), (BAD, 1)], ctx)
        assert isinstance(res[2], SimulationTimeout) and "3 s timeout" in str(res[2])
        assert res[0].status == res[1].status == STATUS_OK
        assert ex.stats["timed_out"] == 1 and time.perf_counter() - t0 < 30
        # a crash with no retry left is reported with the exit code; the batch goes on
        res = run_all(ex, [(OK, 1), (OK, 3)], ctx)
        assert res[0].status == STATUS_OK
        assert isinstance(res[1], WorkerCrashed) and "exit code 13" in str(res[1])
    finally:
        ex.close()


@pytest.mark.slow
def test_fit_round_completes_with_crashing_simulations_marked_failed(tmp_path, monkeypatch):
    """Simulations whose worker dies on every attempt are stored as STATUS_ERROR with the
    reason; the round and the fit complete with the others."""
    monkeypatch.setenv("SOFTSBI_TOY_CRASH_ABOVE", "0.7")
    cfg = FitConfig(backend="toy-gauss", estimator="mdnn", rounds=1, sims_per_round=16, workers=2, n_points=8,
                    n_eval=2, n_dense=16, seed=2, estimator_options={"max_epochs": 5, "hidden": [8]},
                    bounds={"b": (-0.5, 0.5)}, executor_options={"retries": 1})
    res = run_fit(tmp_path / "r", toy_measurement(), cfg, make_plots=False)
    d = res.store.round_data(0)
    bad = d["theta"][:, 0] > 0.7
    assert bad.sum() == 2, d["theta"][:, 0]
    assert (d["status"][bad] == STATUS_ERROR).all() and (d["status"][~bad] == STATUS_OK).all()
    fails = res.store.round_attrs(0)["failures"]
    assert set(fails) == {str(i) for i in np.nonzero(bad)[0]}
    assert all("WorkerCrashed" in v and "2 attempt" in v for v in fails.values())
    assert res.report.per_round[0].usable == int((~bad).sum())


UNGUARDED_SCRIPT = """
import operator, os, sys
from softsbi.executors.local import LocalExecutor
with open(sys.argv[1], "a") as f:   # one line each time this file's top level runs
    f.write(f"{os.getpid()}\\n")
ex = LocalExecutor(workers=2, retries=0)
print(sorted(r for _, r in ex.map_unordered(operator.add, [1, 2, 3, 4], context=10)))
ex.close()
"""

MAIN_FUNCTION_SCRIPT = """
import sys
from softsbi.executors.local import LocalExecutor

def triple(context, item):   # defined in __main__: workers must import this file to run it
    return context * item

if __name__ == "__main__":
    ex = LocalExecutor(workers=2, retries=0)
    print(sorted(r for _, r in ex.map_unordered(triple, [1, 2, 3], context=3)))
    ex.close()
"""


def test_a_script_without_a_main_guard_runs_once_and_its_workers_do_not_rerun_it(tmp_path):
    """A user's `python my_fit.py` with no `if __name__ == "__main__":` guard (the README's Python
    example saved as a file): spawn used to re-run the whole script in every worker, which hung the fit
    on its own run lock. Workers now start from softsbi alone."""
    script, marks = tmp_path / "my_fit.py", tmp_path / "top_level_runs.txt"
    script.write_text(UNGUARDED_SCRIPT)
    out = subprocess.run([sys.executable, str(script), str(marks)], capture_output=True, text=True, timeout=120,
                         cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().splitlines()[-1] == "[11, 12, 13, 14]"
    assert len(marks.read_text().split()) == 1, "the script's top level ran in a worker"


def test_a_job_function_defined_in_the_script_still_reaches_the_workers(tmp_path):
    """The exception to the rule above: a job function from `__main__` needs the script in the worker."""
    script = tmp_path / "my_jobs.py"
    script.write_text(MAIN_FUNCTION_SCRIPT)
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().splitlines()[-1] == "[3, 6, 9]"


class _DiesWhenUnpickled:
    """A context whose unpickling in a worker exits the process (a worker that dies while starting)."""

    def __reduce__(self):
        import os
        return os._exit, (7,)


def test_workers_that_die_while_starting_stop_the_batch_with_one_line():
    """Before: the jobs were retried on fresh workers that died again, for as long as the batch lasted
    (the README example as a script hung for more than 600 s). Now three deaths before the handshake stop it,
    and a job that never ran is not charged an attempt."""
    import operator
    ex = LocalExecutor(workers=2, retries=5)
    t0 = time.perf_counter()
    try:
        with pytest.raises(WorkerStartupError,
                           match=r"die while starting \(3 in a row, last exit code 7.*workers=1 shows the error"):
            list(ex.map_unordered(operator.add, [1, 2, 3], context=_DiesWhenUnpickled()))
        assert ex.stats["startup_failed"] == 3 and time.perf_counter() - t0 < 60
        # the same executor still runs a batch whose context loads
        assert sorted(r for _, r in ex.map_unordered(operator.add, [1, 2], context=5)) == [6, 7]
    finally:
        ex.close()


def test_option_errors():
    with pytest.raises(SoftsbiError, match="--workers must be >= 1"):
        FitConfig(workers=0).validate()
    with pytest.raises(ValueError, match="--workers must be >= 1"):
        LocalExecutor(workers=0)
    with pytest.raises(ValueError, match="timeout must be > 0"):
        LocalExecutor(workers=2, timeout=0)
    with pytest.raises(ValueError, match="retries must be >= 0"):
        LocalExecutor(workers=2, retries=-1)


def test_ray_missing_names_the_install_command(monkeypatch):
    from softsbi.executors.ray_executor import RayExecutor
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    with pytest.raises(DependencyMissing, match=r"pip install softsbi\[ray\]"):
        RayExecutor(workers=2)


@needs_ray
def test_ray_unreachable_address_is_a_clear_error():
    from softsbi.executors.ray_executor import RayExecutor
    if ray.is_initialized():
        pytest.skip("Ray already initialised in this process")
    t0 = time.perf_counter()
    with pytest.raises(SoftsbiError, match=r"127\.0\.0\.1:1 .*ray start --head"):
        RayExecutor(workers=2, address="127.0.0.1:1")
    assert time.perf_counter() - t0 < 15


def test_cli_fit_workers_zero_and_ray_address_without_ray_executor(tmp_path):
    from typer.testing import CliRunner
    from softsbi.cli import app
    r = CliRunner().invoke(app, ["fit", "--observed", str(tmp_path), "--out", str(tmp_path / "o"), "--workers", "0"])
    assert r.exit_code == 2 and "'--workers'" in r.output and ">= 1" in r.output
    r = CliRunner().invoke(app, ["fit", "--observed", str(tmp_path), "--out", str(tmp_path / "o"),
                                 "--ray-address", "1.2.3.4:6379"])
    assert r.exit_code == 2 and "--executor ray" in r.output


# ---------------------------------------------------------------------------------------- ray

@pytest.mark.slow
@needs_ray
def test_ray_crash_is_retried_and_hang_times_out(ray_cluster, tmp_path):
    from softsbi.executors.ray_executor import RayExecutor
    env = {"SOFTSBI_TOY_CRASH_ONCE": str(tmp_path), "SOFTSBI_TOY_HANG_ABOVE": "0.8"}
    ex = RayExecutor(workers=2, timeout=15, retries=1, startup_grace=120, runtime_env={"env_vars": env})
    ctx = toy_ctx()
    res = run_all(ex, [(OK, 1), (OK, 2)], ctx)  # each crashes once, then succeeds on a fresh worker
    assert all(not isinstance(r, BaseException) and r.status == STATUS_OK for r in res.values()), res
    assert ex.stats["crashed"] == 2
    res = run_all(ex, [(OK, 1), (OK, 2)], ctx)  # warm the replacement workers
    ex.retries = 0
    res = run_all(ex, [(OK, 1), (BAD, 3)], ctx)  # BAD crashes once (retries=0 -> failed)
    assert res[0].status == STATUS_OK and isinstance(res[1], WorkerCrashed)
    res = run_all(ex, [(OK, 1), (BAD, 3)], ctx)  # marker exists now: BAD hangs -> timeout
    assert res[0].status == STATUS_OK and isinstance(res[1], SimulationTimeout), res
    ex.close()
    assert ray.is_initialized()  # a Ray started by someone else is left running


RESUME_SCRIPT = r"""
import sys
sys.path.insert(0, {tests!r})
from toy_helpers import toy_measurement
from softsbi.workflows.fit.run import FitConfig, run_fit
cfg = FitConfig(backend="toy-gauss", estimator="mdnn", rounds=2, sims_per_round=60, workers=2, n_points=8,
                n_eval=5, n_dense=32, seed=3, estimator_options={{"max_epochs": 20, "hidden": [16]}},
                executor="ray", executor_options={{"address": {addr!r},
                                                   "runtime_env": {{"env_vars": {{"SOFTSBI_TOY_SLEEP": "0.1"}}}}}})
run_fit({out!r}, toy_measurement(), cfg, make_plots=False)
"""


@pytest.mark.slow
@needs_ray
def test_ray_fit_resumes_after_sigkill_of_the_driver(ray_cluster, tmp_path, kill_when_stored):
    out = tmp_path / "run"
    script = RESUME_SCRIPT.format(tests=str(TESTS_DIR), out=str(out), addr=ray_cluster)
    done = kill_when_stored(script, out, 6)
    assert 6 <= done < 60, f"kill came too late or too early ({done} simulations stored)"
    before = RunStore.open(out / "run.zarr").round_data(0)
    finished = before["status"] != STATUS_PENDING
    subprocess.run([sys.executable, "-c", script], check=True, timeout=300)
    store = RunStore.open(out / "run.zarr")
    after = store.round_data(0)
    np.testing.assert_array_equal(after["x"][finished], before["x"][finished])
    np.testing.assert_array_equal(after["status"][finished], before["status"][finished])
    assert store.completed_rounds() == [0, 1] and (after["status"] == STATUS_OK).all()


# ------------------------------------------------------------------------------ reproducibility

def _fit_arrays(path, executor, workers, address=None):
    cfg = FitConfig(backend="toy-gauss", estimator="rkhs", rounds=2, sims_per_round=20, workers=workers,
                    n_points=8, n_eval=3, n_dense=16, seed=7, executor=executor,
                    executor_options={"address": address} if address else {},
                    estimator_options={"max_epochs": 8, "hidden": [16], "num_threads": 1})
    run_fit(path, toy_measurement(), cfg, make_plots=False)
    store = RunStore.open(Path(path) / "run.zarr")
    return [{k: v for k, v in store.round_data(r).items() if k in ("theta", "seed", "x", "status")}
            for r in (0, 1)]


@pytest.mark.slow
@needs_ray
def test_same_seed_same_store_whatever_the_executor(ray_cluster, tmp_path):
    ref = _fit_arrays(tmp_path / "l1", "local", 1)
    for name, workers in (("local", 2), ("ray", 2)):
        got = _fit_arrays(tmp_path / f"{name}{workers}", name, workers)
        for r in (0, 1):
            for k in ref[r]:
                np.testing.assert_array_equal(got[r][k], ref[r][k], err_msg=f"{name} x{workers}: round {r} {k}")
    assert (ref[1]["status"] == STATUS_OK).all()


@needs_ray
def test_a_diagnose_refit_of_a_ray_fit_runs_on_ray_with_the_run_executor_options(ray_cluster, tmp_path):
    """FitConfig round trip: the diagnosis' refit rebuilds the run's settings from the store
    (FitConfig.from_run_config), so it keeps the executor and its options instead of running locally."""
    from softsbi.workflows.criticism.diagnose import refit_model
    from softsbi.workflows.fit.runs import load_run
    opts = {"address": ray_cluster, "retries": 1, "timeout": 120}
    cfg = FitConfig(backend="toy-gauss", estimator="mdnn", rounds=1, sims_per_round=30, workers=2, n_points=8,
                    n_eval=5, n_dense=32, seed=3, estimator_options={"max_epochs": 10, "hidden": [16]},
                    executor="ray", executor_options=opts)
    out = tmp_path / "run"
    run_fit(out, toy_measurement(), cfg, make_plots=False)
    assert FitConfig.from_run_config(RunStore.open(out / "run.zarr").config) == cfg
    res = refit_model(load_run(out), ["toy-wind"], ["toy-wind"], rounds=1, sims_per_round=20)
    refit = FitConfig.from_run_config(RunStore.open(Path(res.run) / "run.zarr").config)
    assert refit.executor == "ray" and refit.executor_options == opts
    assert refit.effects == ["toy-wind"] and refit.sims_per_round == 20 and refit.workers == 2
    assert refit.estimator_options == cfg.estimator_options and refit.seed == cfg.seed
