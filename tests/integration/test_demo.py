"""`softsbi demo` end to end on a tiny budget (timings belong to the benchmark suites, docs/benchmarks.md)."""
import json

import pytest
from typer.testing import CliRunner

from softsbi.cli import app
from softsbi.workflows.criticism.diagnose import load_diagnosis

pytestmark = pytest.mark.integration

runner = CliRunner()


@pytest.mark.slow
def test_quick_demo_fits_hidden_parameters(tmp_path):
    res = runner.invoke(app, ["demo", "--quick", "--out", str(tmp_path), "--rounds", "1", "--sims-per-round", "24",
                              "--workers", "2"])
    assert res.exit_code == 0, res.output
    rep = json.loads((tmp_path / "nominal" / "report.json").read_text())
    assert set(rep["truth_in_90pct_interval"]) == set(rep["truth"])  # what the closing line counts
    assert set(rep["truth"]) == {p["name"] for p in rep["parameters"]}
    assert rep["simulations"] == 24 + 30
    for png in ("chamfer_rounds.png", "posterior_pairs.png", "clouds.png"):
        assert (tmp_path / "nominal" / png).stat().st_size > 10_000


@pytest.mark.slow
def test_full_demo_story(tmp_path):
    res = runner.invoke(app, ["demo", "--out", str(tmp_path), "--rounds", "2", "--sims-per-round", "100"])
    assert res.exit_code == 0, res.output
    for step in ("1. fit the nominal model", "2. check", "3. diagnose", "4. add the effect", "5. compare"):
        assert step in res.output
    # the story: the hidden breeze is detected, refitted by the diagnosis and named; the named refit is compared
    d = load_diagnosis(tmp_path / "nominal")
    assert d.verdict == "missing-effect" and d.decision.named == ("wind",)
    assert (tmp_path / "nominal" / "check.json").exists()
    assert (tmp_path / "nominal" / "refit-wind" / "report.json").exists()
    assert (tmp_path / "compare.json").exists() and (tmp_path / "compare.png").stat().st_size > 10_000
