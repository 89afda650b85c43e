"""The README's Python API example runs as written, the way a user runs it: saved as a file and
started with ``python example.py`` (in a temporary folder)."""
import re
import subprocess
import sys

import pytest
from toy_helpers import REPO

pytestmark = pytest.mark.integration

README = REPO / "README.md"


@pytest.mark.slow
def test_readme_python_api_example_runs_as_a_script(tmp_path):
    """As a file, not exec'd inside pytest: a script is the driver's ``__main__``, which ``spawn`` workers used
    to re-run (the example has no ``if __name__ == "__main__":`` guard and hung for more than 600 s)."""
    text = README.read_text()
    section = text[text.index("## Python API"):]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    script = tmp_path / "example.py"
    script.write_text(code)
    out = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "['bend', 'stretch', 'friction', 'scale', 'mass']" in out.stdout
    assert (tmp_path / "runs" / "api-example" / "report.json").exists()
