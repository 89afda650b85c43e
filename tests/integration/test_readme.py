"""The README's Python API example runs as written (in a temporary folder)."""
import os
import re
from toy_helpers import REPO

README = REPO / "README.md"


def test_readme_python_api_example_runs(tmp_path, capsys):
    text = README.read_text()
    section = text[text.index("## Python API"):]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        exec(compile(code, "README.md (Python API)", "exec"), {"__name__": "__readme__"})
    finally:
        os.chdir(cwd)
    out = capsys.readouterr().out
    assert "['bend', 'stretch', 'friction', 'scale', 'mass']" in out
    assert (tmp_path / "runs" / "api-example" / "report.json").exists()
