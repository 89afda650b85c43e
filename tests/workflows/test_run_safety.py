"""Runs that cannot be lost (issue 18, first part): one writer per run directory, and stored
failures that can be retried once the cause is fixed."""
import json
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from softsbi.core.errors import SoftsbiError
from softsbi.core.store import RunStore
from softsbi.core.types import STATUS_OK, STATUS_PENDING
from softsbi.workflows.fit.run import FitConfig, run_fit
from softsbi.workflows.lock import RunLocked, run_lock

pytestmark = pytest.mark.integration

pytest.importorskip("softsbi_toy.plugin", reason="install tests/plugins/softsbi_toy (pip install -e)")
from toy_helpers import TESTS_DIR, toy_measurement  # noqa: E402

FIT = r"""
import sys
sys.path.insert(0, {tests!r})
from toy_helpers import toy_measurement
from softsbi.workflows.fit.run import FitConfig, run_fit
from softsbi.workflows.lock import RunLocked
cfg = FitConfig(backend="toy-gauss", estimator="mdnn", rounds=1, sims_per_round=40, workers=1, n_points=8,
                n_eval=3, n_dense=32, seed={seed}, estimator_options={{"max_epochs": 10, "hidden": [16]}})
try:
    run_fit({out!r}, toy_measurement(), cfg, make_plots=False)
except RunLocked as exc:
    print("LOCKED", exc)
    sys.exit(2)
print("DONE")
"""


def _cfg(**kw):
    base = dict(backend="toy-gauss", estimator="mdnn", rounds=2, sims_per_round=30, workers=1, n_points=8, n_eval=3,
                n_dense=32, seed=1, estimator_options={"max_epochs": 10, "hidden": [16]})
    base.update(kw)
    return FitConfig(**base)


def test_a_second_writer_fails_at_once_naming_the_holder(tmp_path):
    """Two fits started on one fresh run directory with different seeds: the second stops at once with
    one line naming the first's pid; the first finishes and the store holds its run only."""
    out = tmp_path / "run"
    env = dict(os.environ, SOFTSBI_TOY_SLEEP="0.1")
    first = subprocess.Popen([sys.executable, "-c", FIT.format(tests=str(TESTS_DIR), out=str(out), seed=1)],
                             env=env, stdout=subprocess.PIPE, text=True)
    deadline = time.time() + 60
    while not (out / "run.lock.json").exists() and time.time() < deadline:
        time.sleep(0.05)
    t0 = time.time()
    second = subprocess.run([sys.executable, "-c", FIT.format(tests=str(TESTS_DIR), out=str(out), seed=2)],
                            env=env, capture_output=True, text=True, timeout=120)
    assert second.returncode == 2, (second.stdout, second.stderr[-2000:])
    assert f"pid {first.pid}" in second.stdout and str(out) in second.stdout
    assert time.time() - t0 < 30  # at once, not after the first fit
    assert first.wait(timeout=300) == 0 and "DONE" in first.stdout.read()
    assert RunStore.open(out / "run.zarr").config["seed"] == 1


def test_the_lock_is_released_after_a_fit_and_refused_inside_one(tmp_path):
    with run_lock(tmp_path / "r"):
        with pytest.raises(RunLocked, match="being written by another softsbi process"):
            with run_lock(tmp_path / "r"):
                pass
    with run_lock(tmp_path / "r"):  # released: taken again
        pass


