"""The plugin registry is strict: duplicate names, wrong base classes and misspelled hooks are
one clear PluginError when it is built; aliases resolve with a FutureWarning."""
import importlib.metadata as md
import json
import types
import warnings

import pytest
from typer.testing import CliRunner

import softsbi.plugins
from softsbi.cli import app
from softsbi.core.errors import PluginError, SoftsbiError
from softsbi.core.interfaces import Effect, Simulator
from softsbi.core.types import ParamSpace
from softsbi.effects import builtin
from softsbi.plugins import Registry, get_plugin_manager, hookimpl, manager, registry

pytestmark = pytest.mark.integration


def _plugin(module: str, **hooks) -> types.ModuleType:
    """An in-memory plugin module whose hooks return the given lists of classes."""
    m = types.ModuleType(module)
    for hook, classes in hooks.items():
        setattr(m, hook, hookimpl(lambda classes=classes: list(classes)))
    return m


def _registry(*plugins: tuple[str, str, types.ModuleType]) -> Registry:
    """``Registry`` of ``(plugin name, "dist version", module)`` plugins only (no entry points)."""
    pm = get_plugin_manager(autoload=False)
    for name, _, module in plugins:
        pm.register(module, name=name)
    return Registry(pm, dists={name: dist for name, dist, _ in plugins})


def _effect(cls_name: str, name: str, module: str = "mywind.plugin", **attrs) -> type:
    return type(cls_name, (Effect,), {"name": name, "__module__": module, "__qualname__": cls_name,
                                      "param_space": lambda self: ParamSpace([]), **attrs})


def _simulator(cls_name: str, name: str, module: str = "mysim.plugin", **attrs) -> type:
    return type(cls_name, (Simulator,), {"name": name, "__module__": module, "__qualname__": cls_name,
                                         "param_space": lambda self, scenario: ParamSpace([]),
                                         "simulate": lambda self, *a, **k: None, **attrs})


BUILTIN = ("effects", "softsbi 0.1.0", _plugin("softsbi.effects.builtin", softsbi_effects=[builtin.Wind]))


def test_duplicate_name_names_both_providers():
    mywind = ("mywind", "mywind 1.2", _plugin("mywind.plugin", softsbi_effects=[_effect("Wind", "wind")]))
    with pytest.raises(PluginError) as err:
        _registry(BUILTIN, mywind)
    msg = str(err.value)  # the name, then each provider: its distribution and class
    assert "'wind'" in msg and "\n" not in msg
    assert msg.index("softsbi 0.1.0 (softsbi.effects.builtin.Wind)") < msg.index("mywind 1.2 (mywind.plugin.Wind)")
    assert isinstance(err.value, SoftsbiError) and isinstance(err.value, TypeError)
    # two different classes of one name inside one plugin clash too
    with pytest.raises(PluginError, match="two simulator plugins are named 'sim'"):
        _registry(("p", "p 1", _plugin("p", softsbi_simulators=[_simulator("A", "sim"), _simulator("B", "sim")])))


def test_same_class_twice_is_not_a_clash():
    again = ("again", "other 2.0", _plugin("other.reexport", softsbi_effects=[builtin.Wind, builtin.Wind]))
    reg = _registry(BUILTIN, again)
    assert reg.effect("wind") is builtin.Wind
    assert reg.names("effect") == ["wind"]
    assert reg.origin[("effect", "wind")] == "softsbi 0.1.0"  # the first provider


@pytest.mark.parametrize("returned, expect", [
    ([_simulator("Sim", "mysim")], (r"returned class mysim\.plugin\.Sim, which does not derive from "
                                    r"softsbi\.core\.effect\.Effect")),
    ([int], r"returned class builtins\.int, which does not derive from softsbi\.core\.effect\.Effect"),
    ([builtin.Wind()], r"an instance: return the class itself.*not a class.*softsbi\.core\.effect\.Effect"),
    (["wind"], r"returned 'wind', which is not a class.*softsbi\.core\.effect\.Effect"),
    ([_effect("NoName", "")], r"NoName without a name.*non-empty string class attribute `name`"),
    (builtin.Wind, r"must return a list of classes derived from softsbi\.core\.effect\.Effect"),
])
def test_wrong_classes_name_the_plugin_hook_object_and_base(returned, expect):
    bad = ("mywind", "mywind 1.2", _plugin("mywind.plugin", softsbi_effects=[]))
    bad[2].softsbi_effects = hookimpl(lambda: returned)
    with pytest.raises(PluginError, match=expect) as err:
        _registry(bad)
    msg = str(err.value)  # the plugin, its module and distribution, the hook
    assert "'mywind'" in msg and "mywind.plugin" in msg and "mywind 1.2" in msg and "softsbi_effects" in msg


