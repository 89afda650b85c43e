"""A plugin whose code fails is one line naming the plugin, its class and its file, in every command: ``plugins``
lists the healthy plugins with the broken one marked, and ``params``, ``simulate`` and ``fit`` refuse it; a fault of
an effect during a ``simulate`` rollout (a non-finite observation, an error raised) is one line, as in a fit."""
import json

import pytest
from typer.testing import CliRunner

from softsbi.cli import app
from softsbi.core.errors import PluginError

pytestmark = pytest.mark.integration

pytest.importorskip("softsbi_toy.plugin", reason="install tests/plugins/softsbi_toy (pip install -e)")

runner = CliRunner()

EFFECTS = '''
import dataclasses

import numpy as np

from softsbi import Effect, Param, ParamSpace, hookimpl
from softsbi.core.interfaces import Simulator


class _Seen(Effect):
    backends = ("toy-gauss",)

    def param_space(self):
        return ParamSpace([Param(self.name.replace("-", "_"), 0.0, 1.0, "m")])

    def observe(self, rollout, theta, rng):
        return rollout


class Healthy(_Seen):
    """A working effect."""
    name = "file-ok"


class Raises(_Seen):
    """param_space() fails."""
    name = "file-raises"

    def param_space(self):
        raise RuntimeError("no table height in the context")


class Duplicate(_Seen):
    """Two parameters of one name."""
    name = "file-dup"

    def param_space(self):
        return ParamSpace([Param("k", 0.0, 1.0, "m"), Param("k", 0.0, 2.0, "m")])


class Inverted(_Seen):
    """Bounds the wrong way round."""
    name = "file-inverted"

    def param_space(self):
        return ParamSpace([Param("k", 1.0, 0.0, "m")])


class NanSensor(_Seen):
    """An observation transform that returns NaN vertices."""
    name = "file-nan"

    def observe(self, rollout, theta, rng):
        return dataclasses.replace(rollout, vertices=np.full_like(rollout.vertices, np.nan))


class WrongShape(_Seen):
    """An observation transform that drops a frame and a coordinate."""
    name = "file-shape"

    def observe(self, rollout, theta, rng):
        return dataclasses.replace(rollout, vertices=rollout.vertices[1:, :, :2])


class Crashes(_Seen):
    """An observation transform that raises."""
    name = "file-crash"

    def observe(self, rollout, theta, rng):
        raise ValueError("belt speed unknown")


class Clash(_Seen):
    """A parameter the toy backend has too."""
    name = "file-clash"

    def param_space(self):
        return ParamSpace([Param("a", 0.0, 1.0, "m")])


class Engine(Simulator):
    """A backend whose param_space() fails."""
    name = "file-engine"
    scenarios = ("lift",)
    effect_kinds = ("observation",)

    def param_space(self, scenario):
        raise KeyError("stiffness")

    def simulate(self, scenario, theta, effects=(), seed=0):
        raise AssertionError("never reached")


@hookimpl
def softsbi_effects():
    return [Healthy, Raises, Duplicate, Inverted, NanSensor, WrongShape, Crashes, Clash]


@hookimpl
def softsbi_simulators():
    return [Engine]
'''

BROKEN = {"file-raises": "its param_space() raised RuntimeError: no table height in the context",
          "file-dup": "ParameterError: duplicate parameter names in ['k', 'k']",
          "file-inverted": "ParameterError: parameter 'k': low (1.0) must be < high (0.0)"}


@pytest.fixture
def plugin(tmp_path, monkeypatch):
    """The effects above in one file, loaded through ``SOFTSBI_PLUGINS``; returns the file."""
    from softsbi.plugins.manager import registry
    path = tmp_path / "conveyor_effects.py"
    path.write_text(EFFECTS)
    monkeypatch.setenv("SOFTSBI_PLUGINS", str(path))
    registry.cache_clear()
    yield path
    monkeypatch.undo()
    registry.cache_clear()


def test_a_broken_effect_is_set_aside_naming_the_plugin_its_class_and_file(plugin):
    from softsbi.plugins.manager import registry
    reg = registry()
    assert reg.effect("file-ok").name == "file-ok" and "file-ok" in reg.names("effect")  # the healthy one works
    for name, cause in BROKEN.items():
        assert name not in reg.names("effect")
        with pytest.raises(PluginError) as err:
            reg.effect(name)
        msg = str(err.value)
        assert msg.startswith(f"effect '{name}' (class ") and str(plugin) in msg and "SOFTSBI_PLUGINS" in msg
        assert cause in msg and "\n" not in msg


def test_plugins_lists_the_healthy_ones_and_marks_the_broken_one(plugin):
    res = runner.invoke(app, ["plugins"])
    assert res.exit_code == 0, res.output
    rows = {line.split("|")[1].strip(): line for line in res.output.splitlines() if line.startswith("| file-")}
    assert set(rows) == {"file-ok", "file-raises", "file-dup", "file-inverted", "file-nan", "file-shape", "file-crash",
                         "file-clash", "file-engine"}  # the last a simulator: its parameters depend on the scenario
    assert "BROKEN" not in rows["file-ok"] and "file_ok [0, 1] m" in rows["file-ok"]
    for name, cause in BROKEN.items():
        assert "BROKEN" in rows[name]
        (line,) = [x for x in res.output.splitlines() if x.startswith(f"effect '{name}'")]
        assert str(plugin) in line and cause in line
    assert "wind" in res.output and "Traceback" not in res.output  # the installed plugins are still listed
    doc = json.loads(runner.invoke(app, ["plugins", "--json"]).output)
    effects = {e["name"]: e for e in doc["effects"]}
    assert str(plugin) in effects["file-dup"]["broken"] and "broken" not in effects["file-ok"]