def test_retry_failed_resimulates_stored_failures_and_redraws_later_rounds(tmp_path, monkeypatch):
    out = tmp_path / "run"
    monkeypatch.setenv("SOFTSBI_SIM_BANK", str(tmp_path / "bank"))  # with the user's bank on, as by default
    monkeypatch.setenv("SOFTSBI_TOY_DIVERGE_ABOVE", "0.5")  # a > 0.5 "diverges": stored as failed
    res = run_fit(out, toy_measurement(), _cfg(), make_plots=False)
    failed0 = int(res.report.per_round[0].failed)
    assert failed0 > 0
    monkeypatch.delenv("SOFTSBI_TOY_DIVERGE_ABOVE")
    messages, cb = _recording_callbacks()
    again = run_fit(out, toy_measurement(), _cfg(), callbacks=cb, make_plots=False)  # plain resume keeps them
    assert again.report.per_round[0].failed == failed0
    assert any("--retry-failed" in m for m in messages), messages  # the flag that simulates them again
    fixed = run_fit(out, toy_measurement(), _cfg(), make_plots=False, retry_failed=True)
    assert fixed.report.failed_simulations == 0
    store = RunStore.open(out / "run.zarr")
    assert store.completed_rounds() == [0, 1]
    assert np.all(store.round_data(0)["status"] == STATUS_OK)
    assert store.round_attrs(0)["failures"] == {}


def test_reset_failures_without_failures_changes_nothing(tmp_path):
    out = tmp_path / "run"
    run_fit(out, toy_measurement(), _cfg(rounds=1), make_plots=False)
    store = RunStore.open(out / "run.zarr")
    assert store.reset_failures() is None
    assert store.completed_rounds() == [0] and not np.any(store.round_data(0)["status"] == STATUS_PENDING)
    assert json.loads((out / "run.lock.json").read_text())["pid"] == os.getpid()


def _recording_callbacks():
    """Fit callbacks that keep every message (``(messages, callbacks)``) and ignore every other hook."""
    messages = []

    class Recorder:
        def message(self, text):
            messages.append(text)

        def __getattr__(self, name):
            return lambda *a, **k: None

    return messages, Recorder()


def _chunk(out, r, name, i):
    """The file of simulation ``i``'s chunk of array ``name`` in round ``r`` (one simulation per chunk)."""
    base = out / "run.zarr" / "rounds" / str(r) / name / "c" / str(i)
    files = [base] if base.is_file() else [p for p in base.rglob("*") if p.is_file()]
    assert len(files) == 1, files
    return files[0]


def test_missing_and_damaged_chunks_are_named_resimulated_and_never_trained_on(tmp_path):
    out = tmp_path / "run"
    cfg = _cfg()
    first = run_fit(out, toy_measurement(), cfg, make_plots=False)
    before = RunStore.open(out / "run.zarr").round_data(0)
    _chunk(out, 0, "x", 3).unlink()                       # a deleted chunk
    p = _chunk(out, 0, "x", 5)
    p.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 2])  # a truncated chunk
    _chunk(out, 0, "status", 7).unlink()                  # a simulation whose "done" mark is gone
    store = RunStore.open(out / "run.zarr")
    r, bad = store.damaged()
    assert r == 0 and sorted(bad) == [3, 5, 7], bad
    assert "cannot be read" in bad[5] and "missing" in bad[3] and "status" in bad[7]
    messages, cb = _recording_callbacks()

    again = run_fit(out, toy_measurement(), cfg, callbacks=cb, make_plots=False)
    assert any("simulations [3, 5, 7]" in m and "again" in m for m in messages), messages
    after = RunStore.open(out / "run.zarr")
    assert after.damaged() is None and after.completed_rounds() == [0, 1]
    d = after.round_data(0)
    assert np.all(d["status"] == STATUS_OK)
    np.testing.assert_array_equal(d["x"], before["x"])  # the same seeds give the same simulations
    # the report is written from the posterior it reports: the same data give the same numbers
    assert again.report.posterior_mean == first.report.posterior_mean
    assert again.report.chamfer_posterior_m == first.report.chamfer_posterior_m


def test_an_out_that_is_a_file_or_unwritable_is_one_clear_line(tmp_path):
    from typer.testing import CliRunner

    from softsbi.cli import app
    afile = tmp_path / "afile"
    afile.write_text("x")
    r = CliRunner().invoke(app, ["fit", "--observed", str(tmp_path), "--out", str(afile)])
    assert r.exit_code == 2
    with pytest.raises(SoftsbiError, match="is a file, not a run directory"):
        with run_lock(afile):
            pass
    with pytest.raises(SoftsbiError, match="cannot write the run directory"):
        with run_lock("/proc/softsbi-cannot-be-here"):
            pass


