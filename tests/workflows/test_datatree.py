"""A run as an ArviZ DataTree (``softsbi.to_datatree``, the optional ``arviz`` extra): the posterior's draws by
parameter with their units, and the check's summaries of the posterior-predictive rollouts and of the measurement;
without arviz-base, one line naming the extra before anything is read."""
from __future__ import annotations

import sys

import numpy as np
import pytest

import softsbi
from softsbi.core.errors import DependencyMissing, ParameterError


def test_without_arviz_base_to_datatree_names_the_extra_in_one_line(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "arviz_base", None)  # as if not installed: its import raises ImportError
    with pytest.raises(DependencyMissing) as info:
        softsbi.to_datatree(tmp_path / "no-run-here")  # refused before the run is read
    assert str(info.value) == 'to_datatree needs arviz-base (Python 3.11 or later), which is not installed: pip install "softsbi[arviz]"'


@pytest.mark.integration
def test_a_run_exports_its_posterior_predictive_and_measurement_for_arviz(tmp_path):
    pytest.importorskip("arviz_base", reason="the 'arviz' extra (arviz-base) is not installed")
    pytest.importorskip("softsbi_toy.plugin", reason="install tests/plugins/softsbi_toy (pip install -e)")
    from toy_helpers import toy_measurement

    from softsbi.workflows.criticism.statistics import FEATURE_NAMES
    from softsbi.workflows.criticism.stats import run_features
    from softsbi.workflows.fit.run import FitConfig, run_fit
    from softsbi.workflows.fit.runs import load_run
    out = tmp_path / "run"
    run_fit(out, toy_measurement(), FitConfig(backend="toy-gauss", estimator="mdnn", rounds=1, sims_per_round=40,
                                              n_points=8, n_eval=5, n_dense=32, workers=1, seed=3,
                                              estimator_options={"max_epochs": 30, "hidden": [16]}), make_plots=False)
    run = softsbi.open_run(out)
    tree = softsbi.to_datatree(run, draws=200, workers=1)
    assert set(tree.children) == {"posterior", "posterior_predictive", "observed_data"}
    post = tree["posterior"]
    assert list(post.data_vars) == run.space.names == ["a", "b"]
    for p in run.space:
        v = post[p.name]
        assert v.dims == ("chain", "draw") and v.shape == (1, 200)
        assert v.attrs["units"] == p.unit and v.attrs["description"] == p.description
        assert p.low <= float(v.min()) and float(v.max()) <= p.high  # draws of the posterior, inside its prior box
    np.testing.assert_allclose(post["a"].values[0], run.posterior.sample(200)[:, 0])  # the run's posterior, seed 0
    view = load_run(out, None)
    T = len(view.dense)
    obs, pred = tree["observed_data"]["summaries"], tree["posterior_predictive"]["summaries"]
    assert obs.dims == ("frame", "feature") and pred.dims == ("chain", "draw", "frame", "feature")
    assert pred.shape == (1, 5, T, 14) and list(obs["feature"].values) == list(FEATURE_NAMES)
    np.testing.assert_allclose(obs.values, run_features(view, view.dense).reshape(T, 14))  # what check tests
    assert obs.attrs["units"] == pred.attrs["units"] == "m"
    assert "posterior_predictive" not in softsbi.to_datatree(out, draws=10, predictive=0).children
    with pytest.raises(ParameterError, match=r"draws must be at least 1"):
        softsbi.to_datatree(out, draws=0)


def test_the_python_api_how_to_lists_to_datatree_with_its_signature_and_groups():
    import inspect
    from pathlib import Path
    doc = (Path(__file__).parents[2] / "docs" / "howto" / "python-api.md").read_text()
    params = ", ".join(p.name if p.default is p.empty else f"{p.name}={p.default!r}"
                       for p in inspect.signature(softsbi.to_datatree).parameters.values())
    assert f"softsbi.to_datatree({params})\n" in doc
    assert 'pip install\n"softsbi[arviz]"' in doc or 'pip install "softsbi[arviz]"' in doc
    for group in ("posterior", "posterior_predictive", "observed_data"):
        assert f"| `{group}` |" in doc
