"""Damaged, missing or unwritable stored results (report.json, check.json, diagnosis.json) and two diagnoses of one
run: one line naming the file and the command that rewrites it, never a traceback, never a ``.tmp`` left; a reused
result says so; a second diagnose is refused before any work; ``diagnose --out`` keeps two diagnoses apart."""
import errno
import json
import shutil
import subprocess

import pytest
from typer.testing import CliRunner

import softsbi
import softsbi.core.results.comparison as comparison
import softsbi.core.jsonfile as jsonfile
import softsbi.core.results as results
from softsbi.cli import app
from softsbi.core.errors import SoftsbiError
from softsbi.workflows.criticism import check, diagnose
from softsbi.workflows.fit.run import FitCallbacks, FitConfig, run_fit
from softsbi.workflows.fit.runs import RunView
from softsbi.workflows.lock import RunLocked, run_lock
from softsbi.workflows.tasks import calibrate
from softsbi.core.defaults import CheckSettings, DiagnoseSettings

pytestmark = pytest.mark.integration

pytest.importorskip("softsbi_toy.plugin", reason="install tests/plugins/softsbi_toy (pip install -e)")
from toy_helpers import toy_measurement  # noqa: E402

runner = CliRunner()
#: the diagnose settings of every test here: no refit, the check's own null (so the stored check.json is reused)
DIAG = dict(settings=DiagnoseSettings(confirm=0, n_null=5, workers=1), plots=False)


def _cfg():
    return FitConfig(backend="toy-gauss", estimator="mdnn", rounds=2, sims_per_round=60, n_points=8, n_eval=5,
                     n_dense=32, workers=1, seed=3, estimator_options={"max_epochs": 30, "hidden": [16]})


@pytest.fixture(scope="module")
def checked(tmp_path_factory):
    """A finished toy fit with its check.json (n_eval 5)."""
    out = tmp_path_factory.mktemp("stored") / "run"
    run_fit(out, toy_measurement(), _cfg(), make_plots=False)
    check.check_run(out, plot=False, settings=CheckSettings(n_eval=5, workers=1))
    return out


@pytest.fixture
def run(checked, tmp_path):
    """A copy of :func:`checked` to damage."""
    return shutil.copytree(checked, tmp_path / "run")


def _no_work(monkeypatch):
    def fail(*a, **k):
        raise AssertionError("work was spent before the refusal")
    for mod in (check, diagnose):
        monkeypatch.setattr(mod, "PosteriorPredictive", fail)
    monkeypatch.setattr(RunView, "posterior_rollouts", fail)
    monkeypatch.setattr(calibrate, "_test_simulations", fail)


def _error_line(res):
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output and (res.exception is None or isinstance(res.exception, SystemExit))
    lines = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, res.output
    return " ".join(res.output[res.output.index("error:"):].split())


@pytest.mark.parametrize("text", ["{bad", '{"parameters": [{"name": "a"', "", "{}"])
def test_a_damaged_report_is_one_line_from_every_command(run, tmp_path, text, monkeypatch):
    _no_work(monkeypatch)
    (run / "report.json").write_text(text)
    for argv in (["check", str(run)], ["diagnose", str(run)], ["view", str(run), "--no-rrd"],
                 ["compare", str(run), str(run), "--out", str(tmp_path / "cmp")]):
        line = _error_line(runner.invoke(app, argv))
        assert f"'{run / 'report.json'}'" in line and f"`softsbi fit ... --out {run}`" in line, argv  # file, command
    with pytest.raises(SoftsbiError, match="report.json' is damaged"):
        softsbi.open_run(run)


def test_a_report_that_is_a_folder_is_one_line_whose_fix_works(run, monkeypatch):
    """The fit refuses to write over a folder, so the advice is to move it first; then the same fit writes it."""
    _no_work(monkeypatch)
    (run / "report.json").unlink()
    (run / "report.json").mkdir()
    line = _error_line(runner.invoke(app, ["check", str(run)]))
    assert f"'{run / 'report.json'}'" in line and "a folder" in line
    assert "moving or removing that folder, then re-running the fit" in line and f"--out {run}`" in line
    (run / "report.json").rmdir()  # the advice, followed
    run_fit(run, toy_measurement(), _cfg(), make_plots=False)
    assert json.loads((run / "report.json").read_text())["posterior_median"]


def test_re_running_the_fit_repairs_a_damaged_report_and_says_so(run):
    good = json.loads((run / "report.json").read_text())
    (run / "report.json").write_text('{"parameters": [')
    said = []

    class Said(FitCallbacks):
        def message(self, text):
            said.append(text)
    run_fit(run, toy_measurement(), _cfg(), callbacks=Said(), make_plots=False)
    assert json.loads((run / "report.json").read_text())["posterior_median"] == good["posterior_median"]
    assert any(f"'{run / 'report.json'}'" in s for s in said), said
    assert any(s.startswith(f"rewrote {run / 'report.json'}") for s in said), said


