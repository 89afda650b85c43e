"""docs/howto/effect-plugin.md shows how to check that an effect moves the object: its commands, run as written on
its own effect file, print what the page says they print (the effect moves the lifted cloth by centimetres; at its
off value it changes nothing)."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.integration

HOWTO = Path(__file__).resolve().parents[2] / "docs" / "howto" / "effect-plugin.md"


def _numbers(text: str) -> np.ndarray:
    return np.array([float(v) for v in re.findall(r"-?\d+\.\d*", text)])


@pytest.mark.slow
def test_the_howtos_check_that_an_effect_moves_the_object_runs_as_written(tmp_path):
    doc = HOWTO.read_text()
    (tmp_path / "my_hem.py").write_text(re.search(r"```python\n(.*?)```", doc, re.S).group(1))
    section = doc.split("## Check that it moves the object\n", 1)[1].split("\n## ", 1)[0]
    script = re.search(r"```bash\n(.*?)```", section, re.S).group(1)
    printed = re.search(r"```text\n(.*?)```", section, re.S).group(1)
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    res = subprocess.run(["bash", "-e", "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    moved_line, off_line = res.stdout[res.stdout.index("with the hem"):].split("the hem at its off value")
    moved = _numbers(moved_line.split(":", 1)[1])
    assert moved[0] == 0.0 and moved.max() > 100  # the same rest pose, then the hem hangs the edges by centimetres
    assert "moves the cloth by 0.000 mm" in off_line
    documented = _numbers(printed.split("the hem at its off value")[0].split(":", 1)[1])
    np.testing.assert_allclose(moved, documented, rtol=0.1, atol=1.0)  # what the page says it prints
