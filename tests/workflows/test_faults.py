"""Fault injection (issue 18): every failure a new user or an unlucky operator meets is one clear
line naming the file and the fix, leaves nothing half-written, and the same command resumes.

Concurrent writers, deleted and truncated chunks, ``--retry-failed`` and an ``--out`` that is a
file are in ``test_run_safety.py``; ``MUJOCO_GL=bogus`` and a machine without OpenGL in
``tests/cli/test_no_gl.py``. Full and read-only disks need a small tmpfs: mounted when the tests
run as root with ``CAP_SYS_ADMIN``, skipped with that reason otherwise.
"""
import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from softsbi.cli import app
from softsbi.core.errors import STORAGE_ERRNOS, DataError, ParameterError, SchemaError, SoftsbiError, StorageError
from softsbi.core.metrics import describe_change
from softsbi.core.store import RunStore
from softsbi.workflows.fit.run import FitConfig, run_fit
from softsbi.workflows.fit.resume import resume_message
from softsbi.workflows.simulate import check_render_memory, render_memory_bytes

pytestmark = pytest.mark.integration

pytest.importorskip("softsbi_toy.plugin", reason="install tests/plugins/softsbi_toy (pip install -e)")
from toy_helpers import DATA, REPO, copy_lift_recording, toy_measurement  # noqa: E402

runner = CliRunner()
LIFT = DATA / "diffcloud_lift"


def _cfg(**kw):
    base = dict(backend="toy-gauss", estimator="mdnn", rounds=2, sims_per_round=30, workers=1, n_points=8, n_eval=3,
                n_dense=32, seed=3, estimator_options={"max_epochs": 10, "hidden": [16]})
    base.update(kw)
    return FitConfig(**base)


class _Messages:
    """Fit callbacks that keep the messages and can run an action after the k-th stored simulation."""

    def __init__(self, after=None, action=None):
        self.messages, self.after, self.action, self.n = [], after, action, 0

    def message(self, text):
        self.messages.append(text)

    def simulation_done(self, r, done, total):
        self.n += 1
        if self.after is not None and self.n == self.after:
            self.action()

    def __getattr__(self, name):
        return lambda *a, **k: None