@pytest.mark.parametrize("name, argv", [("check.json", ["check", "{run}", "--n-eval", "5"]),
                                        ("diagnosis.json", ["diagnose", "{run}", "--n-null", "5", "--confirm", "0"]),
                                        ("check.png", ["check", "{run}", "--n-eval", "5", "--recompute"]),
                                        ("check.png", ["compare", "{run}", "{run}", "--out", "{run}/cmp"]),
                                        ("view.gif", ["view", "{run}", "--no-rrd"]),
                                        ("view.gif", ["view", "{run}", "--no-rrd", "--json"]),
                                        ("calibration.png", ["calibrate", "{run}", "--n-test", "20"])])
def test_a_result_file_or_figure_that_is_a_folder_is_refused_before_any_work(run, monkeypatch, name, argv):
    _no_work(monkeypatch)
    (run / name).unlink(missing_ok=True)
    (run / name).mkdir()
    res = runner.invoke(app, [a.format(run=run) for a in argv])
    if "--json" in argv:  # one JSON error, no IsADirectoryError
        assert res.exit_code == 2 and "Traceback" not in res.output, res.output
        line = json.loads(res.output)["error"]
    else:
        line = _error_line(res)
    assert f"'{run / name}'" in line and "is a folder" in line
    assert not (run / f"{name}.tmp").exists()


def test_a_damaged_check_is_computed_again_and_a_full_disk_names_the_file_and_leaves_no_tmp(run, monkeypatch):
    """check has no --out: the full disk's line names check.json; the damaged file it would replace is left."""
    (run / "check.json").write_text("{bad")

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(jsonfile.os, "fsync", full)
    res = runner.invoke(app, ["check", str(run), "--n-eval", "5", "--workers", "1"])
    line = _error_line(res)
    assert any(ln.startswith(f"{run / 'check.json'} ") for ln in res.output.splitlines())  # said: not usable
    assert f"'{run / 'check.json'}'" in line  # the error: the file it cannot write
    assert "--out" not in line
    assert (run / "check.json").read_text() == "{bad" and not (run / "check.json.tmp").exists()
    assert f"wrote {run / 'check.json'}" not in res.output


def test_diagnose_says_what_it_wrote_or_reused_even_on_a_read_only_run(run, tmp_path, monkeypatch):
    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")
    with monkeypatch.context() as m:
        m.setattr(jsonfile.os, "fsync", full)
        with pytest.raises(SoftsbiError) as err:
            diagnose.diagnose_run(run, **DIAG)
    assert isinstance(err.value, results.ResultUnwritable) and err.value.errno == errno.ENOSPC
    assert f"'{run / 'diagnosis.json'}'" in str(err.value)
    assert not (run / "diagnosis.json").exists() and not (run / "diagnosis.json.tmp").exists()
    (run / "diagnosis.json").write_text("")  # damaged: computed again, saying so
    said = []
    first = diagnose.diagnose_run(run, progress=said.append, **DIAG)
    assert any(s.startswith(f"{run / 'diagnosis.json'} ") for s in said), said  # not usable: computed again
    assert said[-1] == f"wrote {run / 'diagnosis.json'}"
    said.clear()
    assert diagnose.diagnose_run(run, progress=said.append, **DIAG) == first
    assert not any(s.startswith("wrote") for s in said) and said[-1].startswith(f"reused {run / 'diagnosis.json'}")
    # a read-only run directory: the stored result is reused, and nothing claims to have been written
    disk = tmp_path / "disk"
    disk.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64m", "tmpfs", str(disk)], capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here (needs root with CAP_SYS_ADMIN): {r.stderr.strip()[:120]}")
    try:
        ro = shutil.copytree(run, disk / "run")
        assert subprocess.run(["mount", "-o", "remount,ro", str(disk)]).returncode == 0
        res = runner.invoke(app, ["diagnose", str(ro), "--n-null", "5", "--confirm", "0", "--workers", "1"])
        assert res.exit_code == 0, res.output
        assert f"reused {ro / 'diagnosis.json'}" in res.output and "wrote" not in res.output
        # a diagnosis whose check must be computed again: with --out elsewhere, its check is written there
        res = runner.invoke(app, ["diagnose", str(ro), "--n-null", "6", "--confirm", "0", "--workers", "1",
                                  "--out", str(tmp_path / "elsewhere")])
        assert res.exit_code == 0, res.output
        assert {p.name for p in (tmp_path / "elsewhere").iterdir()} >= {"check.json", "diagnosis.json"}
    finally:
        subprocess.run(["umount", "-l", str(disk)], capture_output=True)


