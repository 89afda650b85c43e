"""The calibration of check's omnibus test by a trained task's replicate recordings: its p-value, and what is read
back from the stored file."""
from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from softsbi.core.errors import SoftsbiError
from softsbi.workflows.criticism.check_null import NULL_FILE, CheckNull, check_replicates, stored_check_null


def test_the_calibrated_p_value_counts_the_replicates_at_least_as_extreme_and_never_falls_below_its_floor():
    null = CheckNull(30, 64, (0.5, 1.0, 2.0, 4.0))
    assert null.p_value(3.0).exceed == 1 and null.p_value(3.0).value == pytest.approx(2 / 5)
    assert null.p_value(0.1).value == 1.0
    assert null.p_value(9.0).value == pytest.approx(1 / 5) and null.p_value(9.0).at_floor


def test_a_stored_null_is_read_only_for_its_own_settings_and_a_damaged_one_counts_as_absent(tmp_path):
    task = SimpleNamespace(path=tmp_path)
    assert stored_check_null(task, 30, 64) is None and stored_check_null(None, 30, 64) is None
    (tmp_path / NULL_FILE).write_text(json.dumps(CheckNull(30, 64, (1.0, 2.0)).to_json()))
    assert stored_check_null(task, 30, 64) == CheckNull(30, 64, (1.0, 2.0))
    assert stored_check_null(task, 20, 64) is None and stored_check_null(task, 30, 600) is None
    (tmp_path / NULL_FILE).write_text('{"rollouts": 30, "n_dense": 64, "statistics": [1.0, NaN]}')
    assert stored_check_null(task, 30, 64) is None
    (tmp_path / NULL_FILE).write_text("{not json")
    assert stored_check_null(task, 30, 64) is None


def test_too_few_replicates_to_reject_at_the_level_are_refused():
    check_replicates(0)
    check_replicates(19)
    with pytest.raises(SoftsbiError, match="--check-null 18"):
        check_replicates(18)
    with pytest.raises(SoftsbiError, match="--refit-null 18: .* give --refit-null 19"):
        check_replicates(18, "--refit-null")


def test_unscreened_replicates_calibrate_a_check_s_omnibus_test_alone_and_screened_ones_of_another_family_none(
        tmp_path, monkeypatch):
    """A candidate model's replicates (task train --refit-null) are not screened: a check of its fit against any
    family is calibrated by them on the omnibus test alone (check_run then screens nothing), while screened
    replicates of another family leave the check uncalibrated, said in one line."""
    import numpy as np

    from softsbi.core.store.posterior import EstimatorState
    from softsbi.workflows.criticism.check_null import run_check_null
    from softsbi.workflows.fit.config import FitConfig
    from softsbi.workflows.fit.task_store import TaskStore
    monkeypatch.delenv("SOFTSBI_SIM_BANK", raising=False)
    bank = tmp_path / "bank"
    task = TaskStore(bank / "tasks").put({"task": "toy"}, 40, EstimatorState("mdnn", {}, {"w": np.arange(3.0)}), {})
    run = SimpleNamespace(report=SimpleNamespace(rounds=1, per_round=[SimpleNamespace(task=task.digest)]),
                          config=FitConfig(sim_bank=str(bank)), dense=np.zeros((3, 64, 3)))
    said = []
    unscreened = CheckNull(30, 64, (1.0, 2.0))
    (task.path / NULL_FILE).write_text(json.dumps(unscreened.to_json()))
    assert run_check_null(run, 30, said.append, ["wind", "time-offset"]) == unscreened and said == []
    screened = CheckNull(30, 64, (1.0, 2.0), ((0.5,), (0.7,)), ("wind",))
    (task.path / NULL_FILE).write_text(json.dumps(screened.to_json()))
    assert run_check_null(run, 30, said.append, ["wind"]) == screened and said == []
    assert run_check_null(run, 30, said.append, ["wind", "time-offset"]) is None
    assert len(said) == 1 and "another candidate family (1 candidates, this check 2)" in said[0]