@pytest.fixture
def tmpfs(tmp_path):
    """A fresh 8 MB tmpfs (root with CAP_SYS_ADMIN only)."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=8m", "tmpfs", str(mnt)], capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here (needs root with CAP_SYS_ADMIN): {r.stderr.strip()[:120]}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def _fill(disk):
    """Fill ``disk`` until the device refuses (ENOSPC); returns the filler file."""
    filler = disk / "filler"
    with open(filler, "wb") as fh:
        try:
            while True:
                fh.write(b"\0" * 65536)
                fh.flush()
        except OSError:
            pass
    return filler


def test_a_full_disk_mid_round_is_one_line_and_the_same_fit_resumes_to_the_same_result(tmpfs, tmp_path):
    reference = run_fit(tmp_path / "ref", toy_measurement(), _cfg(), make_plots=False)
    out = tmpfs / "run"
    filler = []
    cb = _Messages(after=12, action=lambda: filler.append(_fill(tmpfs)))
    with pytest.raises(StorageError) as err:
        run_fit(out, toy_measurement(), _cfg(), callbacks=cb, make_plots=False)
    line = str(err.value)
    assert "\n" not in line and err.value.errno == errno.ENOSPC and str(out) in line
    filler[0].unlink()  # space freed: the same call resumes from what was stored
    cb = _Messages()
    again = run_fit(out, toy_measurement(), _cfg(), callbacks=cb, make_plots=False)
    assert any(m.startswith("resuming") for m in cb.messages), cb.messages
    assert again.report.simulations == reference.report.simulations
    assert again.report.posterior_mean == reference.report.posterior_mean
    assert RunStore.open(out / "run.zarr").damaged() is None


def test_a_read_only_disk_is_one_line_for_a_new_and_for_a_finished_run(tmpfs):
    run_fit(tmpfs / "done", toy_measurement(), _cfg(rounds=1), make_plots=False)
    assert subprocess.run(["mount", "-o", "remount,ro", str(tmpfs)]).returncode == 0
    for out in (tmpfs / "new" / "run", tmpfs / "done"):
        with pytest.raises(StorageError, match="read-only") as err:
            run_fit(out, toy_measurement(), _cfg(rounds=1), make_plots=False)
        assert str(out) in str(err.value) and "\n" not in str(err.value)


def test_the_cli_turns_a_full_disk_into_one_line_and_exit_2(tmpfs):
    _fill(tmpfs)
    res = runner.invoke(app, ["simulate", "--backend", "toy-gauss", "--out", str(tmpfs / "r")])
    assert res.exit_code == 2, res.output
    assert STORAGE_ERRNOS[errno.ENOSPC] in res.output and "Traceback" not in res.output


@pytest.mark.parametrize("free_kb", [40, 160])
def test_a_disk_filling_up_mid_simulate_or_import_is_one_line_and_leaves_no_partial_folder(tmpfs, tmp_path,
                                                                                           free_kb):
    """numpy's short write (the disk fills inside one .npy: no errno) reads as the full disk; the folder
    being written is removed, so the same command works once space is freed."""
    filler = _fill(tmpfs)
    os.truncate(filler, filler.stat().st_size - free_kb * 1024)
    res = runner.invoke(app, ["simulate", "--backend", "toy-gauss", "--scenario", "lift", "--out",
                              str(tmpfs / "sim")])
    assert res.exit_code == 2 and STORAGE_ERRNOS[errno.ENOSPC] in res.output, res.output
    src = tmp_path / "src" / "rec"  # a DiffCloud-layout recording of large frames, imported with a scenario
    src.mkdir(parents=True)
    (src / "lift_real2sim.yaml").write_text("z_rotation: 0\ntranslation: [0, 0, 0]\nscale: 1\n")
    for i in range(3):
        np.save(src / f"{i:03d}.npy", np.random.default_rng(i).random((4000, 3)))
    res = runner.invoke(app, ["import", "diffcloud", str(src), str(tmpfs / "rec"), "--scenario", "lift"])
    assert res.exit_code == 2 and STORAGE_ERRNOS[errno.ENOSPC] in res.output, res.output
    assert "Traceback" not in res.output and len(res.output.strip().splitlines()) == 1
    assert [p.name for p in tmpfs.iterdir()] == ["filler"]  # nothing half-written, no hidden temporary folder
    filler.unlink()
    res = runner.invoke(app, ["simulate", "--backend", "toy-gauss", "--scenario", "lift", "--out", str(tmpfs / "sim")])
    assert res.exit_code == 0, res.output


def read_only_run(tmpfs, monkeypatch, module, rollouts: str):
    """A finished toy fit in ``tmpfs`` made read-only, with ``module``'s ``rollouts`` function failing the test if the
    command simulates posterior rollouts for it."""
    run_fit(tmpfs / "done", toy_measurement(), _cfg(rounds=1, n_eval=5), make_plots=False)
    assert subprocess.run(["mount", "-o", "remount,ro", str(tmpfs)]).returncode == 0

    def no_rollouts(*a, **k):
        raise AssertionError("simulated posterior rollouts for a run it cannot write to")
    monkeypatch.setattr(module, rollouts, no_rollouts)
    return tmpfs / "done"


def test_check_on_a_read_only_run_is_refused_before_its_rollouts(tmpfs, monkeypatch):
    import softsbi.workflows.criticism.check as check
    read_only_run(tmpfs, monkeypatch, check, "PosteriorPredictive")
    res = runner.invoke(app, ["check", str(tmpfs / "done"), "--n-eval", "5", "--workers", "1"])
    assert res.exit_code == 2, res.output
    line = " ".join(res.output.split())
    assert f"'{tmpfs / 'done'}'" in line and "--out" not in line  # the run directory; check has no --out


def test_a_garbage_store_is_one_line_naming_the_file(tmp_path):
    out = tmp_path / "run"
    run_fit(out, toy_measurement(), _cfg(rounds=1), make_plots=False)
    (out / "run.zarr" / "zarr.json").write_bytes(os.urandom(200))
    with pytest.raises(SchemaError) as err:
        run_fit(out, toy_measurement(), _cfg(rounds=1), make_plots=False)
    assert "run.zarr" in str(err.value) and "\n" not in str(err.value)


def _recording(tmp_path):
    return copy_lift_recording(tmp_path, LIFT)


def test_bad_recording_files_are_one_line_naming_file_and_fix(tmp_path):
    from softsbi.workflows.measurement import load_recording
    rec = _recording(tmp_path)
    good = (rec / "003.npy").read_bytes()
    (rec / "003.npy").write_bytes(os.urandom(500))  # random bytes: not numpy's allow_pickle advice
    with pytest.raises(DataError, match=r"003\.npy' is not a NumPy \.npy file") as err:
        load_recording(rec)
    assert "pickle" not in str(err.value)
    (rec / "003.npy").write_bytes(good[:90])  # truncated
    with pytest.raises(DataError, match=r"003\.npy' cannot be read"):
        load_recording(rec)
    np.save(rec / "003.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(DataError, match="holds Python objects"):
        load_recording(rec)
    (rec / "003.npy").write_bytes(good)
    yaml = rec / "lift_real2sim.yaml"
    yaml.write_text(yaml.read_text() + "z_rotation: [1,\n")
    with pytest.raises(DataError, match=r"lift_real2sim\.yaml is not valid YAML at line \d+, column \d+") as err:
        load_recording(rec)
    assert "\n" not in str(err.value)


def test_an_unknown_plugin_name_leaves_no_run_directory(tmp_path):
    out = tmp_path / "never"
    rec = _recording(tmp_path)
    res = runner.invoke(app, ["fit", "--observed", str(rec), "--out", str(out), "--estimator", "rkhz"])
    assert res.exit_code == 2 and "'rkhs'" in res.output  # the name meant
    assert not out.exists()
    kept = tmp_path / "kept"
    kept.mkdir()
    (kept / "notes.txt").write_text("mine")
    runner.invoke(app, ["fit", "--observed", str(rec), "--out", str(kept), "--estimator", "rkhz"])
    assert (kept / "notes.txt").exists()  # a directory the user made is never removed


def test_a_huge_render_is_refused_before_simulating_with_an_estimate_and_an_override(tmp_path):
    res = runner.invoke(app, ["simulate", "--render", "4000", "--out", str(tmp_path / "r")])
    assert res.exit_code == 2
    assert "4.8 GB" in res.output and "--render-memory-gb" in res.output and "Traceback" not in res.output
    assert not (tmp_path / "r").exists()
    assert check_render_memory(4000, 25, cap_gb=10) == render_memory_bytes(4000, 25)  # the override admits it
    with pytest.raises(SoftsbiError, match="positive"):
        check_render_memory(0, 25, cap_gb=4)


def test_a_prior_widened_beyond_the_declared_one_is_fitted(tmp_path):
    """The fix bound_sentence advises (``--bounds`` beyond the declared prior) runs: the fit draws and simulates
    values outside the declared box (toy-gauss declares a in [-1, 1]) and reports the widened prior."""
    res = run_fit(tmp_path / "w", toy_measurement(truth=(0.9, -0.4)), _cfg(bounds={"a": (-1.0, 3.0)}),
                  make_plots=False)
    assert res.report.parameters[0].high == 3.0
    theta = RunStore.open(tmp_path / "w" / "run.zarr", mode="r").round_data(0)["theta"]
    assert (theta[:, 0] > 1.0).any() and res.report.failed_simulations == 0
    with pytest.raises(ParameterError, match="physical limits"):
        run_fit(tmp_path / "w2", toy_measurement(), _cfg(bounds={"a": (-1.0, float("inf"))}), make_plots=False)


def test_out_of_bounds_values_advise_only_options_the_command_has(tmp_path):
    res = runner.invoke(app, ["simulate", "--theta", "bend=-5", "--out", str(tmp_path / "r")])
    assert res.exit_code == 2 and "bend" in res.output and "--bounds" not in res.output
    with pytest.raises(ParameterError, match="--fix.*--bounds"):
        run_fit(tmp_path / "f", toy_measurement(), _cfg(fixed={"a": 50.0}), make_plots=False)


def test_a_refused_write_advises_out_only_to_commands_that_have_it(tmp_path, capsys):
    """`view` and `calibrate` (no --out) were told to "choose --out" on a full or read-only disk."""
    import typer
    from softsbi.cli.calibrate_cmd import calibrate
    from softsbi.cli.command import _out_flag, guard
    from softsbi.cli.diagnose_cmd import diagnose
    from softsbi.cli.fit_cmd import fit
    from softsbi.cli.view_cmd import view
    from softsbi.core.errors import storage_error
    assert [_out_flag(c) for c in (view, calibrate, fit, diagnose)] == [None, None, "--out", "--out"]
    for errno_ in (errno.ENOSPC, errno.EROFS):
        line = str(storage_error(OSError(errno_, "refused"), "RUN", out_flag=None))
        assert "--out" not in line and ("re-run the same command" in line or "copy the run directory" in line)
        assert "--out" in str(storage_error(OSError(errno_, "refused"), "RUN"))

    def view_like(run: str = typer.Argument(...)):  # a command without --out whose write the disk refuses
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "view.gif"))

    with pytest.raises(typer.Exit):
        guard(view_like)(run="RUN")
    err = capsys.readouterr().err
    assert "no space left on the device" in err and "--out" not in err


def test_relative_changes_are_never_a_negative_lower():
    assert describe_change(5.77, 6.69) == "16% higher"
    assert describe_change(3.77, 1.25) == "67% lower"
    assert describe_change(2.0, 2.001) == "unchanged"
    assert describe_change(0.0, 1.0) == "n/a"


def test_resume_names_the_partly_stored_round_and_the_time_spent_and_rounds_count_from_one(tmp_path):
    out = tmp_path / "run"

    def stop():
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_fit(out, toy_measurement(), _cfg(), callbacks=_Messages(after=40, action=stop), make_plots=False)
    store = RunStore.open(out / "run.zarr")
    assert store.completed_rounds() == [0]
    assert store.config["wall_time_s"] > 0  # the interrupted session's time is kept
    assert store.is_begun(1) and len(store.pending(1)) == 20  # round 2: 10 of its 30 stored
    # the resumed fit begins with the resume line of this store and its time (the wording, rounds counted from one:
    # tests/report/test_progress_lines.py)
    said = resume_message(store, store.config["wall_time_s"])
    cb = _Messages()
    run_fit(out, toy_measurement(), _cfg(), callbacks=cb, make_plots=False)
    assert said in cb.messages
    # round 2 draws from the posterior of round 1 (rounds count from one wherever a user reads them)
    assert "round 1" in RunStore.open(out / "run.zarr").round_attrs(1)["proposal"]


@pytest.mark.slow
def test_a_crashing_simulator_with_one_worker_fails_its_simulations_not_the_command(tmp_path):
    """`softsbi fit --workers 1` ran simulations in its own process: a simulator that killed it (exit 14) ended the
    command without a word. One worker now runs in a process of its own, as with --workers 2."""
    rec = tmp_path / "rec"
    assert runner.invoke(app, ["simulate", "--backend", "toy-gauss", "--out", str(rec)]).exit_code == 0
    env = dict(os.environ, SOFTSBI_TOY_CRASH_ABOVE="0.8",  # a > 0.8: a tenth of the prior crashes
               PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    res = subprocess.run([sys.executable, "-m", "softsbi.cli", "fit", "--backend", "toy-gauss", "--rounds", "1",
                          "--sims-per-round", "20", "--workers", "1", "--retries", "0", "--n-eval", "3", "--points",
                          "8", "--estimator", "mdnn", "--estimator-opt", "max_epochs=5", "--observed", str(rec),
                          "--out", str(tmp_path / "run"), "--json"], capture_output=True, text=True, env=env,
                         timeout=300, check=False)
    assert res.returncode == 0, res.stderr[-2000:]
    assert json.loads(res.stdout)["per_round"][0]["failed"] > 0


SIGINT_FIT = [sys.executable, "-m", "softsbi.cli", "fit", "--backend", "toy-gauss", "--rounds", "1",
              "--sims-per-round", "60", "--workers", "1", "--n-eval", "3", "--points", "8", "--estimator", "mdnn",
              "--estimator-opt", "max_epochs=10"]


@pytest.mark.slow
@pytest.mark.parametrize("sig, code, word", [(signal.SIGINT, 130, "interrupted"),
                                             (signal.SIGTERM, 143, "terminated (SIGTERM)")])
def test_ctrl_c_or_sigterm_says_how_to_resume_and_the_same_command_resumes(tmp_path, sig, code, word):
    """SIGTERM (a scheduler's or `kill`'s stop) exited silently; now it stops the command as Ctrl-C does."""
    rec = tmp_path / "rec"  # a recording directory written by `softsbi simulate`
    made = runner.invoke(app, ["simulate", "--backend", "toy-gauss", "--out", str(rec)])
    assert made.exit_code == 0, made.output
    out = tmp_path / "run"
    cmd = SIGINT_FIT + ["--observed", str(rec), "--out", str(out)]
    # 0.2 s per simulation: the interrupt lands mid-round even on a loaded machine
    env = dict(os.environ, SOFTSBI_TOY_SLEEP="0.2",
               PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    # a user's shell leaves SIGINT at its default; an earlier test (e.g. Ray) may have left it ignored in this
    # process, and an ignored SIGINT is inherited (Python then installs no KeyboardInterrupt handler)
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.time() + 120
    while time.time() < deadline:  # wait until a few simulations are stored
        status = out / "run.zarr" / "rounds" / "0" / "status" / "c"
        if status.is_dir() and len(list(status.iterdir())) >= 5:
            break
        time.sleep(0.1)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == code, (stdout, stderr[-2000:])
    assert f"{word};" in " ".join(stderr.split())
    assert "Traceback" not in stderr
    store = RunStore.open(out / "run.zarr")
    stored = 60 - len(store.pending(0))
    assert 5 <= stored < 60
    # the resume line the same command begins with: round 1 and its stored simulations, the time spent
    said = resume_message(store, store.config.get("wall_time_s") or 0.0)
    again = subprocess.run(cmd + ["--json"], capture_output=True, text=True,
                           env=dict(env, SOFTSBI_TOY_SLEEP="0"), timeout=300)
    assert again.returncode == 0, again.stderr[-2000:]
    assert said in again.stderr
    assert json.loads(again.stdout)["simulations"] == 63


def test_a_bad_or_unusable_sensor_is_one_line(tmp_path):
    rec = _recording(tmp_path)
    out = tmp_path / "never"
    res = runner.invoke(app, ["fit", "--observed", str(rec), "--out", str(out), "--sensor", "lidar"])
    assert res.exit_code == 2 and "--sensor" in res.output and "'camera'" in res.output and not out.exists()
    # the virtual depth sensor needs a calibrated DiffCloud folder: one line naming the fix, before simulating
    res = runner.invoke(app, ["fit", "--observed", str(rec), "--out", str(out), "--sensor", "camera",
                              "--rounds", "1", "--sims-per-round", "10"])
    assert res.exit_code == 2 and "sensor='camera'" in res.output and "DiffCloud" in res.output
    assert "sensor='height'" in res.output and "Traceback" not in res.output  # the fix
    assert not out.exists()  # nothing left behind


LATE_SIGTERM = r"""
import atexit, os, signal, sys, time
from softsbi.cli.app import main