def _first_chunk(group_dir):
    files = sorted(p for p in (group_dir / "c").rglob("*") if p.is_file())
    return files[0]


def test_a_damaged_evaluation_or_round_posterior_is_computed_again_and_never_breaks_check(tmp_path):
    """The chunk repair covers every group: fit computes a damaged evaluation or round posterior again (from
    the stored simulations and seeds: the same numbers); check, view, compare and diagnose read only the
    evaluation's samples, which they simulate again."""
    from softsbi.workflows.fit.runs import load_run
    out = tmp_path / "run"
    cfg = _cfg(n_eval=5)
    first = run_fit(out, toy_measurement(), cfg, make_plots=False)
    for part in ("evaluation/chamfer", "rounds/0/posterior/means"):
        p = _first_chunk(out / "run.zarr" / part)
        p.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 2])
    assert len(load_run(out, 5).post_theta) == 5  # what check & co. open: no traceback
    store = RunStore.open(out / "run.zarr")
    assert set(store.damaged_groups()) == {"evaluation", "rounds/0/posterior"}
    messages, cb = _recording_callbacks()

    again = run_fit(out, toy_measurement(), cfg, callbacks=cb, make_plots=False)
    assert any("evaluation'" in m and "'chamfer'" in m for m in messages), messages  # the group and its array
    assert any("rounds/0/posterior'" in m for m in messages), messages
    assert RunStore.open(out / "run.zarr").damaged_groups() == {}
    assert again.report.posterior_mean == first.report.posterior_mean
    assert again.report.chamfer_posterior_m == first.report.chamfer_posterior_m


def test_unreadable_store_metadata_is_one_line_naming_the_file_and_the_fix(tmp_path):
    import shutil

    from typer.testing import CliRunner

    from softsbi.cli import app
    out = tmp_path / "run"
    first = run_fit(out, toy_measurement(), _cfg(n_eval=5), make_plots=False)
    meta = out / "run.zarr" / "rounds" / "0" / "status" / "zarr.json"
    meta.write_bytes(os.urandom(300))
    with pytest.raises(SoftsbiError) as err:
        run_fit(out, toy_measurement(), _cfg(n_eval=5), make_plots=False)
    line = str(err.value)
    assert f"'{meta}'" in line and "\n" not in line and "rounds/0" in line  # the file and the folder to remove
    res = CliRunner().invoke(app, ["check", str(out), "--workers", "1"])
    assert res.exit_code == 2 and "zarr.json" in res.output and "Traceback" not in res.output
    for sub in ("rounds/0", "rounds/1", "evaluation"):  # the fix the message gives
        shutil.rmtree(out / "run.zarr" / sub)
    again = run_fit(out, toy_measurement(), _cfg(n_eval=5), make_plots=False)
    assert again.report.posterior_mean == first.report.posterior_mean