def test_a_diagnosis_says_up_front_how_many_refits_and_simulations_are_coming_with_an_estimate(run, tmp_path):
    from softsbi.core.results.fitreport import FitReport, RoundRow
    rep = FitReport(parameters=("a",), posterior_median={"a": 1.0}, rounds=3, sims_per_round=400, simulations=1230,
                    wall_time_s=600.0)
    assert diagnose.diagnosis_plan(rep, 9, 2, n_null=30) == (
        "diagnose plan: the check's 30 posterior rollouts and the screening of 9 candidates, then, if the check "
        "rejects, up to 3 refits (the top 2 candidates, then a pair) of about 1260 simulations each (3 rounds x 400 "
        "simulations, then its check): 3810 simulations at most; "
        "about 31 min at the nominal fit's pace (1230 simulations in 10 min) (--confirm 2 sets the number of refits)")
    assert diagnose.diagnosis_plan(rep, 9, 1, refit_rounds=1, refit_sims=100, n_null=30).startswith(
        "diagnose plan: the check's 30 posterior rollouts and the screening of 9 candidates, then, if the check "
        "rejects, up to 1 refit (the top candidate) of about 160 simulations each (1 round x 100 simulations, then its "
        "check): 190 simulations at most; about 2 min")
    one = FitReport(parameters=("a",), posterior_median={"a": 1.0}, rounds=1, sims_per_round=400, simulations=430,
                    wall_time_s=43.0, per_round=(RoundRow(round=0, task="k" * 64),))  # stopped at its trained task
    # an untrained candidate's refit of such a run runs the default rounds, and the plan says so (it said 1 round)
    assert diagnose.diagnosis_plan(one, 9, 2, n_null=30, amortised=6) == (
        "diagnose plan: the check's 30 posterior rollouts and the screening of 9 candidates, then, if the check "
        "rejects, the amortised posteriors of the 6 trained candidates (10 to 30 rollouts each, as their decision needs; a "
        "trained candidate's refit "
        "simulates no round) and up to 3 refits (the top 2 candidates, then a pair) of about 1660 simulations each (4 "
        "rounds x 400 simulations, then its check) when "
        "no task trained the candidate: 5190 simulations at most; about 9 min at the nominal fit's pace (430 "
        "simulations in 43 s) (--confirm 2 sets the number of refits)")
    assert "of about 460 simulations each (1 round x 400" in diagnose.diagnosis_plan(
        one, 9, 2, refit_rounds=1, n_null=30, amortised=0)
    assert diagnose.diagnosis_plan(FitReport(parameters=("a",), posterior_median={"a": 1.0}), 4, 0) == (
        "diagnose plan: the check's 30 posterior rollouts and the screening of 4 candidates")
    said = []  # said first, before any simulation
    diagnose.diagnose_run(
        run,
        progress=said.append,
        out_dir=tmp_path / "d",
        settings=DiagnoseSettings(confirm=2, n_null=5, workers=1),
        plots=False,
    )
    assert said[0].startswith("diagnose plan: the check's 5 posterior rollouts") and "up to 3 refits" in said[0]


def test_a_second_diagnose_is_refused_at_once_and_told_to_wait_or_use_out(run, monkeypatch):
    _no_work(monkeypatch)
    with run_lock(run, command="diagnose"):
        with pytest.raises(RunLocked) as err:
            diagnose.diagnose_run(run, **DIAG)
    line = str(err.value)
    assert "`softsbi diagnose`" in line and "pid" in line and "\n" not in line  # the other command and its pid
    assert f"`softsbi diagnose {run} --out OTHER_FOLDER`" in line and "fit into another --out" not in line


def test_diagnose_out_keeps_a_second_diagnosis_apart(run, tmp_path):
    res = runner.invoke(app, ["diagnose", str(run), "--n-null", "5", "--confirm", "0", "--workers", "1",
                              "--out", str(tmp_path / "second")])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "second" / "diagnosis.json").is_file() and not (run / "diagnosis.json").exists()
    assert f"wrote {tmp_path / 'second' / 'diagnosis.json'}" in res.output
    assert f"reused {run / 'check.json'}" in res.output  # the run's own check, same settings: read, not written
    # other settings: the check is computed again into --out, and the run's check.json and check.png stay as they were
    before = (run / "check.json").read_bytes()
    res = runner.invoke(app, ["diagnose", str(run), "--n-null", "6", "--confirm", "0", "--workers", "1",
                              "--out", str(tmp_path / "third")])
    assert res.exit_code == 0, res.output
    assert (run / "check.json").read_bytes() == before and not (run / "check.png").exists()
    assert (tmp_path / "third" / "check.json").is_file() and (tmp_path / "third" / "check.png").is_file()
    assert f"wrote {tmp_path / 'third' / 'check.json'} and {tmp_path / 'third' / 'check.png'}" in res.output
    said = []  # the Python API takes the same folder and reuses the result there
    d = softsbi.diagnose(run, out=tmp_path / "second", progress=said.append, **DIAG)
    assert said[-1].startswith(f"reused {tmp_path / 'second' / 'diagnosis.json'}") and d.run == str(run)
    assert not (run / "diagnosis.json").exists()


