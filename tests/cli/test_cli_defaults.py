"""Every CLI default is its library default: each option of a command that the library also takes must default
to the value of the FitConfig field or workflow parameter it sets (None: "the library's"), and every other
option with a default is named here as the CLI's own."""
import dataclasses
import inspect
import re
from enum import Enum
from pathlib import Path

import typer

from softsbi.cli import app
from softsbi.executors.local import LocalExecutor
from softsbi.workflows.tasks.calibrate import calibrate_run
from softsbi.workflows.criticism.check import check_run
from softsbi.workflows.criticism.compare import compare_runs
from softsbi.workflows.compare_backends import compare_backends
from softsbi.workflows.demo import run_demo
from softsbi.workflows.criticism.diagnose import diagnose_run
from softsbi.workflows.extractor import train_extractor
from softsbi.workflows.tasks.training import train_task
from softsbi.workflows.fit.task_store import task_store_of
from softsbi.workflows.fit.run import FitConfig
from softsbi.workflows.measurement import import_diffcloud, load_image_recording
from softsbi.workflows.simulate import simulate_to_folder
from softsbi.core.defaults import CheckSettings, DiagnoseSettings
from softsbi.workflows.view import write_view

FIT = {f.name: (f.default if f.default is not dataclasses.MISSING else f.default_factory())
       for f in dataclasses.fields(FitConfig)}


def _settings(cls):
    """The defaults of a settings object's fields (check's and diagnose's settings)."""
    return {f.name: f.default for f in dataclasses.fields(cls)}


def _sig(fn, rename=None):
    params = {k: p.default for k, p in inspect.signature(fn).parameters.items() if p.default is not p.empty}
    return {cli: params[lib] for cli, lib in (rename or {}).items()} | params


#: command -> {CLI option name: library default}
LIBRARY = {
    "simulate": _sig(simulate_to_folder),
    "fit": {**FIT, "points": FIT["n_points"], "effect": FIT["effects"], "fix": FIT["fixed"],
            "backend_opt": FIT["backend_options"], "estimator_opt": FIT["estimator_options"],
            "image_size": _sig(load_image_recording)["size"], "retries": _sig(LocalExecutor.__init__)["retries"],
            "sim_timeout": _sig(LocalExecutor.__init__)["timeout"]},
    "check": {**_settings(CheckSettings), **_sig(check_run)},
    "diagnose": {**_settings(DiagnoseSettings), **_sig(diagnose_run, {"effect": "effects"})},
    "compare": {**_settings(CheckSettings), **_sig(compare_runs)},
    "view": _sig(write_view),
    "calibrate": _sig(calibrate_run),
    "demo": _sig(run_demo),
    "train-extractor": _sig(train_extractor, {"opt": "options"}),
    "compare-backends": {**_sig(compare_backends), "scenario": _sig(simulate_to_folder)["scenario"],
                         "backends": ",".join(_sig(compare_backends)["backends"])},
    "diffcloud": _sig(import_diffcloud),
    "params": {"backend": FIT["backend"]},
    "train": {**FIT, "points": FIT["n_points"], "effect": FIT["effects"], "fix": FIT["fixed"],
              **_sig(train_task, {"prior_sims": "n_prior"})},
    **{sub: _sig(task_store_of) for sub in ("list", "show", "delete")},
}
#: options only the CLI has, with a default of its own
CLI_ONLY = {"as_json", "out", "recording", "theta", "extractor", "observed", "ray_address", "retry_failed",
            "data", "match", "effect", "backend_opt", "no_sim_bank"}


def _commands():
    group = typer.main.get_command(app)
    for name, cmd in group.commands.items():
        for sub_name, sub in getattr(cmd, "commands", {name: cmd}).items():
            yield sub_name, sub


def _norm(v):
    if isinstance(v, Enum):
        v = v.value
    if isinstance(v, (tuple, Path)):
        v = list(v) if isinstance(v, tuple) else str(v)
    return v


def test_every_cli_default_is_its_library_default():
    checked = 0
    for name, cmd in _commands():
        lib = LIBRARY.get(name, {})
        for p in cmd.params:
            default = p.default if not callable(p.default) else p.default()
            if p.name in lib:
                if default is None or default == []:  # None / nothing given: the library's default applies
                    continue
                assert _norm(default) == _norm(lib[p.name]), (name, p.name, default, lib[p.name])
                checked += 1
            else:
                assert p.name in CLI_ONLY or default in (None, False, [], ()), \
                    f"`softsbi {name} --{p.name.replace('_', '-')}` defaults to {default!r}: take it from the library"
    assert checked >= 30, checked


def test_check_and_diagnose_take_their_flags_defaults_and_bounds_from_the_settings_objects():
    """Each setting of check, compare and diagnose is defined once: the CLI option has the settings field's flag and
    default, and it refuses a value outside the field's bound with the bound's own words, as the Python API does."""
    from typer.testing import CliRunner
    import pytest
    from softsbi.core.errors import SoftsbiError
    commands = dict(_commands())
    seen = 0
    for command, cls in (("check", CheckSettings), ("compare", CheckSettings), ("diagnose", DiagnoseSettings)):
        options = {p.name: p for p in commands[command].params}
        for name, limit in cls.BOUNDS.items():
            if name == "seed" and name not in options:  # the commands keep the default seed; the API takes one
                continue
            option = options[name]
            assert limit.flag in option.opts and option.default == cls.__dataclass_fields__[name].default
            outside = limit.low if limit.strict else limit.low - 1
            words = limit.problem(outside)
            args = [command, "RUN"] + (["RUN_B"] if command == "compare" else []) + [limit.flag, f"{outside:g}"]
            res = CliRunner().invoke(app, args)
            said = " ".join(re.sub("[│╭╮╰╯─]", " ", res.output).split())  # the message, out of its box
            assert res.exit_code == 2 and words in said, (args, res.output)
            with pytest.raises(SoftsbiError, match=f"^{limit.flag} {re.escape(words)}$"):
                cls(**{name: outside})
            seen += 1
    assert seen == 2 * (len(CheckSettings.BOUNDS) - 1) + len(DiagnoseSettings.BOUNDS) - 1
