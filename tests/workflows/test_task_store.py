"""Stored tasks (softsbi.workflows.fit.task_store): the key holds everything that determines a fit's first round, and an
entry that is damaged, moved or of another key is never used."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from softsbi.core.posterior_store import EstimatorState
from softsbi.core.types import Param, ParamSpace
from softsbi.workflows.fit import task_store as tasks
from softsbi.workflows.fit.run import FitConfig
from softsbi.workflows.fit.jobs import SimContext
from softsbi.workflows.fit.task_store import TaskStore, task_digest, task_identity


def _parts(**change):
    cfg = FitConfig(backend="toy-gauss", estimator="mdnn", seed=3, frames=[1, 2])
    space = ParamSpace([Param("a", -1.0, 1.0, "1"), Param("b", -1.0, 1.0, "1")])
    ctx = SimContext(backend="toy-gauss", backend_options={}, scenario={"name": "toy", "options": {"source": "x"}},
                     effects=[], observer="pointcloud", observer_options={"n_points": 16}, param_names=space.names,
                     fixed={}, dense=None, n_dense=64, min_z=0.01)
    parts = {"cfg": cfg, "space": space, "ctx": ctx, "opts": {"max_epochs": 5}}
    parts.update(change)
    return parts


def _digest(**change):
    p = _parts(**change)
    return task_digest(task_identity(p["cfg"], p["space"], p["ctx"], p["opts"]))


def test_the_key_changes_with_everything_that_determines_the_first_round(monkeypatch):
    base = _digest()
    p = _parts()
    cfg, ctx = p["cfg"], p["ctx"]
    changed = {
        "backend": _digest(cfg=replace(cfg, backend="mujoco-flex")),
        "model (an effect on)": _digest(cfg=replace(cfg, effects=["wind"])),
        "prior bounds": _digest(space=ParamSpace([Param("a", -2.0, 1.0, "1"), Param("b", -1.0, 1.0, "1")])),
        "fixed value": _digest(cfg=replace(cfg, fixed={"b": 0.1})),
        "scenario": _digest(ctx=replace(ctx, scenario={"name": "toy", "options": {"table_z": 0.1}})),
        "sensor model": _digest(ctx=replace(ctx, min_z=0.02)),
        "frames": _digest(cfg=replace(cfg, frames=[2])),
        "observer options": _digest(ctx=replace(ctx, observer_options={"n_points": 32})),
        "estimator options": _digest(opts={"max_epochs": 6}),
        "seed": _digest(cfg=replace(cfg, seed=4)),
        "backend options": _digest(cfg=replace(cfg, backend_options={"sigma": 0.1})),
    }
    assert all(d != base for d in changed.values()), [k for k, d in changed.items() if d == base]
    assert len(set(changed.values())) == len(changed)
    monkeypatch.setattr(tasks, "installed_version", lambda: "99.0")
    assert _digest() != base  # another softsbi version trains the task again
    monkeypatch.undo()
    # what does not change the first round keeps the key: the later rounds, the workers, where the scenario came from
    assert _digest(cfg=replace(cfg, rounds=7, sims_per_round=33, workers=1, n_eval=5)) == base
    assert _digest(cfg=replace(cfg, backend_options={"batch_size": 8})) == base  # a speed knob, the same results
    assert _digest(ctx=replace(ctx, scenario={"name": "toy", "options": {"source": "elsewhere"}})) == base


def _state():
    return EstimatorState("mdnn", {"max_epochs": 5}, {"w": np.arange(6.0).reshape(2, 3), "k": 2})


def test_a_stored_task_reads_back_and_a_damaged_or_moved_entry_is_absent(tmp_path):
    store = TaskStore(tmp_path / "tasks")
    p = _parts()
    idy = task_identity(p["cfg"], p["space"], p["ctx"], p["opts"])
    t = store.put(idy, 40, _state(), {"epochs": 3})
    assert t is not None and t.n_prior == 40 and t.info == {"epochs": 3} and t.report is None
    np.testing.assert_array_equal(t.estimator.state["w"], _state().state["w"])
    assert store.get(t.digest).digest == t.digest and [x.digest for x in store.list()] == [t.digest]
    assert store.find(t.digest[:6]).digest == t.digest
    # moved under another key: not used
    other = tmp_path / "tasks" / ("0" * 64)
    (t.path).rename(other)
    assert store.get("0" * 64) is None and store.list() == []
    other.rename(t.path)
    # damaged: one stored array changed behind the checksum's back
    import zarr
    g = zarr.open_group(str(t.path / "task.zarr" / "estimator" / "state"), mode="a")
    name = next(iter(g.array_keys()))
    g[name][...] = g[name][...] + 1
    assert store.get(t.digest) is None
    from softsbi.core.errors import SoftsbiError
    with pytest.raises(SoftsbiError, match="no stored task"):
        store.find(t.digest[:6])


def test_find_and_delete_name_the_key(tmp_path):
    from softsbi.core.errors import SoftsbiError
    store = TaskStore(tmp_path / "tasks")
    p = _parts()
    t = store.put(task_identity(p["cfg"], p["space"], p["ctx"], p["opts"]), 10, _state(), {})
    with pytest.raises(SoftsbiError, match="at least its first 4"):
        store.find("ab")
    assert store.delete(t.digest[:8]).digest == t.digest and store.list() == []