def test_compare_computes_a_damaged_check_again_saying_so(run, tmp_path):
    (run / "check.json").write_text("{}")
    res = runner.invoke(app, ["compare", str(run), str(run), "--out", str(tmp_path / "cmp"), "--n-eval", "5",
                              "--workers", "1"])
    assert res.exit_code == 0, res.output
    assert any(ln.startswith(f"{run / 'check.json'} ") and "'key'" in ln for ln in res.output.splitlines())
    assert f"reused {run / 'check.json'}" in res.output  # the second run's check: the one just written
    assert json.loads((run / "check.json").read_text())["type"] == "CheckResult"


@pytest.mark.parametrize("name", ["report.json", "posterior_pairs.png"])
def test_a_fit_whose_report_json_or_figure_is_a_folder_is_refused_before_simulating(tmp_path, name):
    out = tmp_path / "run"
    (out / name).mkdir(parents=True)
    with pytest.raises(SoftsbiError, match=f"{name}' is a folder, not a file"):
        run_fit(out, toy_measurement(), _cfg(), make_plots=True)
    assert not (out / "run.zarr").exists()


def test_the_python_api_compares_runs_given_as_plain_strings(checked, tmp_path):
    """`softsbi.compare("a", "b")` failed at `str.mkdir` after both checks had run; it takes str like Path, and its
    `alpha` reaches both checks (a level other than the stored check.json's computes them again)."""
    a, b = (str(shutil.copytree(checked, tmp_path / name)) for name in ("a", "b"))
    res = softsbi.compare(a, b, out=str(tmp_path / "cmp"), n_eval=5, workers=1, progress=False)
    assert (res.run_a, res.run_b) == (a, b) and res.png == str(tmp_path / "cmp" / "compare.png")
    assert (tmp_path / "cmp" / "compare.json").is_file() and (tmp_path / "cmp" / "compare.png").is_file()
    assert res.row(comparison.Metric.CHAMFER).a == res.check_a.chamfer_mean_m
    res = softsbi.compare(a, b, n_eval=5, workers=1, alpha=0.2, max_null=20, progress=False)
    assert res.check_a.test.alpha == res.check_b.test.alpha == 0.2 and res.png == str(tmp_path / "b" / "compare.png")
    stored = results.from_json(results.CheckResult, json.loads((tmp_path / "a" / "check.json").read_text()))
    assert stored.test.alpha == 0.2


def test_compare_refuses_an_alpha_out_of_range_before_any_work(checked, tmp_path, monkeypatch):
    _no_work(monkeypatch)
    with pytest.raises(SoftsbiError, match=r"--alpha must be > 0 and < 1 \(got 1.5\): a probability"):
        softsbi.compare(str(checked), str(checked), out=str(tmp_path / "cmp"), alpha=1.5, progress=False)
    assert not (tmp_path / "cmp").exists()
    res = runner.invoke(app, ["compare", str(checked), str(checked), "--alpha", "1.5"])
    assert res.exit_code == 2 and "--alpha" in res.output, res.output


def test_an_asked_refit_budget_is_kept_when_the_run_stopped_at_its_stored_task():
    """`diagnose --refit-rounds N` was dropped as "the run's own" when N equalled the run's rounds, and a run that had
    stopped at its stored task then refitted an untrained candidate at the default 4 rounds: 3, 4 and 1 rounds for
    one setting, depending on which recording filled the task first."""
    from types import SimpleNamespace
    from softsbi.core.results.fitreport import FitReport, RoundRow
    cfg = SimpleNamespace(rounds=1, sims_per_round=100)
    at_task = SimpleNamespace(config=cfg, report=FitReport(parameters=("a",), posterior_median={"a": 1.0}, rounds=1,
                                                            per_round=(RoundRow(round=0, task="k" * 64),)))
    sequential = SimpleNamespace(config=cfg, report=FitReport(parameters=("a",), posterior_median={"a": 1.0},
                                                              rounds=1, per_round=(RoundRow(round=0),)))
    asked = DiagnoseSettings(refit_rounds=1, refit_sims=100)
    assert diagnose.refit_budget(at_task, asked) == (1, None)
    assert diagnose.refit_budget(sequential, asked) == (None, None)  # the run's own: one stored key
    assert diagnose.refit_budget(at_task, DiagnoseSettings()) == (None, None)
