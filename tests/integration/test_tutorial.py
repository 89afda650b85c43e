"""docs/tutorial.md runs as written: its files (the code blocks whose first line is ``# <file name>``) are saved, and
its bash blocks run in order in one shell in an empty folder, as a reader would type them."""
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from softsbi.core.results import CheckResult, from_json
from toy_helpers import REPO

pytestmark = pytest.mark.integration

TUTORIAL = REPO / "docs" / "tutorial.md"


def tutorial_files(text: str) -> dict[str, str]:
    """``{file name: content}`` of the blocks that start with a ``# name.ext`` line."""
    return {m.group(2): m.group(3) for m in re.finditer(r"```(yaml|python)\n# ([\w.-]+\.\w+)\n(.*?)```", text, re.S)}


def tutorial_commands(text: str) -> list[str]:
    return re.findall(r"```bash\n(.*?)```", text, re.S)


@pytest.mark.slow
def test_the_tutorial_runs_from_file_to_verdict(tmp_path):
    text = TUTORIAL.read_text()
    files = tutorial_files(text)
    assert set(files) == {"carry.yaml", "ballast.py"}
    for name, content in files.items():
        (tmp_path / name).write_text(content)
    script = "\n".join(tutorial_commands(text))
    assert script.count("softsbi ") >= 8
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    env.pop("SOFTSBI_PLUGINS", None)
    out = subprocess.run(["bash", "-euo", "pipefail", "-c", script], cwd=tmp_path, env=env, capture_output=True,
                         text=True, timeout=900)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    # the story the tutorial tells: the fit misses, the diagnosis names the hidden effect, its refit is better
    assert "| ballast" in out.stdout and "ballast_mass" in out.stdout  # plugins and params list it
    run = tmp_path / "runs" / "carry"
    assert from_json(CheckResult, json.loads((run / "check.json").read_text())).test.misspecified
    diag = json.loads((run / "diagnosis.json").read_text())
    assert diag["decision"]["verdict"] == "missing-effect" and diag["decision"]["named"] == ["ballast"], diag["decision"]
    rows = json.loads((run / "refit-ballast" / "compare.json").read_text())["rows"]
    assert rows[0]["b"] < rows[0]["a"]  # the refit's posterior-predictive Chamfer is lower
