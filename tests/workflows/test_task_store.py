"""Stored tasks (softsbi.workflows.fit.task_store): the key holds everything that determines a fit's first round, and an
entry that is damaged, moved or of another key is never used."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from softsbi.core.store.posterior import EstimatorState
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
    assert store.get(t.digest) is None and store.list() == []  # never used
    damaged = store.find(t.digest[:6])  # but named, and removable
    assert isinstance(damaged, tasks.DamagedTask) and damaged.digest == t.digest and "checksum" in damaged.problem
    assert store.entries() == [damaged] and not damaged.trained and damaged.model == "nominal"
    assert store.delete(t.digest[:6]) == damaged and store.entries() == [] and not t.path.exists()


def test_find_and_delete_name_the_key(tmp_path):
    from softsbi.core.errors import SoftsbiError
    store = TaskStore(tmp_path / "tasks")
    p = _parts()
    t = store.put(task_identity(p["cfg"], p["space"], p["ctx"], p["opts"]), 10, _state(), {})
    with pytest.raises(SoftsbiError, match="at least its first 4"):
        store.find("ab")
    assert store.delete(t.digest[:8]).digest == t.digest and store.list() == []


class _Trained:
    """An estimator whose state is :func:`_state`'s (what a fit's first round hands :meth:`PriorRound.keep`)."""

    def state_dict(self):
        return _state().state


def _damage(task):
    import zarr
    g = zarr.open_group(str(task.path / "task.zarr" / "estimator" / "state"), mode="a")
    name = next(iter(g.array_keys()))
    g[name][...] = g[name][...] + 1


@pytest.mark.parametrize("trained", [True, False])
def test_a_fit_never_uses_a_damaged_task_says_so_and_replaces_it_only_without_a_training_report(tmp_path, trained):
    from result_helpers import training_report_doc

    from softsbi.core.results.fitreport import TrainingReport
    store = TaskStore(tmp_path / "tasks")
    p = _parts()
    idy = task_identity(p["cfg"], p["space"], p["ctx"], p["opts"])
    report = TrainingReport.from_json(training_report_doc()) if trained else None
    t = store.put(idy, 40, _state(), {"epochs": 3}, report)
    assert t.report == report  # read back typed: its contraction per parameter
    (t.path / "check-null.json").write_text('{"rollouts": 30, "n_dense": 64, "statistics": [1.0]}')
    _damage(t)
    prior = tasks.PriorRound(store, idy)
    assert prior.task is None and prior.damaged is not None and not prior.usable(10)
    line = prior.damage_line()
    assert t.digest[:12] in line and "is damaged" in line and "\n" not in line
    kept = prior.keep(40, _Trained(), {"epochs": 1}, {"max_epochs": 5}, "mdnn")
    if trained:  # its training report and check replicates are the user's to delete, not the fit's to drop
        assert kept is None and "leaves the entry" in line and f"softsbi task delete {t.digest[:12]}" in line
        assert isinstance(store.entry(t.digest), tasks.DamagedTask) and (t.path / "check-null.json").exists()
    else:
        assert kept is not None and kept.info == {"epochs": 1} and "stores it in its place" in line
        assert store.get(t.digest) is not None


@pytest.mark.integration
def test_task_list_show_and_delete_name_a_trained_and_a_damaged_task(tmp_path, monkeypatch):
    """`task show` of a task `task train` trained prints its training report (its contraction read back typed);
    a damaged entry is named by `task list` and `task show` and removed by `task delete`; a --sim-bank that is a
    file is one line naming it."""
    from result_helpers import training_report_doc
    from typer.testing import CliRunner

    from softsbi.cli import app
    from softsbi.core.results.fitreport import TrainingReport
    monkeypatch.delenv("SOFTSBI_SIM_BANK", raising=False)  # the tests' default: off
    runner = CliRunner()
    bank = tmp_path / "bank"
    store = TaskStore(bank / "tasks")
    p = _parts()
    good = store.put(task_identity(p["cfg"], p["space"], p["ctx"], p["opts"]), 40, _state(), {},
                     TrainingReport.from_json(training_report_doc()))
    bad = store.put(task_identity(p["cfg"], p["space"], p["ctx"], {"max_epochs": 6}), 40, _state(), {},
                    TrainingReport.from_json(training_report_doc()))
    _damage(bad)
    res = runner.invoke(app, ["task", "show", good.digest[:8], "--sim-bank", str(bank)])
    assert res.exit_code == 0 and "Traceback" not in res.output, res.output
    assert "0.40" in res.output and "verdict: calibrated" in res.output  # a's 90% width over the prior's
    res = runner.invoke(app, ["task", "list", "--sim-bank", str(bank)])
    assert res.exit_code == 0, res.output
    rows = {ln.split()[1]: ln for ln in res.output.splitlines() if ln.split()[1:2] in ([good.digest[:12]],
                                                                                     [bad.digest[:12]])}
    assert "calibrated" in rows[good.digest[:12]] and "DAMAGED" in rows[bad.digest[:12]], res.output
    import json
    docs = json.loads(runner.invoke(app, ["task", "list", "--sim-bank", str(bank), "--json"]).output)
    assert {d["key"]: d["damaged"] is not None for d in docs} == {good.digest: False, bad.digest: True}
    res = runner.invoke(app, ["task", "show", bad.digest[:8], "--sim-bank", str(bank)])
    line = " ".join(res.output.split())
    assert res.exit_code == 2 and "is damaged" in line and f"softsbi task delete {bad.digest[:12]}" in line, line
    res = runner.invoke(app, ["task", "delete", bad.digest[:8], "--sim-bank", str(bank)])
    assert res.exit_code == 0 and "damaged" in res.output and not bad.path.exists(), res.output
    assert [t.digest for t in store.entries()] == [good.digest]
    afile = tmp_path / "afile"
    afile.write_text("x")
    for argv in (["task", "list"], ["task", "show", "abcd"], ["task", "delete", "abcd"]):
        res = runner.invoke(app, [*argv, "--sim-bank", str(afile)])
        line = " ".join(res.output.split())
        assert res.exit_code == 2 and f"{afile} is a file" in line and "no stored task" not in line, line
