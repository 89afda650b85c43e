"""The Python API as a script uses it: simulate_recording fills in what the CLI fills in, and fit, check, diagnose
and compare show their progress one line per phase on stderr unless asked not to."""
from __future__ import annotations

import pytest

import softsbi
import softsbi.workflows.api as api
from softsbi.workflows.reporting import phase


def test_simulate_recording_fills_in_the_parameters_not_given():
    toy = pytest.importorskip("softsbi_toy.plugin")
    from softsbi.plugins import registry
    sc = toy.toy_scenario(3)
    space = registry().simulator("toy-gauss")().param_space(sc)
    rec = softsbi.simulate_recording("toy-gauss", sc, {"a": 0.3}, n_points=8, n_dense=32)
    assert rec.truth == {"a": 0.3, "b": space.midpoint()["b"]}
    assert softsbi.simulate_recording("toy-gauss", sc, n_points=8, n_dense=32).truth == space.midpoint()


def _fake_fit(out, recording, cfg, callbacks=None, make_plots=True):
    """run_fit's progress calls for one round of 20 simulations, without simulating."""
    if callbacks is not None:
        callbacks.round_start(0, 1, 20, 20)
        callbacks.simulation_done(0, 20, 20)
        callbacks.round_end(0, {})
    return "fitted"


def _fake_check(run, settings=None, **rest):
    with phase("posterior-predictive rollouts", 30) as advance:
        advance(30)
    return "checked"


def test_api_calls_show_one_line_per_phase_on_stderr_unless_asked_not_to(monkeypatch, capsys):
    monkeypatch.setattr(api, "run_fit", _fake_fit)
    monkeypatch.setattr(api, "check_run", _fake_check)
    rec = softsbi.Recording(scenario=None, x=None, dense=None, source="")
    assert softsbi.fit(rec, "out", rounds=1) == "fitted" and softsbi.check("run") == "checked"
    out, err = capsys.readouterr()
    assert out == "" and err.splitlines() == [
        "fit: round 1/1: 20 simulations ...", "fit: round 1/1: done in 0 s",
        "posterior-predictive rollouts: 30 simulations ...", "posterior-predictive rollouts: done in 0 s"]
    softsbi.fit(rec, "out", rounds=1, progress=False)
    softsbi.check("run", progress=False)
    assert capsys.readouterr() == ("", "")


def _rendered(f, skip=()) -> str:
    """A function's parameters with their defaults, as docs/howto/python-api.md lists them."""
    import inspect
    out = []
    for p in inspect.signature(f).parameters.values():
        if p.name in skip:
            continue
        out.append("**" + p.name if p.kind is p.VAR_KEYWORD else p.name if p.default is p.empty
                   else f"{p.name}={p.default!r}")
    return ", ".join(out)


def _with_settings(cls, f, skip=()) -> str:
    """A workflow's settings as the API takes them: the settings object's fields, then the workflow's own keywords."""
    import dataclasses
    fields = ", ".join(f"{x.name}={x.default!r}" for x in dataclasses.fields(cls))
    return fields + ", " + _rendered(f, (*skip, "settings"))


def test_the_python_api_how_to_lists_each_function_with_the_code_s_signature_and_defaults():
    from pathlib import Path

    from softsbi.core.results import MCPValue
    from softsbi.workflows.criticism.check import check_run
    from softsbi.workflows.criticism.compare import compare_runs
    from softsbi.workflows.criticism.diagnose import diagnose_run
    from softsbi.core.defaults import CheckSettings, DiagnoseSettings
    doc = (Path(__file__).parents[2] / "docs" / "howto" / "python-api.md").read_text()
    for name in ("load_scenario", "load_recording", "simulate_recording", "simulate", "fit", "open_run", "check",
                 "diagnose", "compare", "calibrate_run", "import_diffcloud", "train_task"):
        assert f"softsbi.{name}({_rendered(getattr(softsbi, name))})\n" in doc, name
    assert f"`check`'s `settings`: `{_with_settings(CheckSettings, check_run, ('run_dir',))}`" in doc
    assert (f"`diagnose`'s `settings`: "
            f"`{_with_settings(DiagnoseSettings, diagnose_run, ('run_dir', 'effects', 'progress', 'out_dir'))}`") in doc
    assert (
        f"`compare`'s `settings`: `{_with_settings(CheckSettings, compare_runs, ('run_a', 'run_b', 'out_dir'))}`" in doc
    )
    assert (
        "SOFTSBI_PLUGINS" in doc
        and "MCPValue" in doc
        and MCPValue(exceed=3, n=30).p_value == MCPValue(exceed=3, n=30).value
    )
