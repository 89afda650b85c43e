"""`softsbi params` lists a task's parameters; `softsbi plugins` the backends that apply each effect."""
import json

from typer.testing import CliRunner

from softsbi.cli import app

runner = CliRunner()


def test_params_lists_the_backends_and_each_effects_parameters_with_units_and_priors():
    res = runner.invoke(app, ["params", "lift", "--effect", "wind", "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    rows = {r["name"]: r for r in doc["parameters"]}
    assert list(rows) == ["bend", "stretch", "friction", "scale", "mass", "wind_x", "wind_y"]
    assert rows["bend"] == {"name": "bend", "unit": "N*m", "prior": [1e-6, 1e-3], "scale": "log", "limits": [0.0, None],
                            "description": rows["bend"]["description"], "source": "mujoco-flex"}
    assert rows["wind_x"]["source"] == "wind" and rows["wind_x"]["unit"] == "m/s"
    assert rows["wind_x"]["scale"] == "linear" and rows["wind_x"]["limits"] == [None, None]
    text = runner.invoke(app, ["params", "lift", "--effect", "wind"]).output
    assert "wind_y" in text and "m/s" in text and "-2 to 2" in text and "-inf to inf" in text


def test_params_takes_a_scenario_file_and_another_backend_and_refuses_what_it_cannot_apply(tmp_path):
    res = runner.invoke(app, ["params", "winding", "--backend", "pybullet-massspring", "--json"])
    assert res.exit_code == 0, res.output
    assert [r["name"] for r in json.loads(res.output)["parameters"]][:2] == ["pb_rope_bend", "pb_rope_stretch"]
    res = runner.invoke(app, ["params", "lift", "--backend", "pybullet-massspring", "--effect", "wind"])
    assert res.exit_code == 2
    line = res.output.strip()
    assert line.startswith("error: ") and "\n" not in line and "'pybullet-massspring'" in line and "'wind'" in line
    assert "force field" in line  # the door the effect needs
    res = runner.invoke(app, ["params", str(tmp_path / "nothing.yaml")])
    assert res.exit_code == 2 and "nothing.yaml" in res.output and "Traceback" not in res.output


def test_plugins_lists_the_backends_that_apply_each_effect_and_its_parameters():
    res = runner.invoke(app, ["plugins", "--json"])
    assert res.exit_code == 0, res.output
    effects = {e["name"]: e for e in json.loads(res.output)["effects"]}
    # wind acts through the force door too, so newton-cloth (force fields only) applies it
    assert effects["wind"]["backends"] == ["mujoco-flex", "newton-cloth"]
    assert effects["wind"]["doors"] == ["model-edit", "force"]
    assert {"mujoco-flex", "pybullet-massspring"} <= set(effects["point-noise"]["backends"])
    assert effects["point-noise"]["doors"] == ["observation"]
    assert effects["grip-compliance"]["model_edits"] == ["mujoco-flex"]
    assert [p["name"] for p in effects["table-slope"]["parameters"]] == ["slope_x", "slope_y"]
    assert effects["table-slope"]["parameters"][0]["unit"] == "deg"
    text = runner.invoke(app, ["plugins"]).output
    assert "wind_x [-2, 2] m/s" in text and "grip_timeconst [0.008, 0.3] s log" in text
