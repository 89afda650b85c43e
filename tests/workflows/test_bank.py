"""The simulation bank (softsbi.workflows.fit.bank): rollouts stored by what determines them and read back."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from softsbi.core.errors import SoftsbiError
from softsbi.core.types import STATUS_DIVERGED, Rollout
from softsbi.workflows.fit.bank import SimulationBank, check_bank_path, rollout_key

pytestmark = pytest.mark.integration


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
    # a speed knob (rollouts per simulate_batch call) gives the same rollouts: the same key
    assert rollout_key(base[0], {"grid": 7, "batch_size": 8}, *base[2:]) == k


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
    from softsbi.workflows.fit.run import FitConfig, run_fit
    monkeypatch.setenv("SOFTSBI_SIM_BANK", str(tmp_path / "bank"))
    calls = []
    original = toy.ToyGauss.simulate
    monkeypatch.setattr(toy.ToyGauss, "simulate", lambda self, *a, **k: calls.append(1) or original(self, *a, **k))
    cfg = FitConfig(backend="toy-gauss", rounds=1, sims_per_round=40, workers=1, n_points=16, n_dense=64, n_eval=5,
                    estimator="mdnn", estimator_options={"max_epochs": 5})
    run_fit(tmp_path / "a", toy_measurement(truth=(0.3, -0.4)), cfg, make_plots=False)
    first = len(calls)
    b = run_fit(tmp_path / "b", toy_measurement(truth=(-0.2, 0.1)), cfg, make_plots=False)
    assert first >= 40 and len(calls) - first < 40  # the second fit's 40 first-round rollouts came from the bank
    off = run_fit(tmp_path / "c", toy_measurement(truth=(-0.2, 0.1)), FitConfig(**{**cfg.__dict__, "sim_bank": "off"}),
                  make_plots=False)
    np.testing.assert_array_equal(b.store.round_data(0)["x"], off.store.round_data(0)["x"])


def _move(bank, src: str, dst: str) -> None:
    """Put ``src``'s entry folder in ``dst``'s place, as a user moving or copying folders by hand would."""
    import shutil
    shutil.rmtree(bank._where(dst), ignore_errors=True)
    bank._where(dst).parent.mkdir(parents=True, exist_ok=True)
    shutil.copytree(bank._where(src), bank._where(dst))


def test_an_entry_under_another_key_is_detected_and_an_old_one_is_a_miss(tmp_path):
    """The checksum covers the key: an intact entry copied into another key's place is not read as that key's."""
    import zarr
    from softsbi.workflows.fit.bank import HIT, MISS, WRONG_KEY
    bank = SimulationBank(tmp_path / "bank")
    a, b = "ab" * 32, "cd" * 32
    assert bank.put(a, _rollout(0)) and bank.put(b, _rollout(1))
    _move(bank, a, b)
    assert bank.lookup(b) == (None, WRONG_KEY) and bank.get(b) is None
    assert bank.lookup(a)[1] == HIT
    assert bank.put(b, _rollout(1)) and bank.lookup(b)[1] == HIT  # replaced
    np.testing.assert_array_equal(bank.get(b).vertices, _rollout(1).vertices)
    g = zarr.open_group(str(bank._where(a)), mode="a")  # an entry of the first format stored no key
    del g.attrs["key"]
    assert bank.lookup(a) == (None, MISS)


def _fit_cfg(**kw):
    from softsbi.workflows.fit.run import FitConfig
    return FitConfig(backend="toy-gauss", rounds=1, sims_per_round=20, workers=1, n_points=16, n_dense=64, n_eval=5,
                     estimator="mdnn", estimator_options={"max_epochs": 5}, **kw)


def test_a_fit_reports_its_bank_hits_and_replaces_entries_under_another_key(tmp_path, monkeypatch):
    """Report and progress count what the bank gave; two swapped entries are simulated again and replaced, with
    one warning line, and the round equals a fit without a bank."""
    pytest.importorskip("softsbi_toy.plugin")
    from toy_helpers import toy_measurement
    from softsbi.workflows.fit.bank import HIT
    from softsbi.workflows.fit.run import FitCallbacks, run_fit
    monkeypatch.setenv("SOFTSBI_SIM_BANK", str(tmp_path / "bank"))

    class Told(FitCallbacks):
        def __init__(self):
            self.messages, self.read = [], []

        def message(self, text):
            self.messages.append(text)

        def read_from_bank(self, r, hits, total):
            self.read.append((r, hits, total))

    a = run_fit(tmp_path / "a", toy_measurement(), _fit_cfg(), callbacks=(told_a := Told()), make_plots=False)
    assert a.report.bank_hits == 0 and a.report.per_round[0].bank_hits == 0 and not told_a.read
    bank = SimulationBank(tmp_path / "bank")
    keys = sorted(p.name for p in (tmp_path / "bank").glob("??/*"))
    assert len(keys) == 20
    _move(bank, keys[0], keys[1])
    _move(bank, keys[2], keys[3])
    b = run_fit(tmp_path / "b", toy_measurement(), _fit_cfg(), callbacks=(told := Told()), make_plots=False)
    assert b.report.bank_hits == 18 and b.report.per_round[0].bank_hits == 18
    assert told.read == [(0, 18, 20)]
    warned = [m for m in told.messages if "another rollout's key" in m]
    assert len(warned) == 1 and "2 stored" in warned[0]
    assert all(bank.lookup(k)[1] == HIT for k in keys)  # replaced by what the keys' parameters give
    off = run_fit(tmp_path / "c", toy_measurement(), _fit_cfg(sim_bank="off"), make_plots=False)
    np.testing.assert_array_equal(b.store.round_data(0)["x"], off.store.round_data(0)["x"])
    # a resumed fit keeps the count (stored with the round)
    again = run_fit(tmp_path / "b", toy_measurement(), _fit_cfg(), make_plots=False)
    assert again.report.per_round[0].bank_hits == 18


@pytest.mark.parametrize("terminal", [False, True])
def test_progress_says_how_many_were_read_from_the_bank(terminal, monkeypatch):
    """On a terminal and in a pipe: a phase tells the CLI its bank reads once, when all its simulations are done, and
    the CLI prints one line for each bank read (their wording: tests/report/test_progress_lines.py)."""
    import io
    from rich.console import Console
    from softsbi.cli.output import Output
    from softsbi.cli.progress import PhaseReporter, ProgressHooks
    from softsbi.workflows.reporting import phase, reporting
    told = []
    read = PhaseReporter.read_from_bank
    monkeypatch.setattr(PhaseReporter, "read_from_bank",
                        lambda self, handle, hits, total: told.append((hits, total)) or read(self, handle, hits, total))
    o = Output()
    buf = io.StringIO()
    o.err = Console(file=buf, force_terminal=terminal, width=200, highlight=False, markup=False)
    said = []
    message = o.message
    o.message = lambda text, style=None: said.append(text) or message(text, style)
    with o.progress() as p:
        hooks = ProgressHooks(o, p)
        hooks.round_start(0, 2, 20, 20)
        hooks.read_from_bank(0, 20, 20)
        n_round = len(said)
        with reporting(PhaseReporter(o, p)), phase("posterior-predictive rollouts", 10) as advance:
            for done in range(1, 10):
                advance(done, min(done, 7))
            assert told == []  # not before the phase's last simulation is done
            advance(10, 7)
            assert told == [(7, 10)]
    # in a pipe a phase also says when it begins and ends (a round when it begins); on a terminal its bar does
    assert (n_round, len(said)) == ((1, 2) if terminal else (2, 5))
    text = buf.getvalue()
    assert all(m + "\n" in text for m in said)  # each message whole, on a line of its own


def test_run_jobs_counts_the_runs_own_bank_and_warns_of_entries_under_another_key(tmp_path):
    """check, diagnose, compare and view re-simulate through the run's bank: the phase is told its hits, and a
    swapped entry is one warning line."""
    toy = pytest.importorskip("softsbi_toy.plugin")
    from softsbi.workflows.fit.bank import HIT, WRONG_KEY
    from softsbi.workflows.fit.jobs import JobItem, SimContext, run_jobs
    from softsbi.workflows.reporting import Reporter, reporting

    class Told(Reporter):
        def __init__(self):
            self.read, self.messages = [], []

        def read_from_bank(self, handle, hits, total):
            self.read.append((hits, total))

        def message(self, text):
            self.messages.append(text)

    sc = toy.toy_scenario(3)
    ctx = SimContext(backend="toy-gauss", backend_options={}, scenario=sc.to_json(), effects=[], observer="pointcloud",
                     observer_options={"n_points": 16}, param_names=["a", "b"], fixed={}, dense=None, n_dense=64,
                     bank=str(tmp_path / "bank"))
    items = [JobItem(np.array([0.1 * i, -0.1 * i]), i) for i in range(4)]
    with reporting(first := Told()):
        run_jobs(ctx, items, workers=1)
    assert first.read == [] and first.messages == []
    bank = SimulationBank(tmp_path / "bank")
    keys = sorted(p.name for p in (tmp_path / "bank").glob("??/*"))
    _move(bank, keys[0], keys[1])
    with reporting(second := Told()):
        res = run_jobs(ctx, items, workers=1)
    assert second.read == [(3, 4)] and len(second.messages) == 1 and "1 stored" in second.messages[0]
    assert sorted(r.bank for r in res) == [HIT, HIT, HIT, WRONG_KEY]  # the bank status of each result
    # a bank that cannot store (here its tmp/ is a file; a full disk alike) stored nothing, silently: now one line
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "tmp").write_text("")
    with reporting(third := Told()):
        res = run_jobs(replace(ctx, bank=str(tmp_path / "full")), items, workers=1)
    assert [r.status for r in res] == [0] * 4 and len(SimulationBank(tmp_path / "full")) == 0
    assert len(third.messages) == 1 and "4 rollout(s) could not be stored" in third.messages[0]


def _refused(args, tmp_path):
    from typer.testing import CliRunner
    from softsbi.cli import app
    res = CliRunner().invoke(app, ["fit", "--backend", "toy-gauss", "--observed", str(tmp_path / "rec"), "--out",
                                   str(tmp_path / "run"), *args])
    assert res.exit_code != 0 and "Traceback" not in res.output, res.output
    return " ".join(res.output.split())


def test_bank_paths_are_checked_before_any_work(tmp_path, monkeypatch):
    """An empty --sim-bank, a bank inside the run or the recording, a bank that is a file or cannot be created:
    one line naming the flag, before the recording is read (it does not exist here) and before anything is
    written."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("SOFTSBI_SIM_BANK", str(tmp_path / "user-bank"))
    (tmp_path / "rec").mkdir()
    (tmp_path / "file").write_text("not a folder")
    assert "--sim-bank" in _refused(["--sim-bank", ""], tmp_path)
    for bank, flag in ((tmp_path / "run" / "bank", "--out"), (tmp_path / "rec" / "bank", "--observed")):
        line = _refused(["--sim-bank", str(bank)], tmp_path)
        assert f"--sim-bank {bank}" in line and flag in line  # the bank and the flag it is inside
    line = _refused(["--sim-bank", str(tmp_path)], tmp_path)
    assert f"--out {tmp_path / 'run'}" in line and "--sim-bank" in line
    assert "--sim-bank " + str(tmp_path / "file") + " is a file" in _refused(["--sim-bank", str(tmp_path / "file")],
                                                                             tmp_path)
    assert str(tmp_path / "file" / "bank") in _refused(["--sim-bank", str(tmp_path / "file" / "bank")], tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "rec"]  # nothing written, no run begun