@pytest.mark.slow
def test_a_damaged_observed_is_rebuilt_from_the_recording_by_fit_check_and_view(tmp_path):
    """The observed state is the recording as the fit observed it: a damaged chunk of it is rebuilt from the
    recording named in the run's settings, in one line, by check and view as by fit, never a codec's traceback;
    a recording that is gone is one line naming the fit command that rebuilds it."""
    import shutil

    from typer.testing import CliRunner

    from softsbi.cli import app
    from softsbi.workflows.measurement import load_recording
    runner = CliRunner()
    rec = tmp_path / "rec"
    res = runner.invoke(app, ["simulate", "--backend", "toy-gauss", "--scenario", "lift", "--out", str(rec)])
    assert res.exit_code == 0, res.output
    out = tmp_path / "run"
    cfg = _cfg(n_eval=5)
    first = run_fit(out, load_recording(rec, n_points=cfg.n_points, seed=cfg.seed), cfg, make_plots=False)
    good = RunStore.open(out / "run.zarr").read_observed()

    def damage(name):
        p = _first_chunk(out / "run.zarr" / "observed" / name)
        p.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 2])

    def same_observed():
        back = RunStore.open(out / "run.zarr").read_observed()
        assert sorted(back) == sorted(good) and all(np.array_equal(back[k], good[k]) for k in good)

    for name, argv in (("x", ["check", str(out), "--n-eval", "5", "--workers", "1"]),
                       ("dense", ["view", str(out), "--n-eval", "2", "--workers", "1", "--no-rrd", "--json"])):
        damage(name)
        res = runner.invoke(app, argv)
        assert res.exit_code == 0 and "Traceback" not in res.output, res.output
        said = [ln for ln in res.output.splitlines() if "rebuilt it from the recording" in ln]
        assert len(said) == 1 and f"'{name}'" in said[0] and str(rec) in " ".join(res.output.split()), res.output
        same_observed()
    damage("x")
    messages, cb = _recording_callbacks()
    again = run_fit(out, load_recording(rec, n_points=cfg.n_points, seed=cfg.seed), cfg, callbacks=cb,
                    make_plots=False)
    assert any("observed'" in m and "rebuilt it from the recording" in m for m in messages), messages
    same_observed()
    assert again.report.posterior_mean == first.report.posterior_mean
    damage("x")
    shutil.rmtree(rec)  # nothing to rebuild it from: the fit command that does, in one line
    res = runner.invoke(app, ["check", str(out), "--n-eval", "5", "--workers", "1", "--recompute"])
    assert res.exit_code == 2 and "Traceback" not in res.output, res.output
    line = " ".join(res.output.split())
    assert "observed'" in line and f"--observed {rec}" in line and f"--out {out}" in line


def test_a_half_written_array_or_round_is_resumed_without_zarr_warnings(tmp_path, recwarn):
    """A kill while an array or a round was being created leaves a folder without metadata: it is no member of the
    store, the resumed fit writes it again, and zarr's warning about it never reaches the user."""
    from zarr.errors import ZarrUserWarning
    out = tmp_path / "run"
    first = run_fit(out, toy_measurement(), _cfg(rounds=1), make_plots=False)
    (out / "run.zarr" / "rounds" / "1").mkdir()  # a round whose zarr.json was never written
    (out / "run.zarr" / "rounds" / "0" / "half" / "c").mkdir(parents=True)  # an array's chunks, no metadata
    (out / "run.zarr" / "rounds" / "0" / "half" / "c" / "0").write_bytes(b"x")
    recwarn.clear()
    again = run_fit(out, toy_measurement(), _cfg(rounds=2), make_plots=False)
    assert [str(w.message) for w in recwarn if issubclass(w.category, ZarrUserWarning)] == []
    assert RunStore.open(out / "run.zarr").completed_rounds() == [0, 1] and again.report.rounds == 2
    assert first.report.per_round[0].usable == again.report.per_round[0].usable  # round 1 as before


def _replace_array(out, path, value):
    """Replace the store array ``path`` (``"rounds/0/x"``) of run ``out`` with a well-formed array ``value``."""
    import shutil

    from softsbi.core.store.posterior import put_array
    shutil.rmtree(out / "run.zarr" / path)
    group, name = path.rsplit("/", 1)
    put_array(RunStore.open(out / "run.zarr").root[group], name, value,
              tuple(f"dim_{i}" for i in range(value.ndim)), "m")


