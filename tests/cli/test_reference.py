"""docs/reference/ is generated from the code (`python -m softsbi.cli.reference`): the committed pages must be what
the code gives now, and they must cover every command, option, format field and built-in effect."""
import shutil

import typer

from softsbi.cli import app
from softsbi.cli.reference import REFERENCE, generate, main
from softsbi.data.recording import RecordingMeta
from softsbi.plugins import registry
from softsbi.scenarios.spec import ScenarioSpec


def test_the_committed_reference_pages_are_current():
    pages = generate()
    assert sorted(p.name for p in REFERENCE.glob("*.md")) == sorted(pages)
    stale = [n for n, text in pages.items() if (REFERENCE / n).read_text() != text]
    assert not stale, f"docs/reference/{stale} differ from the code: run `python -m softsbi.cli.reference`"


def test_the_pages_cover_every_command_option_field_and_builtin_effect():
    pages = generate()
    group = typer.main.get_command(app)
    for name, cmd in group.commands.items():
        for sub, c in (getattr(cmd, "commands", None) or {None: cmd}).items():
            assert f"## softsbi {name}{' ' + sub if sub else ''}\n" in pages["cli.md"]
            for p in c.params:
                assert (f"`{p.opts[0]}`" if p.param_type_name == "option" else f"`{p.name.upper()}`") in pages["cli.md"]
    for model in (ScenarioSpec, RecordingMeta):
        for f, info in model.model_fields.items():
            assert f"| `{f}` |" in pages["formats.md"] and info.description, (model.__name__, f)
    builtin = [n for n, c in registry().tables["effect"].items() if c.__module__.startswith("softsbi.")]
    assert len(builtin) >= 14
    for n in builtin:
        assert f"\n## {n}\n" in pages["effects.md"]
    assert "aniso-friction" not in pages["effects.md"]  # third-party plugins are not softsbi's reference
    assert "| `wind_x` | m/s | -2 to 2 | linear | -inf to inf |" in pages["effects.md"]
    assert "## lift on mujoco-flex" in pages["parameters.md"] and "| `bend` | N*m | 1e-06 to 0.001 | log |" in \
        pages["parameters.md"]


def test_check_names_a_stale_page_and_writing_makes_it_current(tmp_path, capsys):
    out = tmp_path / "reference"
    shutil.copytree(REFERENCE, out)
    (out / "effects.md").write_text("edited by hand\n")
    assert main(["--check", "--out", str(out)]) == 1
    assert "effects.md" in capsys.readouterr().err
    assert main(["--out", str(out)]) == 0 and main(["--check", "--out", str(out)]) == 0