def late_sigterm():  # Python's exit handlers run after the command: a SIGTERM that lands while they do
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(5)


atexit.register(late_sigterm)
sys.argv = ["softsbi"] + sys.argv[1:]
main()
"""


@pytest.mark.slow
def test_a_sigterm_after_the_command_ended_is_no_traceback(tmp_path):
    """One SIGTERM in `softsbi check` printed a `Terminated` traceback: it landed after the command had ended, in
    Python's exit handlers. Outside a command SIGTERM ends the process at once (exit code 143), what the command
    printed kept."""
    out = tmp_path / "run"
    run_fit(out, toy_measurement(), _cfg(rounds=1), make_plots=False)
    script = tmp_path / "late_sigterm.py"
    script.write_text(LATE_SIGTERM)
    import softsbi
    code = Path(softsbi.__file__).parents[1]  # the softsbi under test
    env = dict(os.environ, PYTHONPATH=str(code) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    res = subprocess.run([sys.executable, str(script), "check", str(out), "--n-eval", "5", "--workers", "1"],
                         capture_output=True, text=True, env=env, timeout=300)
    assert res.returncode == 143 and "Traceback" not in res.stderr and "Terminated" not in res.stderr, res.stderr
    assert "misspecification test" in res.stdout and (out / "check.json").is_file()  # the ended command's output


def test_a_folder_named_check_null_json_in_the_task_store_is_refused_before_any_simulation(tmp_path, monkeypatch):
    import softsbi.workflows.tasks.training as training
    monkeypatch.setenv("SOFTSBI_SIM_BANK", str(tmp_path / "bank"))
    cfg = _cfg(rounds=1, n_points=16, n_dense=64, estimator_options={"max_epochs": 8})
    (task,) = training.train_task(toy_measurement(), cfg, 40, candidates=[], n_test=0, check_null=0)
    (task.path / "check-null.json").mkdir()

    def simulated(*a, **k):
        raise AssertionError("simulated before refusing the folder in check-null.json's place")
    monkeypatch.setattr(training, "run_jobs", simulated)
    with pytest.raises(SoftsbiError) as err:
        training.train_task(toy_measurement(), cfg, 40, candidates=[], n_test=0, check_null=19, retrain=True)
    line = str(err.value)
    assert str(task.path / "check-null.json") in line and "\n" not in line


def test_a_read_only_simulation_bank_is_refused_before_the_fit(tmpfs, tmp_path):
    (tmpfs / "bank").mkdir()
    assert subprocess.run(["mount", "-o", "remount,ro", str(tmpfs)]).returncode == 0
    rec = tmp_path / "rec"
    assert runner.invoke(app, ["simulate", "--backend", "toy-gauss", "--out", str(rec)]).exit_code == 0
    res = runner.invoke(app, ["fit", "--observed", str(rec), "--backend", "toy-gauss", "--rounds", "1",
                              "--sims-per-round", "10", "--workers", "1", "--sim-bank", str(tmpfs / "bank"),
                              "--out", str(tmp_path / "run")])
    assert res.exit_code == 2, res.output
    (line,) = res.output.strip().splitlines()
    assert f"--sim-bank {tmpfs / 'bank'} cannot be written" in line and "--no-sim-bank" in line
    assert not (tmp_path / "run").exists()


def test_view_of_a_read_only_run_is_refused_before_its_rollouts(tmpfs, monkeypatch):
    import softsbi.workflows.view as view
    read_only_run(tmpfs, monkeypatch, view, "posterior_rollouts")
    res = runner.invoke(app, ["view", str(tmpfs / "done"), "--n-eval", "2", "--workers", "1", "--no-rrd"])
    assert res.exit_code == 2, res.output
    (line,) = res.output.strip().splitlines()
    assert f"run directory '{tmpfs / 'done'}' cannot be written" in line and "copy the run directory" in line