def test_misspelled_hook_is_named_with_a_suggestion():
    typo = _plugin("mywind.plugin", softsbi_efects=[builtin.Wind])
    with pytest.raises(PluginError) as err:
        _registry(("mywind", "mywind 1.2", typo))
    msg = str(err.value)
    assert "'mywind'" in msg and msg.index("'softsbi_efects'") < msg.index("'softsbi_effects'")  # typo, then the hook
    assert "softsbi_simulators" in msg  # lists the real hooks
    # an undecorated function of that name is no hook at all
    plain = _plugin("mywind.plugin", softsbi_effects=[builtin.Wind])
    plain.softsbi_efects = lambda: [builtin.Wind]
    assert _registry(("mywind", "mywind 1.2", plain)).names("effect") == ["wind"]


def test_alias_resolves_with_a_future_warning():
    new = _simulator("MassSpring", "pybullet-massspring", aliases=("pybullet-fem",))
    reg = _registry(("pb", "softsbi 0.1.0", _plugin("softsbi.backends.pybullet_massspring",
                                                    softsbi_simulators=[new])))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert reg.simulator("pybullet-massspring") is new  # the real name: no warning
    with pytest.warns(FutureWarning, match="plugin name 'pybullet-fem' is deprecated; use 'pybullet-massspring'"):
        assert reg.simulator("pybullet-fem") is new
    with pytest.warns(FutureWarning):
        assert reg.get("simulator", "pybullet-fem") is new
    assert reg.names("simulator") == ["pybullet-massspring"]
    assert set(reg.tables["simulator"]) == {"pybullet-massspring"}
    row, = reg.describe()["simulators"]
    assert row["name"] == "pybullet-massspring" and row["aliases"] == ["pybullet-fem"]


def test_alias_clashes_are_detected():
    new = _simulator("MassSpring", "pybullet-massspring", module="softsbi.backends.pybullet_massspring",
                     aliases=("pybullet-fem",))
    ours = ("pb", "softsbi 0.1.0", _plugin("softsbi.backends.pybullet_massspring", softsbi_simulators=[new]))
    theirs = ("fem", "pbfem 0.3", _plugin("pbfem.plugin", softsbi_simulators=[_simulator("Fem", "pybullet-fem",
                                                                                           module="pbfem.plugin")]))
    for order in [(ours, theirs), (theirs, ours)]:
        with pytest.raises(PluginError) as err:
            _registry(*order)
        msg = str(err.value)
        assert "'pybullet-fem'" in msg and "softsbi.backends.pybullet_massspring.MassSpring" in msg
        assert "'pybullet-massspring'" in msg and "pbfem 0.3 (pbfem.plugin.Fem)" in msg  # whose alias, the other one
    # alias against alias
    other = ("o", "o 1", _plugin("o", softsbi_simulators=[_simulator("O", "o-sim", aliases=("pybullet-fem",))]))
    with pytest.raises(PluginError, match="'pybullet-fem'.*an alias of 'pybullet-massspring'.*an alias of 'o-sim'"):
        _registry(ours, other)
    # malformed aliases
    bad = ("b", "b 1", _plugin("b", softsbi_simulators=[_simulator("B", "b-sim", aliases="old-b")]))
    with pytest.raises(PluginError, match=r"`aliases` is 'old-b'; it must be a tuple of non-empty strings"):
        _registry(bad)