def test_the_bank_named_by_the_environment_is_checked_alike(tmp_path, monkeypatch):
    from softsbi.core.errors import SoftsbiError
    from softsbi.workflows.fit.bank import check_bank_path
    (tmp_path / "file").write_text("not a folder")
    for bad, why in [(tmp_path / "file", "is a file"), (tmp_path / "file" / "b", "cannot be created"),
                     (tmp_path / "run" / "b", "is inside --out")]:
        monkeypatch.setenv("SOFTSBI_SIM_BANK", str(bad))
        assert f"SOFTSBI_SIM_BANK {bad} {why}" in _refused([], tmp_path)
        assert "SOFTSBI_SIM_BANK=off" in _refused([], tmp_path)
        with pytest.raises(SoftsbiError, match="SOFTSBI_SIM_BANK"):  # the API checks it too
            check_bank_path("default", {"--out": tmp_path / "run"})
    monkeypatch.setenv("SOFTSBI_SIM_BANK", str(tmp_path / "new" / "bank"))
    check_bank_path("default", {"--out": tmp_path / "run", "--observed": None})
    assert (tmp_path / "new" / "bank").is_dir()  # created


def test_the_api_refuses_an_empty_bank_before_any_work(tmp_path, monkeypatch):
    pytest.importorskip("softsbi_toy.plugin")
    from toy_helpers import toy_measurement
    from softsbi.core.errors import SoftsbiError
    from softsbi.workflows.fit.run import run_fit
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("SOFTSBI_SIM_BANK", str(tmp_path / "user-bank"))
    with pytest.raises(SoftsbiError, match="--sim-bank is empty"):
        run_fit(tmp_path / "run", toy_measurement(), _fit_cfg(sim_bank=""))
    assert not (tmp_path / "run").exists() and not list(tmp_path.glob("??"))


