"""The simulation bank (softsbi.workflows.bank): rollouts stored by what determines them and read back."""
from __future__ import annotations

import numpy as np
import pytest

from softsbi.core.types import STATUS_DIVERGED, Rollout
from softsbi.workflows.bank import SimulationBank, rollout_key


def _rollout(seed: int = 0) -> Rollout:
    rng = np.random.default_rng(seed)
    return Rollout(times=np.arange(3) * 0.1, gripper=rng.random((3, 3)), vertices=rng.random((3, 4, 3)),
                   faces=np.array([[0, 1, 2], [0, 2, 3]]), info={"min_visible_z": 0.01, "centres": np.zeros(3)})


def test_the_key_is_everything_a_rollout_depends_on():
    base = ("mujoco-flex", {"grid": 7}, {"name": "lift", "times": [0, 0.1]}, ["wind"], {"bend": 1e-4, "wind_x": 0.5}, 3)
    k = rollout_key(*base)
    assert k == rollout_key(*base) and len(k) == 64
    for i, other in enumerate([{"grid": 9}, {"name": "lift", "times": [0, 0.2]}, ["air-drag"],
                               {"bend": 1e-4, "wind_x": 0.5 + 1e-15}, 4]):
        changed = list(base)
        changed[i + 1] = other
        assert rollout_key(*changed) != k, i


def test_a_stored_rollout_reads_back_identical_and_a_damaged_one_counts_as_absent(tmp_path):
    bank = SimulationBank(tmp_path / "bank")
    ro = _rollout()
    assert bank.get("ab" * 32) is None and bank.put("ab" * 32, ro) and len(bank) == 1
    back = bank.get("ab" * 32)
    for name in ("times", "gripper", "vertices", "faces"):
        np.testing.assert_array_equal(getattr(back, name), getattr(ro, name))
    assert back.info == {"min_visible_z": 0.01} and back.status == ro.status  # arrays in info are not kept
    chunk = next(p for p in (tmp_path / "bank").rglob("*") if p.is_file() and "vertices" in p.parts and
                 p.name != "zarr.json")
    chunk.write_bytes(chunk.read_bytes()[:-7])  # a truncated chunk
    assert bank.get("ab" * 32) is None
    assert bank.put("ab" * 32, ro) and bank.get("ab" * 32) is not None  # stored anew
    assert not list((tmp_path / "bank" / "tmp").iterdir())  # nothing half-written is left


def test_a_failed_rollout_is_not_kept(tmp_path):
    """A failure may come from the environment, not the parameters: a retry must simulate it again."""
    bank = SimulationBank(tmp_path / "bank")
    failed = _rollout()
    failed.status, failed.reason = STATUS_DIVERGED, "diverged"
    assert not bank.put("cd" * 32, failed) and len(bank) == 0 and bank.get("cd" * 32) is None


def test_a_read_only_bank_stores_nothing(tmp_path):
    bank = SimulationBank(tmp_path / "ro", writable=False)
    assert not bank.put("cd" * 32, _rollout()) and bank.get("cd" * 32) is None


def test_a_second_fit_of_the_same_task_reads_its_first_round_from_the_bank(tmp_path, monkeypatch):
    """Two fits of two recordings of one toy task: the second simulates none of its first round (the same prior
    and seed draw the same parameters), and its stored simulations equal those it would have simulated."""
    toy = pytest.importorskip("softsbi_toy.plugin")
    from toy_helpers import toy_measurement
    from softsbi.workflows.fit import FitConfig, run_fit
    monkeypatch.setenv("SOFTSBI_SIM_BANK", str(tmp_path / "bank"))
    calls = []
    original = toy.ToyGauss.simulate
    monkeypatch.setattr(toy.ToyGauss, "simulate", lambda self, *a, **k: calls.append(1) or original(self, *a, **k))
    cfg = FitConfig(backend="toy-gauss", rounds=1, sims_per_round=40, workers=1, n_points=16, n_dense=64, n_eval=5,
                    estimator="mdnn", estimator_options={"max_epochs": 5})
    run_fit(tmp_path / "a", toy_measurement(truth=(0.3, -0.4)), cfg)
    first = len(calls)
    b = run_fit(tmp_path / "b", toy_measurement(truth=(-0.2, 0.1)), cfg)
    assert first >= 40 and len(calls) - first < 40  # the second fit's 40 first-round rollouts came from the bank
    off = run_fit(tmp_path / "c", toy_measurement(truth=(-0.2, 0.1)), FitConfig(**{**cfg.__dict__, "sim_bank": "off"}))
    np.testing.assert_array_equal(b.store.round_data(0)["x"], off.store.round_data(0)["x"])
