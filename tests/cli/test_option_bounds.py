"""Every numeric option is bounded in one place (:class:`~softsbi.core.defaults.Bound`): NaN and infinity are refused,
every count has a stated maximum, and each is refused in one line when the flags are parsed, before any work."""
import dataclasses
import inspect
import math
import re
import subprocess
import sys
import typing

import pytest
import typer
from typer.testing import CliRunner

from softsbi.cli import app
from softsbi.cli.options import names, parse_bounds, parse_kv
from softsbi.core import defaults as D
from softsbi.core.defaults import Bound, CheckSettings, DiagnoseSettings
from softsbi.core.errors import SoftsbiError

runner = CliRunner()


def _said(res) -> str:
    """The output in one line, out of typer's error box."""
    return " ".join(res.output.replace("│", " ").split())


def _options(kind: type):
    """``(command path, flag)`` of every option of every command whose values are of type ``kind`` (int or float,
    optional or not), read from the command function's annotations."""
    def walk(cmd, path):
        subs = getattr(cmd, "commands", None)
        if subs:
            for name, sub in subs.items():
                yield from walk(sub, path + [name])
            return
        hints = typing.get_type_hints(inspect.unwrap(cmd.callback))
        for p in cmd.params:
            if p.param_type_name == "option" and [a for a in typing.get_args(hints[p.name]) or (hints[p.name],)
                                                  if a is not type(None)] == [kind]:
                yield path, p.opts[0]
    return list(walk(typer.main.get_command(app), []))


def _bounds():
    """Every bound: the module's and the settings objects'."""
    mine = [v for v in vars(D).values() if isinstance(v, Bound)]
    return mine + [b for cls in (CheckSettings, DiagnoseSettings) for b in cls.BOUNDS.values()]


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_every_bound_and_settings_object_refuses_nan_and_infinity_naming_the_range(value):
    """`diagnose --k-se nan` completed and turned a right verdict into another ("by more than nan"); `--alpha nan`
    gave a traceback in check, compare and diagnose: NaN compares false with every bound, so it passed them."""
    for b in _bounds():
        assert b.problem(value) == f"must be a finite number {b.limit()} (got {value:g})" + (
            f": {b.why}" if b.why else ""), b.flag
    with pytest.raises(SoftsbiError, match=r"^--alpha must be a finite number > 0 and < 1 \(got nan\): a probability$"):
        CheckSettings(alpha=math.nan)
    with pytest.raises(SoftsbiError, match=r"^--k-se must be a finite number > 0 \(got inf\)"):
        DiagnoseSettings(k_se=math.inf)


def test_every_float_option_of_every_command_refuses_nan_and_infinity_when_parsed():
    """Each float flag of each command (found by its type, so that a new one is covered too), given nan or inf
    before anything else: exit code 2, the flag and 'a finite number' in one message, no traceback."""
    floats = _options(float)
    assert {"--alpha", "--k-se", "--min-height", "--sim-timeout", "--render-memory-gb"} <= {f for _, f in floats}
    for path, flag in floats:
        for value in ("nan", "inf", "-inf"):
            res = runner.invoke(app, [*path, flag, value])
            said = _said(res)
            assert res.exit_code == 2 and f"Invalid value for '{flag}': must be a finite number" in said, \
                (path, flag, value, res.output)
            assert "Traceback" not in res.output


def test_every_count_option_of_every_command_has_a_maximum_refused_when_parsed(tmp_path):
    """`check RUN --n-eval 1000000000` gave a 74.5 GiB allocation traceback and `diagnose --refit-sims 1000000000`
    planned 4.7e4 hours and started: each integer flag (found by its type) now refuses 1e12 in one line naming the
    flag, its maximum and why, before the command opens anything."""
    counts = _options(int)
    assert len(counts) >= 30, counts
    for path, flag in counts:
        res = runner.invoke(app, [*path, flag, "1000000000000"])
        assert res.exit_code == 2 and f"Invalid value for '{flag}': must be <= " in _said(res), (path, flag, res.output)
        assert "(got 1000000000000): " in _said(res) and "Traceback" not in res.output
    res = runner.invoke(app, ["check", str(tmp_path / "RUN"), "--n-eval", "1000000000"])
    assert res.exit_code == 2 and "'--n-eval': must be <= 10000 (got 1000000000): the null's first stage" in _said(res)
    assert str(tmp_path) not in res.output  # refused before the (missing) run is opened
    res = runner.invoke(app, ["diagnose", str(tmp_path / "RUN"), "--refit-sims", "1000000000"])
    assert res.exit_code == 2 and "'--refit-sims': must be <= 100000 (got 1000000000)" in _said(res)
    # the Python API's settings refuse the same, and accept the maximum itself
    with pytest.raises(SoftsbiError, match=r"^--n-eval must be <= 10000 \(got 1000000000\): "):
        CheckSettings(n_eval=10**9)
    with pytest.raises(SoftsbiError, match=r"^--refit-sims must be <= 100000 \(got 1000000000\): "):
        DiagnoseSettings(refit_sims=10**9)
    assert DiagnoseSettings(n_null=D.MAX_ROLLOUTS, refit_sims=D.MAX_SIMS, refit_rounds=D.MAX_ROUNDS,
                            workers=D.MAX_WORKERS, confirm=D.MAX_CONFIRM, max_null=D.MAX_ROLLOUTS).refit_sims == D.MAX_SIMS
    for b in _bounds():  # every count's bound says why it stops where it does
        assert b.high is None or (b.why and b.problem(b.high) is None and b.problem(b.high + 1)), b.flag