def test_contradictory_bank_flags_and_a_bad_batch_size_are_refused_and_an_explicit_bank_wins_over_off(tmp_path,
                                                                                                   monkeypatch):
    """`--sim-bank DIR --no-sim-bank` and batch_size 0 or -3 (silently 1) were accepted; `SOFTSBI_SIM_BANK=off`
    silently overrode an explicit `--sim-bank DIR`: the flag given on the command line wins."""
    from softsbi.workflows.fit.bank import bank_folder
    from softsbi.workflows.fit.task_store import task_store_of
    monkeypatch.chdir(tmp_path)
    (tmp_path / "rec").mkdir()
    line = _refused(["--sim-bank", str(tmp_path / "b"), "--no-sim-bank"], tmp_path)
    assert f"--sim-bank {tmp_path / 'b'} and --no-sim-bank contradict each other" in line
    for size in ("0", "-3", "1.5"):
        assert f"--backend-opt batch_size must be an integer >= 1 (got {size})" in \
            _refused(["--backend-opt", f"batch_size={size}"], tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec"]  # nothing written
    monkeypatch.setenv("SOFTSBI_SIM_BANK", "off")
    assert bank_folder(str(tmp_path / "b")) == tmp_path / "b" and bank_folder("default") is None
    assert task_store_of(str(tmp_path / "b")).path == tmp_path / "b" / "tasks"
    with pytest.raises(SoftsbiError, match="is a file"):  # and it is checked as any explicit bank
        (tmp_path / "file").write_text("")
        check_bank_path(str(tmp_path / "file"), {})