def test_a_round_array_of_the_wrong_shape_is_one_line_naming_it_and_the_fix(tmp_path):
    """A well-formed array of the wrong shape is damage: named with its shape, the expected one and the fix, which
    works (never numpy's reshape error from the chunk check)."""
    import shutil
    out = tmp_path / "run"
    cfg = _cfg(rounds=1)
    first = run_fit(out, toy_measurement(), cfg, make_plots=False)
    x = RunStore.open(out / "run.zarr").round_data(0)["x"]
    _replace_array(out, "rounds/0/x", x[:20])  # a short round
    short = f"its 'x' array has shape (20, {', '.join(map(str, x.shape[1:]))}), expected {x.shape}"
    assert RunStore.open(out / "run.zarr").damaged_groups() == {"rounds/0": short}
    with pytest.raises(SoftsbiError) as err:
        run_fit(out, toy_measurement(), cfg, make_plots=False)
    line = str(err.value)
    assert "\n" not in line and short in line and f"remove the folder '{out / 'run.zarr' / 'rounds' / '0'}'" in line
    shutil.rmtree(out / "run.zarr" / "rounds" / "0")  # the fix the line gives
    shutil.rmtree(out / "run.zarr" / "evaluation")
    again = run_fit(out, toy_measurement(), cfg, make_plots=False)
    assert again.report.posterior_mean == first.report.posterior_mean


@pytest.mark.slow
def test_an_observed_array_of_the_wrong_shape_is_rebuilt_by_check_and_fit(tmp_path):
    from typer.testing import CliRunner

    from softsbi.cli import app
    from softsbi.workflows.measurement import load_recording
    rec = tmp_path / "rec"
    res = CliRunner().invoke(app, ["simulate", "--backend", "toy-gauss", "--scenario", "lift", "--out", str(rec)])
    assert res.exit_code == 0, res.output
    out = tmp_path / "run"
    cfg = _cfg(rounds=1)
    run_fit(out, load_recording(rec, n_points=cfg.n_points, seed=cfg.seed), cfg, make_plots=False)
    good = RunStore.open(out / "run.zarr").read_observed()
    T = len(good["times"])
    _replace_array(out, "observed/x", np.zeros((3, 2)))
    res = CliRunner().invoke(app, ["check", str(out), "--n-eval", "5", "--workers", "1"])
    assert res.exit_code == 0 and "Traceback" not in res.output, res.output
    said = [ln for ln in res.output.splitlines() if "rebuilt it from the recording" in ln]
    assert len(said) == 1 and f"its 'x' array has shape (3, 2), expected ({T}, *, 3)" in said[0], res.output
    assert np.array_equal(RunStore.open(out / "run.zarr").read_observed()["x"], good["x"])
    _replace_array(out, "observed/x", np.zeros((3, 2)))
    messages, cb = _recording_callbacks()  # a resumed fit rebuilds it too, and its next round is drawn
    again = run_fit(out, load_recording(rec, n_points=cfg.n_points, seed=cfg.seed), _cfg(rounds=2), callbacks=cb,
                    make_plots=False)
    assert any("(3, 2)" in m and "rebuilt it from the recording" in m for m in messages), messages
    assert again.report.rounds == 2
    assert np.array_equal(RunStore.open(out / "run.zarr").read_observed()["x"], good["x"])


def test_the_api_check_says_when_it_replaces_a_check_of_other_settings(tmp_path, recwarn):
    """softsbi.check(run, effects=[...]) replaced the run's check.json without a word: it now warns, naming what
    changed, and out_dir keeps both."""
    import softsbi
    from softsbi.core.errors import SoftsbiWarning
    out = tmp_path / "run"
    run_fit(out, toy_measurement(), _cfg(rounds=1, n_eval=5), make_plots=False)
    first = softsbi.check(out, n_eval=5, workers=1, progress=False)
    softsbi.check(out, n_eval=5, workers=1, progress=False)  # the same settings: reused, nothing said
    assert [w for w in recwarn if issubclass(w.category, SoftsbiWarning)] == []
    with pytest.warns(SoftsbiWarning) as said:
        softsbi.check(out, n_eval=5, workers=1, progress=False, effects=[])
    (line,) = [str(w.message) for w in said if issubclass(w.category, SoftsbiWarning)]
    assert line == (f"replaced {out / 'check.json'}, which held the check of other settings (family "
                    f"{sorted(first.test.family)!r} -> []); pass out_dir=... to keep both")
    assert first.test.family  # the default family: the run's own check.json was replaced by one without it
