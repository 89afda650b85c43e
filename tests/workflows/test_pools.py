"""A command's batches share one started pool of workers (softsbi.workflows.pools), and a local pool serves batches
of different contexts without restarting its workers."""
import operator

import pytest

from softsbi.executors.local import LocalExecutor
from softsbi.workflows import pools

pytestmark = pytest.mark.integration  # starts worker processes


def test_a_local_pool_keeps_its_workers_across_contexts_and_runs_each_batch_with_its_own():
    exe = LocalExecutor(workers=2)
    try:
        first = dict(exe.map_unordered(operator.add, [1, 2], context=10))
        pids = sorted(exe.worker_pids())
        second = dict(exe.map_unordered(operator.add, [1, 2], context=100))
        assert first == {0: 11, 1: 12} and second == {0: 101, 1: 102}
        assert exe.stats["started"] == 2 and sorted(exe.worker_pids()) == pids  # the same two processes
    finally:
        exe.close()
    assert exe.worker_pids() == []


def test_inside_a_command_one_executor_per_plugin_and_options_closed_when_the_command_ends(monkeypatch):
    made, closed = [], []

    class Fake:
        def __init__(self, workers=None, **options):
            made.append((workers, options))

        def close(self):
            closed.append(self)

    monkeypatch.setattr(pools, "registry", lambda: type("R", (), {"executor": staticmethod(lambda name: Fake)})())
    with pools.shared_executors():
        with pools.executor("local", 2) as a, pools.executor("local", 2) as b, pools.executor("local", 1) as c:
            assert a is b and a is not c
        with pools.shared_executors():  # an inner command joins the outer one
            with pools.executor("local", 2) as d:
                assert d is a
        assert closed == []  # kept between batches
    assert len(made) == 2 and len(closed) == 2
    with pools.executor("local", 2) as e:  # outside a command: a fresh one, closed after its batch
        assert e is not a
    assert len(closed) == 3
