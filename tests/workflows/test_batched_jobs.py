"""Simulations in batches (softsbi.workflows.fit.jobs.map_simulations): a backend with ``batch_size > 1`` gets a
phase's simulations as ``simulate_batch`` calls, with the same results as one ``simulate`` per job."""
from __future__ import annotations

import numpy as np
import pytest

from softsbi.core.errors import ParameterError
from softsbi.core.interfaces import Simulator
from softsbi.workflows import pools
from softsbi.workflows.fit.bank import HIT
from softsbi.workflows.fit.jobs import JobItem, SimContext, batch_size, map_simulations, run_jobs

pytestmark = pytest.mark.integration

toy = pytest.importorskip("softsbi_toy.plugin")


def _ctx(tmp_path=None, size=1, **kw):
    sc = toy.toy_scenario(3)
    return SimContext(backend="toy-gauss", backend_options={"batch_size": size}, scenario=sc.to_json(), effects=[],
                      observer="pointcloud", observer_options={"n_points": 16}, param_names=["a", "b"], fixed={},
                      dense=np.zeros((3, 8, 3)), n_dense=64,
                      bank=None if tmp_path is None else str(tmp_path / "bank"), **kw)


# 9 simulations: two effect sets, distinct seeds, one that diverges (a > 0.7)
ITEMS = [JobItem(np.array([0.1 * i, -0.1 * i]), 100 + i) for i in range(6)] + \
        [JobItem({"a": 0.2, "b": 0.1, "wind": 0.3}, 7, effects=["toy-wind"]),
         JobItem({"a": -0.4, "b": 0.0, "wind": 0.1}, 8, effects=["toy-wind"]), JobItem(np.array([0.9, 0.0]), 9)]


def _same(a, b):
    assert len(a) == len(b)
    for r, s in zip(a, b):
        assert r.status == s.status and r.reason == s.reason
        for k in ("x", "chamfer", "chamfer_one_sided"):
            if getattr(r, k) is None:
                assert getattr(s, k) is None
            else:
                np.testing.assert_array_equal(getattr(r, k), getattr(s, k))


def _run(ctx, workers=1):
    with pools.executor("local", workers) as exe:
        out = dict(map_simulations(exe, ctx, ITEMS))
    return [out[i] for i in range(len(ITEMS))]


@pytest.fixture
def calls(monkeypatch):
    """The ``simulate_batch`` calls made in this process: ``[(B, effects, seeds)]``."""
    seen = []
    inherited = Simulator.simulate_batch

    def counting(self, scenario, thetas, effects=(), seed=0):
        seen.append((len(thetas), tuple(effects), list(seed)))
        return inherited(self, scenario, thetas, effects, seed)

    monkeypatch.setattr(toy.ToyGauss, "simulate_batch", counting)
    monkeypatch.setenv("SOFTSBI_TOY_DIVERGE_ABOVE", "0.7")
    return seen


def test_batches_give_the_results_of_single_jobs(calls):
    single = _run(_ctx(size=1))
    assert calls == []  # batch_size 1: one simulate per job
    batched = _run(_ctx(size=4))
    _same(single, batched)
    assert single[-1].status != 0  # the divergent one stays a failed simulation, not a failed batch
    # jobs of 4, 4 and 1 items; within a job one call per effect set, each rollout with its item's seed
    assert calls == [(4, (), [100, 101, 102, 103]), (2, (), [104, 105]), (2, ("toy-wind",), [7, 8]), (1, (), [9])]


def test_a_batch_call_that_raises_runs_its_simulations_one_by_one(calls, monkeypatch):
    def refuses(self, scenario, thetas, effects=(), seed=0):
        calls.append(len(thetas))
        raise ParameterError("one theta of the batch is outside the limits")

    monkeypatch.setattr(toy.ToyGauss, "simulate_batch", refuses)
    _same(_run(_ctx(size=1)), _run(_ctx(size=4)))
    assert calls == [4, 2, 2, 1]


def test_batched_rollouts_fill_and_read_the_bank(tmp_path, calls):
    first = _run(_ctx(tmp_path, size=4))
    assert sum(b for b, _, _ in calls) == len(ITEMS)
    again = _run(_ctx(tmp_path, size=4))
    # every successful rollout read from the bank; the divergent one (not banked) simulated again
    assert [r.bank for r in again[:-1]] == [HIT] * (len(ITEMS) - 1) and calls[-1] == (1, (), [9])
    _same(first, again)


def test_batches_in_worker_processes_and_their_size():
    ctx = _ctx(size=4)
    assert batch_size(ctx, 9, workers=2) == 4 and batch_size(ctx, 6, workers=2) == 3
    assert batch_size(ctx, 1, workers=2) == 1 and batch_size(_ctx(size=1), 9, workers=2) == 1
    items = ITEMS[:8]  # no divergence hook in the workers' environment
    single = run_jobs(_ctx(size=1), items, workers=2)
    _same(single, run_jobs(ctx, items, workers=2))


@pytest.mark.slow
def test_a_crashing_simulation_fails_itself_only_not_its_batch(monkeypatch):
    monkeypatch.setenv("SOFTSBI_TOY_CRASH_ABOVE", "0.45")  # the worker process dies at item 5 (a = 0.5)
    items, one_process = ITEMS[:8], {"retries": 0, "in_process": False}
    with pools.shared_executors():  # one worker process, replaced when it dies
        single = run_jobs(_ctx(size=1), items, workers=1, executor_options=one_process)
        batched = run_jobs(_ctx(size=4), items, workers=1, executor_options=one_process)
    failed = [i for i, r in enumerate(batched) if r.status != 0]
    assert failed == [i for i, r in enumerate(single) if r.status != 0] == [5]
    assert "WorkerCrashed" in batched[5].reason
    _same([r for i, r in enumerate(single) if i != 5], [r for i, r in enumerate(batched) if i != 5])