def test_a_run_whose_calibration_is_lost_says_so_and_what_its_p_value_is_then(tmp_path, monkeypatch):
    """check of a run that stopped at a trained task: a damaged or empty check-null.json, a deleted or damaged
    task each say in one line that the check is not calibrated and against what its p-value is computed."""
    import numpy as np
    import zarr

    from softsbi.core.store.posterior import EstimatorState
    from softsbi.workflows.criticism.check_null import run_check_null
    from softsbi.workflows.fit.config import FitConfig
    from softsbi.workflows.fit.task_store import TaskStore
    monkeypatch.delenv("SOFTSBI_SIM_BANK", raising=False)  # the tests' default: off
    bank = tmp_path / "bank"
    store = TaskStore(bank / "tasks")
    task = store.put({"task": "toy"}, 40, EstimatorState("mdnn", {}, {"w": np.arange(3.0)}), {})
    run = SimpleNamespace(report=SimpleNamespace(rounds=1, per_round=[SimpleNamespace(task=task.digest)]),
                          config=FitConfig(sim_bank=str(bank)), dense=np.zeros((3, 64, 3)))
    said = []

    def lost():
        assert run_check_null(run, 30, said.append) is None and len(said) == 1, said
        line = said.pop()
        assert line.startswith("check is not calibrated: ") and "uncalibrated posterior-predictive" in line
        assert "\n" not in line and "--check-null" in line
        return line

    assert run_check_null(run, 30, said.append) is None and said == []  # trained with --check-null 0: no file
    (task.path / NULL_FILE).write_text(json.dumps(CheckNull(30, 64, (1.0, 2.0)).to_json()))
    assert run_check_null(run, 30, said.append) == CheckNull(30, 64, (1.0, 2.0)) and said == []
    for text in ("{}", "{not json", '{"rollouts": 30, "n_dense": 64, "statistics": []}'):
        (task.path / NULL_FILE).write_text(text)
        assert f"'{task.path / NULL_FILE}' is damaged" in lost()
    g = zarr.open_group(str(task.path / "task.zarr" / "estimator" / "state"), mode="a")
    name = next(iter(g.array_keys()))
    g[name][...] = g[name][...] + 1
    assert f"task {task.digest[:12]} in {store.path} is damaged" in lost()
    store.delete(task.digest)
    assert f"task {task.digest[:12]} is no longer stored in {store.path}" in lost()


def test_replicates_calibrate_a_check_only_against_the_family_they_were_screened_against():
    """The joint calibration compares the recording's (omnibus, directional) pair with the replicates': each
    replicate keeps every candidate's statistic, so a check against any part of the family (a refit screens the
    family less its own effect) is calibrated by the maximum over that part; a candidate the replicates were not
    screened against is another procedure, and the omnibus test alone needs no family."""
    null = CheckNull(30, 64, (1.0, 2.0, 3.0), ((0.5, 0.1), (2.5, float("nan")), (1.0, 3.0)), ("wind", "heavy-hem"))
    assert null.calibrates([]) and null.calibrates(["heavy-hem", "wind"]) and null.calibrates(["wind"])
    assert not null.calibrates(["wind", "air-drag"])
    assert not CheckNull(30, 64, (1.0, 2.0)).calibrates(["wind"])  # stored before the joint calibration
    # beyond every replicate in both statistics: p = 1/4; the directional maximum over the asked part only
    assert null.joint_p_value(np.array([9.0, 9.0]), ["wind", "heavy-hem"]).value == pytest.approx(1 / 4)
    assert null.joint_p_value(np.array([0.9, 2.8]), ["wind"]).value == pytest.approx(2 / 4)
    assert null.joint_p_value(np.array([0.9, 2.8]), ["wind", "heavy-hem"]).value == pytest.approx(3 / 4)
    # a replicate whose only asked candidate could not be screened is left out
    assert null.joint_p_value(np.array([9.0, 9.0]), ["heavy-hem"]).n == 2
    with pytest.raises(SoftsbiError, match="not screened against"):
        null.joint_p_value(np.array([1.0, 1.0]), ["air-drag"])
    back = json.loads(json.dumps(null.to_json()))
    assert back["family"] == ["wind", "heavy-hem"] and back["directional"][1] == [2.5, None]