def test_entry_points_failing_to_import_are_skipped_but_malformed_ones_raise(tmp_path, monkeypatch):
    (tmp_path / "softsbi_regtest_typo.py").write_text(
        "from softsbi.plugins import hookimpl\n"
        "@hookimpl\n"
        "def softsbi_estimatrs():\n"
        "    return []\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(manager, "LOAD_ERRORS", {})
    broken = md.EntryPoint("broken", "softsbi_regtest_no_such_module", "softsbi")
    typo = md.EntryPoint("typo", "softsbi_regtest_typo", "softsbi")
    monkeypatch.setattr(manager.md, "entry_points", lambda group: [broken] if group == "softsbi" else [])
    with pytest.warns(UserWarning, match="'broken'.*failed to load and is skipped"):
        reg = Registry(get_plugin_manager(autoload=True))
    assert "broken" in manager.LOAD_ERRORS and reg.names("effect") == []
    monkeypatch.setattr(manager.md, "entry_points", lambda group: [broken, typo] if group == "softsbi" else [])
    with pytest.warns(UserWarning), \
            pytest.raises(PluginError, match=r"plugin 'typo' \(softsbi_regtest_typo, softsbi_regtest_typo\) has an "
                                             r"unknown hook 'softsbi_estimatrs'\. Did you mean 'softsbi_estimators'"):
        Registry(get_plugin_manager(autoload=True))


def test_installed_registry_builds():
    reg = registry()
    assert registry() is reg  # cached
    assert "mujoco-flex" in reg.names("simulator")
    assert "rkhs" in reg.names("estimator")
    assert "local" in reg.names("executor")
    assert "wind" in reg.names("effect")
    assert {"pointcloud", "heatmap"} <= set(reg.names("observer"))
    assert "heatmap" in reg.names("extractor")
    for kind, table in reg.tables.items():
        for name, cls in table.items():
            assert issubclass(cls, manager.BASES[kind]) and cls.name == name


def test_cli_prints_a_broken_registry_as_one_line(monkeypatch):
    mywind = ("mywind", "mywind 1.2", _plugin("mywind.plugin", softsbi_effects=[_effect("Wind", "wind")]))
    monkeypatch.setattr(softsbi.plugins, "registry", lambda: _registry(BUILTIN, mywind))
    runner = CliRunner()
    res = runner.invoke(app, ["plugins"])
    assert res.exit_code == 2, res.output
    lines = res.output.strip().splitlines()
    assert lines == [("error: two effect plugins are named 'wind': softsbi 0.1.0 (softsbi.effects.builtin.Wind) "
                      "and mywind 1.2 (mywind.plugin.Wind); uninstall one or rename it")], res.output
    res = runner.invoke(app, ["plugins", "--json"])
    assert res.exit_code == 2
    doc = json.loads(res.output[res.output.index("{"):])
    assert doc["type"] == "PluginError" and "'wind'" in doc["error"]


FILE_EFFECT = '''
from softsbi import Effect, Param, ParamSpace, hookimpl


class FileHem(Effect):
    """Extra weight on the border vertices (a force field). Off at 0 kg/m."""
    name = "file-hem"
    description = "extra weight along the cloth's edges (kg/m)"

    def param_space(self):
        return ParamSpace([Param("hem_density", 0.0, 0.05, "kg/m")])

    def force(self, x, v, t, theta, ctx):
        return ctx.edges[:, None] * theta["hem_density"] * ctx.spacing * ctx.gravity[None, :]


@hookimpl
def softsbi_effects():
    return [FileHem]
'''


@pytest.mark.slow
def test_an_effect_in_one_file_plugs_in_through_softsbi_plugins_without_a_package(tmp_path):
    """SOFTSBI_PLUGINS=my_effect.py: listed, simulated, and fitted with spawned workers (which load the same
    file); a path that does not exist is one line naming the variable and the fix."""
    import os
    import subprocess
    import sys
    (tmp_path / "my_effect.py").write_text(FILE_EFFECT)
    env = {**os.environ, "SOFTSBI_PLUGINS": "my_effect.py"}

    def cli(*args, env=env):
        return subprocess.run([sys.executable, "-m", "softsbi.cli", *args], cwd=tmp_path, env=env, capture_output=True,
                              text=True, timeout=300)

    res = cli("plugins", "--json")
    assert res.returncode == 0, res.stderr[-2000:]
    effects = {e["name"]: e for e in json.loads(res.stdout)["effects"]}
    assert effects["file-hem"]["package"] == "SOFTSBI_PLUGINS (my_effect.py)"
    res = cli("simulate", "--scenario", "lift", "--effect", "file-hem", "--theta", "hem_density=0.04",
              "--backend-opt", "grid=5", "--out", "meas")
    assert res.returncode == 0, res.stderr[-2000:]
    res = cli("fit", "--observed", "meas", "--effect", "file-hem", "--backend-opt", "grid=5", "--rounds", "1",
              "--sims-per-round", "10", "--n-eval", "2", "--workers", "2", "--out", "run")
    assert res.returncode == 0, res.stderr[-2000:]
    report = json.loads((tmp_path / "run" / "report.json").read_text())
    assert "hem_density" in report["posterior_mean"] and report["failed_simulations"] == 0
    res = cli("plugins", env={**env, "SOFTSBI_PLUGINS": "missing.py"})
    assert res.returncode == 2 and "SOFTSBI_PLUGINS" in res.stderr and "'missing.py'" in res.stderr
    assert "FileNotFoundError" in res.stderr
    assert "Traceback" not in res.stderr