@pytest.mark.parametrize("command", [["params", "lift", "--backend", "toy-gauss", "--effect", "file-raises"],
                                     ["simulate", "--backend", "toy-gauss", "--scenario", "lift", "--effect",
                                      "file-raises"]])
def test_params_and_simulate_refuse_a_broken_effect_in_one_line(plugin, tmp_path, command):
    out = tmp_path / "sim"
    res = runner.invoke(app, command + (["--out", str(out)] if command[0] == "simulate" else []))
    assert res.exit_code == 2, res.output
    (line,) = res.output.strip().splitlines()
    assert line.startswith("error: effect 'file-raises'") and str(plugin) in line and "RuntimeError" in line
    assert not out.exists()


@pytest.mark.parametrize("backend, effect, said", [
    ("file-engine", "file-ok", ("error: simulator 'file-engine' (class softsbi_file_plugin_conveyor_effects.Engine "
                                "in {plugin}, from SOFTSBI_PLUGINS ({plugin})) is broken: its param_space(scenario "
                                "'lift') raised KeyError: 'stiffness'; fix the plugin's code or remove it from "
                                "SOFTSBI_PLUGINS")),
    ("toy-gauss", "file-clash", ("error: effect 'file-clash' (class softsbi_file_plugin_conveyor_effects.Clash in "
                                 "{plugin}, from SOFTSBI_PLUGINS ({plugin})) is broken: its parameter 'a' is also one "
                                 "of simulator 'toy-gauss''s; rename it; fix the plugin's code or remove it from "
                                 "SOFTSBI_PLUGINS"))])
def test_a_backend_failing_to_declare_its_parameters_or_a_clash_of_names_is_one_line(plugin, tmp_path, backend,
                                                                                      effect, said):
    for command in (["params", "lift", "--backend", backend, "--effect", effect],
                    ["simulate", "--backend", backend, "--scenario", "lift", "--effect", effect,
                     "--out", str(tmp_path / "sim")]):
        res = runner.invoke(app, command)
        assert res.exit_code == 2, res.output
        assert res.output.strip() == said.format(plugin=plugin)
    assert not (tmp_path / "sim").exists()


@pytest.mark.parametrize("effect, said", [
    ("file-nan", ("effect 'file-nan': observe() returned non-finite vertices (NaN or inf) at file_nan=0.5; a "
                  "fault of the effect's code")),
    ("file-shape", ("effect 'file-shape': observe() returned vertices of shape (24, 4, 2), expected a Rollout whose "
                    "vertices have the shape it was given, (25, 4, 3) (T frames, N vertices, xyz), at file_shape=0.5; "
                    "a fault of the effect's code")),
    ("file-crash", "(ValueError: belt speed unknown)")])
def test_an_effect_failing_in_a_simulate_rollout_is_one_line(plugin, tmp_path, effect, said):
    out = tmp_path / "sim"
    res = runner.invoke(app, ["simulate", "--backend", "toy-gauss", "--scenario", "lift", "--effect", effect,
                              "--out", str(out)])
    assert res.exit_code == 2, res.output
    (line,) = res.output.strip().splitlines()
    assert line.startswith("error: the simulation failed") and said in line and "nothing was written" in line
    assert not out.exists()


def test_simulate_refuses_a_scenario_the_backend_cannot_run_as_fit_does(tmp_path):
    res = runner.invoke(app, ["simulate", "--backend", "toy-gauss", "--scenario", "wipe", "--out", str(tmp_path / "s")])
    assert res.exit_code == 2
    assert res.output.strip() == "error: toy-gauss cannot run scenario 'wipe'; it runs toy, lift"
    assert not (tmp_path / "s").exists()


def test_a_fit_refuses_a_broken_effect_before_its_run_and_names_a_nan_sensor_effect(plugin, tmp_path):
    rec = tmp_path / "rec"
    res = runner.invoke(app, ["simulate", "--backend", "toy-gauss", "--scenario", "lift", "--out", str(rec)])
    assert res.exit_code == 0, res.output
    fit = ["fit", "--observed", str(rec), "--backend", "toy-gauss", "--rounds", "1", "--sims-per-round", "10",
           "--workers", "1"]
    res = runner.invoke(app, fit + ["--effect", "file-dup", "--out", str(tmp_path / "never")])
    assert res.exit_code == 2 and "effect 'file-dup'" in res.output and str(plugin) in res.output
    assert not (tmp_path / "never").exists()
    res = runner.invoke(app, fit + ["--effect", "file-nan", "--out", str(tmp_path / "nan")])
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert "effect 'file-nan': observe() returned non-finite vertices" in res.output
    assert "fix the effect's code named there" in res.output
