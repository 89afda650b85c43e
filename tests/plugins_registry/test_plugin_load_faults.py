"""A plugin whose code fails while it is loaded, registered or made is one line that names the plugin (its file, or
its class and file), where its code failed, and the fix that applies: its code, a package it imports, or taking it
out of SOFTSBI_PLUGINS (an installed plugin: uninstalling it). Never a traceback, and never the advice meant for an
entry that names no file ("give an importable module name ...") when the file is there."""
import importlib.metadata as md

import pytest
from typer.testing import CliRunner

from softsbi.cli import app
from softsbi.core.errors import SoftsbiWarning
from softsbi.plugins import Registry, get_plugin_manager, manager

pytestmark = pytest.mark.integration

pytest.importorskip("softsbi_toy.plugin", reason="install tests/plugins/softsbi_toy (pip install -e)")

runner = CliRunner()

HEAD = "from softsbi import Effect, Param, ParamSpace, hookimpl\nfrom softsbi.core.interfaces import Simulator\n"

#: plugin files by name: their code, and what the one line must hold besides the file's path
FILES = {
    "raises_on_import": (HEAD + "TABLE = {}['height']\n",
                         ["failed while loading: KeyError: 'height' (line 3 of {path})",
                          "fix its code, or remove it from SOFTSBI_PLUGINS"]),
    "syntax_error": (HEAD + "def belt(:\n    pass\n",
                     ["failed while loading: SyntaxError: invalid syntax (line 3 of {path})",
                      "fix its code, or remove it from SOFTSBI_PLUGINS"]),
    "missing_package": (HEAD + "import conveyor_belt_sdk\n",
                        ["ModuleNotFoundError: No module named 'conveyor_belt_sdk' (line 3 of {path})",
                         "install the package that provides 'conveyor_belt_sdk' (the plugin imports it), or remove "
                         "it from SOFTSBI_PLUGINS"]),
    "hook_raises": (HEAD + "@hookimpl\ndef softsbi_effects():\n    return [Belt]\n",
                    ["softsbi plugin '{path}' (SOFTSBI_PLUGINS): hook softsbi_effects raised NameError: name 'Belt' "
                     "is not defined (line 5 of {path})", "fix the plugin's code or remove it from SOFTSBI_PLUGINS"]),
    "hook_arguments": (HEAD + "@hookimpl\ndef softsbi_effects(extra):\n    return []\n",
                       ["is malformed:", "declared in the hookimpl but can not be found in the hookspec",
                        "declare each hook without arguments"]),
    "not_a_class": (HEAD + "@hookimpl\ndef softsbi_effects():\n    return ['belt']\n",
                    ["softsbi plugin '{path}' (SOFTSBI_PLUGINS): hook softsbi_effects returned 'belt', which is not "
                     "a class; an effect plugin is a class derived from softsbi.core.effect.Effect"]),
}

BELT = HEAD + '''

class Belt(Effect):
    """Its constructor fails."""
    name = "file-belt"

    def __init__(self):
        raise RuntimeError("belt speed unknown")

    def param_space(self):
        return ParamSpace([Param("v", 0.0, 1.0, "m/s")])


class Engine(Simulator):
    """Its constructor fails."""
    name = "file-engine"
    scenarios = ("lift",)

    def __init__(self, **options):
        raise RuntimeError("no licence")

    def param_space(self, scenario):
        return ParamSpace([Param("k", 0.0, 1.0, "m")])

    def simulate(self, scenario, theta, effects=(), seed=0):
        raise AssertionError("never reached")


@hookimpl
def softsbi_effects():
    return [Belt]


@hookimpl
def softsbi_simulators():
    return [Engine]
'''