def test_name_value_options_refuse_nan_and_infinity_in_one_line():
    """--theta, --fix, --backend-opt, --estimator-opt, --opt (name=value) and --bounds (name=low:high) read 'nan' and
    'inf' as floats; they are refused naming the option and the item."""
    for value in ("nan", "inf", "-inf", "[1,nan]"):
        with pytest.raises(SoftsbiError, match=rf"^--fix 'bend={re.escape(value)}': .* is not a finite number"):
            parse_kv([f"bend={value}"], "--fix")
    with pytest.raises(SoftsbiError, match=r"^--bounds 'bend=0:inf': inf is not a finite number"):
        parse_bounds(["bend=0:inf"])
    assert parse_kv(["a=1,b=[1,2.5],c=name,d=true"], "--opt") == {"a": 1, "b": [1, 2.5], "c": "name", "d": True}
    assert parse_bounds(["bend=1e-6:1e-3"]) == {"bend": (1e-6, 1e-3)}


def test_task_train_refuses_a_check_null_that_cannot_reject_before_loading_anything():
    """A --check-null of 1 to 18 was refused only after the imports, the plugins and the recording (57 s on a
    laptop): now when the flags are parsed, by the rule the training workflow applies itself."""
    from softsbi.workflows.criticism.check_null import check_replicates
    for n in range(0, 25):
        try:
            check_replicates(n)
            workflow_refuses = False
        except SoftsbiError:
            workflow_refuses = True
        assert (D.CHECK_NULL_BOUND.problem(n) is not None) == workflow_refuses, n
        assert (D.REFIT_NULL_BOUND.problem(n) is not None) == workflow_refuses, n
    code = ("import sys; from typer.testing import CliRunner; from softsbi.cli import app; "
            "r = CliRunner().invoke(app, ['task', 'train', '--observed', 'no-recording', '--check-null', '5']); "
            "print(r.exit_code, ' '.join(r.output.replace('\\u2502', ' ').split())); "
            "print(sorted(m for m in ('numpy', 'softsbi.plugins.manager', 'softsbi.workflows.tasks.training') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120).stdout
    first, loaded = out.strip().splitlines()[-2:]
    assert first.startswith("2 ") and "'--check-null': must be 0 (none) or >= 19 (got 5)" in first, out
    assert "no-recording" not in first and loaded == "[]", out


def test_task_train_refuses_candidates_and_prior_bounds_before_loading_anything(monkeypatch):
    """--candidates that name no effect and a NaN prior bound: refused before the fit settings are made (and the
    plugins loaded), not after."""
    import softsbi.workflows.fit.run as fit_run
    monkeypatch.setattr(fit_run, "FitConfig", None)  # reached only after the checks
    for args, message in ((["--candidates", ",,"], "--candidates ',,' names no effect"),
                          (["--bounds", "bend=nan:1e-3"], "--bounds 'bend=nan:1e-3': nan is not a finite number")):
        res = runner.invoke(app, ["task", "train", "--observed", "no-recording", *args])
        assert res.exit_code == 2 and message in _said(res), res.output


def test_diagnose_refuses_an_empty_candidate_or_effect_name_in_one_line(tmp_path):
    """`diagnose RUN RUN RUN --candidate ''` dropped the empty name and weighed the default candidates instead."""
    runs = [str(tmp_path / f"run{i}") for i in range(3)]
    for args, flag in ((["--candidate", ""], "--candidate"), (["--candidate", "wind", "--candidate", ","], "--candidate"),
                       (["--effect", " "], "--effect")):
        res = runner.invoke(app, ["diagnose", *runs, "--out", str(tmp_path / "joint"), *args])
        lines = [ln for ln in res.output.splitlines() if ln.strip()]
        assert res.exit_code == 2 and len(lines) == 1 and lines[0].startswith(f"error: {flag} '"), res.output
        assert "names nothing" in lines[0] and not (tmp_path / "joint").exists()
    assert names(["wind,", "a,b"], "--effect") == ["wind", "a", "b"] and names(None, "--effect") == []


def test_check_and_diagnose_settings_declare_their_shared_fields_once():
    """n_eval/n_null aside, the fields of check and diagnose (max_null, alpha, workers, seed) and their bounds are
    declared on one base class; DiagnoseSettings keeps its names and its check()."""
    def fields(cls):
        return {f.name for f in dataclasses.fields(cls)}
    shared = fields(CheckSettings) & fields(DiagnoseSettings)
    assert shared == {"max_null", "alpha", "workers", "seed"}

    def owner(cls, name):
        return next(c for c in cls.__mro__ if name in inspect.get_annotations(c))
    assert {owner(CheckSettings, n) for n in shared} == {owner(DiagnoseSettings, n) for n in shared} != {CheckSettings}
    assert all(CheckSettings.BOUNDS[n] is DiagnoseSettings.BOUNDS[n] for n in shared)
    d = DiagnoseSettings(n_null=7, max_null=99, alpha=0.01, workers=3, seed=4, k_se=3.0)
    assert d.check() == CheckSettings(n_eval=7, max_null=99, alpha=0.01, workers=3, seed=4)
    assert DiagnoseSettings().n_null == D.N_NULL and CheckSettings().n_eval == D.N_NULL


def test_fit_settings_refuse_a_count_above_its_maximum_for_the_python_api_too():
    """`fit --sims-per-round 1000000000` is refused when the flags are parsed, but FitConfig(sims_per_round=10**9)
    (the Python API's softsbi.fit) validated and planned 1e9 simulations a round: each count of a fit's settings is
    now refused in one line naming the setting, the value, the maximum and why (the flag's own Bound), and the
    maximum itself is accepted."""
    from softsbi.workflows.fit.config import FitConfig
    cases = [("sims_per_round", D.SIMS_BOUND, "--sims-per-round"), ("rounds", D.ROUNDS_BOUND, "--rounds"),
             ("workers", D.WORKERS_BOUND, "--workers"), ("n_eval", D.EVAL_BOUND, "--n-eval"),
             ("n_points", D.POINTS_BOUND, "--points (n_points)"), ("seed", D.SEED_BOUND, "--seed"),
             ("sensor_draws", D.SENSOR_DRAWS_BOUND, "--sensor-draws"), ("refine", D.REFINE_BOUND, "--refine")]
    for name, bound, named in cases:
        with pytest.raises(SoftsbiError) as err:
            FitConfig(**{name: 10**12}).validate()
        assert str(err.value) == f"{named} must be <= {bound.high} (got 1000000000000): {bound.why}", name
        assert "\n" not in str(err.value)
    with pytest.raises(SoftsbiError, match=r"^--sims-per-round must be <= 100000 \(got 1000000000\): the estimator"):
        FitConfig(sims_per_round=10**9).validate()
    with pytest.raises(SoftsbiError, match=r"^--sims-per-round must be >= 10 \(got 3\): the estimator needs data"):
        FitConfig(sims_per_round=3).validate()  # the least value, in the flag's words too
    FitConfig(backend="toy-gauss", sims_per_round=D.MAX_SIMS, rounds=D.MAX_ROUNDS, workers=D.MAX_WORKERS,
              n_eval=D.MAX_ROLLOUTS, n_points=D.MAX_POINTS, seed=D.MAX_SEED, refine=D.MAX_SIMS).validate()


def test_every_command_refuses_an_empty_effect_or_candidate_name_in_one_line(tmp_path):
    """`fit --effect ''` fitted the nominal model, and `simulate`, `params` and `task train` dropped the empty name
    too: only diagnose refused it. Every command's --effect, --candidate and --candidates (found by the flag, so that
    a new command is covered too) now refuses it in one line before anything is written, by the one check
    (options.names) diagnose used."""
    required = {("fit",): ["--observed", str(tmp_path / "rec"), "--out", str(tmp_path / "out")],
                ("simulate",): ["--out", str(tmp_path / "out")],
                ("params",): ["lift"],
                ("task", "train"): ["--observed", str(tmp_path / "rec"), "--sim-bank", str(tmp_path / "out")],
                ("diagnose",): [str(tmp_path / "run"), str(tmp_path / "run2"), "--out", str(tmp_path / "out")],
                ("design",): [str(tmp_path / "run"), "--out", str(tmp_path / "out")]}
    found = [(tuple(path), flag) for path, flag in _options(str) if flag in ("--effect", "--candidate", "--candidates")]
    assert {p for p, _ in found} == set(required) and len(found) == 8, found
    for path, flag in found:
        for value in ("", ",", " "):
            res = runner.invoke(app, [*path, *required[path], flag, value])
            lines = [ln for ln in res.output.splitlines() if ln.strip()]
            assert res.exit_code == 2 and len(lines) == 1 and lines[0].startswith(f"error: {flag} '{value}' names "), \
                (path, flag, value, res.output)
            assert not (tmp_path / "out").exists(), (path, flag)
    res = runner.invoke(app, ["compare-backends", "--backends", ",", "--out", str(tmp_path / "out")])
    assert res.exit_code == 2 and "error: --backends ',' names nothing" in res.output, res.output
