"""The benchmark runner (benchmarks/runner.py): declared suites, results JSON with provenance, the generated page."""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import types

import pytest

from toy_helpers import REPO

sys.path.insert(0, str(REPO))
from benchmarks import runner


def test_the_runner_lists_every_suite_and_each_suite_declares_its_options():
    out = subprocess.run([sys.executable, "-m", "benchmarks", "list"], cwd=REPO, capture_output=True, text=True,
                         check=True).stdout
    assert [line.split()[0] for line in out.splitlines()] == list(runner.SUITES)
    assert {s.group for s in runner.SUITES.values()} <= set(runner.GROUPS)
    for s in runner.SUITES.values():
        mod = s.load()
        assert callable(mod.suite), s.name
        default = runner.options(s, mod, [])
        if mod.FULL is not None:  # --full sets options the suite has, to other values than its default
            full = runner.options(s, mod, ["--full"])
            assert all(hasattr(default, k) for k in mod.FULL), s.name
            assert any(getattr(full, k) != getattr(default, k) for k in mod.FULL), s.name


def _fake_suite(monkeypatch) -> runner.Suite:
    mod = types.ModuleType("fake_suite")
    mod.FULL = {"n": 5}

    def add_arguments(ap: argparse.ArgumentParser) -> None:
        ap.add_argument("--n", type=int, default=2)

    def suite(opts):
        return {"tables": [runner.table("squares", ["k", "k^2"], [[k, k * k] for k in range(opts.n)])],
                "notes": [f"{opts.n} rows."]}

    mod.add_arguments, mod.suite = add_arguments, suite
    s = runner.Suite("fake", "Speed", "a fake suite", "Squares of the first n integers.", mod)
    monkeypatch.setitem(runner.SUITES, "fake", s)
    return s


def test_a_suite_run_writes_its_json_with_provenance_and_rewrites_its_section(tmp_path, monkeypatch):
    _fake_suite(monkeypatch)
    results, doc = tmp_path / "results", tmp_path / "benchmarks.md"
    runner.run("fake", ["--n", "3"], results=results, doc=doc)
    data = json.loads((results / "fake.json").read_text())
    run = data["runs"]["default"]
    assert run["command"] == "python -m benchmarks run fake --n 3" and run["source"] == "measured"
    assert re.fullmatch(r"[0-9a-f]{10}", run["commit"]) and isinstance(run["dirty"], bool)
    assert run["machine"]["cores"] >= 1 and run["machine"]["cpu"] and run["machine"]["os"]
    assert run["options"] == {"n": 3} and run["tables"][0]["rows"] == [[0, 0], [1, 1], [2, 4]]
    text = doc.read_text()
    section = text[text.index("### fake: a fake suite"):]
    assert f"Commit `{run['commit']}`" in section and "`python -m benchmarks run fake --n 3`" in section
    assert f"{run['machine']['cores']} cores; {run['machine']['cpu']}" in section
    assert "| 2 | 4 |" in section and "3 rows." in section
    # --full is stored beside the default run; a run of the same configuration replaces it from scratch
    runner.run("fake", ["--full"], results=results, doc=doc)
    runner.run("fake", ["--n", "1"], results=results, doc=doc)
    data = json.loads((results / "fake.json").read_text())
    assert list(data["runs"]) == ["default", "full"] and data["runs"]["full"]["options"] == {"n": 5}
    section = doc.read_text()[doc.read_text().index("### fake"):]
    default, full = section.split("**Full configuration.**")
    assert "| 0 | 0 |" in default and "| 1 | 1 |" not in default and "1 rows." in default
    assert "| 4 | 16 |" in full and "5 rows." in full


def test_rendering_is_deterministic_and_names_commit_machine_and_command(tmp_path, monkeypatch):
    _fake_suite(monkeypatch)
    recorded = {"config": "full", "source": "recorded", "commit": "abc1234", "machine": {"cores": 2, "note": "idle"},
                "command": "python benchmarks/fake.py --n 240", "tables": [runner.table("t", ["a"], [[0.123456]])]}
    (tmp_path / "fake.json").write_text(json.dumps({"suite": "fake", "runs": {"full": recorded}}))
    text = runner.render_text(tmp_path)
    assert text == runner.render_text(tmp_path)
    assert ("**Full configuration, recorded.** Commit `abc1234`; machine: 2 cores; idle; command: "
            "`python benchmarks/fake.py --n 240`.") in text
    assert "| 0.1235 |" in text  # floats to 4 significant digits
    for s in runner.SUITES.values():  # every declared suite has its section, measured or not
        assert f"### {s.name}: {s.title}" in text
    assert "Not measured yet: `python -m benchmarks run speed`." in text


def test_commands_and_options_name_no_absolute_path(tmp_path):
    cmd = runner.command(["run", "real-lift", "--data", str(REPO.parent / "shared" / "data"), "--out", str(tmp_path)])
    assert cmd.startswith("python -m benchmarks run real-lift --data ../shared/data --out ")
    assert not re.search(r"(^| )/", cmd)
    assert runner.portable({"out": tmp_path, "n": [1, "x"]}) == {"out": f"OUTSIDE/{tmp_path.name}", "n": [1, "x"]}
    assert runner.portable(REPO / "runs" / "x") == os.path.join("runs", "x")


def test_the_committed_page_is_what_the_stored_results_render():
    assert runner.DOC.read_text() == runner.render_text(), "run `python -m benchmarks render`"


@pytest.mark.parametrize("pattern", ["/work/", "/tmp/", "session"])
def test_benchmarks_and_their_page_name_no_work_session_or_machine_path(pattern):
    files = [p for p in (REPO / "benchmarks").rglob("*") if p.suffix in (".py", ".json", ".jsonl", ".md")]
    hits = [str(p.relative_to(REPO)) for p in [*files, runner.DOC] if pattern in p.read_text().lower()]
    assert not hits, f"{pattern!r} in {hits}"