@pytest.fixture
def load(tmp_path, monkeypatch):
    """``load(name, code)``: the path of a plugin file holding ``code``, set as ``SOFTSBI_PLUGINS``."""
    from softsbi.plugins.manager import registry

    def put(name, code):
        path = tmp_path / f"{name}.py"
        path.write_text(code)
        monkeypatch.setenv("SOFTSBI_PLUGINS", str(path))
        registry.cache_clear()
        return path
    yield put
    monkeypatch.undo()
    registry.cache_clear()


@pytest.mark.parametrize("name", sorted(FILES))
def test_a_plugin_file_failing_to_load_or_register_is_one_line_naming_it_where_and_the_fix(load, name):
    code, said = FILES[name]
    path = load(name, code)
    res = runner.invoke(app, ["plugins"])
    assert res.exit_code == 2, res.output
    (line,) = res.output.strip().splitlines()
    assert line.startswith("error: ") and str(path) in line and "Traceback" not in line
    for part in said:
        assert part.format(path=path) in line, line
    assert "give an importable module name" not in line  # the file is there: that advice is for a wrong entry


def test_an_effect_whose_constructor_fails_is_set_aside_naming_the_constructor(load):
    path = load("belt", BELT)
    res = runner.invoke(app, ["params", "lift", "--backend", "toy-gauss", "--effect", "file-belt"])
    assert res.exit_code == 2, res.output
    (line,) = res.output.strip().splitlines()
    assert f"effect 'file-belt' (class softsbi_file_plugin_belt.Belt in {path}" in line
    assert "making it (Belt()) raised RuntimeError: belt speed unknown (line " in line  # not its param_space()
    assert line.endswith("fix the plugin's code or remove it from SOFTSBI_PLUGINS")


def test_a_simulator_that_cannot_be_made_or_refuses_its_options_is_one_line_before_any_work(load, tmp_path):
    path = load("belt", BELT)
    out = tmp_path / "sim"
    res = runner.invoke(app, ["simulate", "--backend", "file-engine", "--scenario", "lift", "--out", str(out)])
    assert res.exit_code == 2, res.output
    (line,) = res.output.strip().splitlines()
    assert f"simulator 'file-engine' (class softsbi_file_plugin_belt.Engine in {path}" in line
    assert "making it raised RuntimeError: no licence (line " in line and "remove it from SOFTSBI_PLUGINS" in line
    res = runner.invoke(app, ["fit", "--observed", str(tmp_path), "--backend", "file-engine", "--out", str(out)])
    assert res.exit_code == 2 and "making it raised RuntimeError: no licence" in res.output, res.output
    # a built-in backend refusing an option's value: the options, not the plugin, need the fix
    res = runner.invoke(app, ["simulate", "--scenario", "lift", "--backend-opt", "grid=1", "--out", str(out)])
    assert res.exit_code == 2, res.output
    assert res.output.strip() == ("error: simulator 'mujoco-flex' (--backend-opt) refused the options {'grid': 1}: "
                                  "grid must be >= 3 vertices per side, got 1; change them")
    assert not out.exists()


def test_an_installed_plugin_failing_to_import_is_one_warning_with_the_fix(tmp_path, monkeypatch):
    (tmp_path / "softsbi_regtest_needs.py").write_text("import conveyor_belt_sdk\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(manager, "LOAD_ERRORS", {})
    monkeypatch.delenv("SOFTSBI_PLUGINS", raising=False)
    needs = md.EntryPoint("needs", "softsbi_regtest_needs", "softsbi")
    monkeypatch.setattr(manager.md, "entry_points", lambda group: [needs] if group == "softsbi" else [])
    with pytest.warns(SoftsbiWarning) as said:
        Registry(get_plugin_manager(autoload=True))
    (msg,) = [str(w.message) for w in said]
    assert msg.startswith("softsbi plugin 'needs' (softsbi_regtest_needs) failed to load and is skipped: "
                          "ModuleNotFoundError: No module named 'conveyor_belt_sdk' (line 1 of ")
    assert msg.endswith("install the package that provides 'conveyor_belt_sdk' (the plugin imports it), or "
                        "uninstall it")

