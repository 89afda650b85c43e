"""``softsbi fit`` with an estimator whose posterior is not a Gaussian mixture (``flow``): the run store
keeps the estimator's state, so truncated proposals, resuming, ``open_run`` and ``calibrate`` work; a damaged
state is named in one line and trained again; runs written before (mixtures only) still open."""
from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
import zarr

import softsbi
from softsbi.core.distributions import gaussian
from softsbi.core.errors import DependencyMissing, PosteriorDamaged, SchemaError
from softsbi.core.store import EstimatorState, RunStore
from softsbi.workflows.fit.run import FitCallbacks, FitConfig, run_fit

pytestmark = pytest.mark.integration

pytest.importorskip("zuko")
pytest.importorskip("softsbi_toy.plugin", reason="install tests/plugins/softsbi_toy (pip install -e)")
from toy_helpers import toy_measurement  # noqa: E402

FLOW = {"max_epochs": 20, "transforms": 1, "hidden": [16]}


def _cfg(**kw) -> FitConfig:
    base = dict(backend="toy-gauss", estimator="flow", rounds=2, sims_per_round=40, workers=1, n_points=8, n_eval=3,
                n_dense=32, seed=0, estimator_options=FLOW)
    return FitConfig(**{**base, **kw})


@pytest.fixture(scope="module")
def flow_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("flow") / "run"
    res = run_fit(out, toy_measurement(), _cfg(), make_plots=False)
    return out, res


def test_flow_fit_with_truncated_proposals_reopens_with_the_same_posterior(flow_run):
    out, res = flow_run
    store = RunStore.open(out / "run.zarr")
    assert store.completed_rounds() == [0, 1] and res.report.proposal == "truncated"
    assert store.round_attrs(1)["proposal"].startswith("prior truncated to the 0.999 region of round 1's posterior")
    assert dict(store.root["rounds"]["1"]["posterior"].attrs)["kind"] == "estimator"
    # round 2 drew inside the truncation region only
    u1 = store.round_data(1)["u"]
    assert u1.shape == (40, 2) and np.all((u1 >= 0) & (u1 <= 1))
    post = softsbi.open_run(out).posterior
    rng = lambda: np.random.default_rng(3)  # noqa: E731
    np.testing.assert_array_equal(post.unit.sample(50, rng()), res.posterior.sample(50, rng()))
    u = np.random.default_rng(4).random((30, 2))
    np.testing.assert_array_equal(post.unit.log_prob(u), res.posterior.log_prob(u))
    theta = post.sample(20)
    assert theta.shape == (20, 2) and np.isfinite(post.log_prob(theta)).all()
    assert set(post.mean) == {"a", "b"} and all(lo < hi for lo, hi in post.interval(0.9).values())


def test_flow_fit_resumes_from_the_stored_flow_after_an_interruption(flow_run, tmp_path):
    out, res = flow_run

    class Stop(Exception):
        pass

    class StopAfterRound1(FitCallbacks):
        def round_end(self, r, summary):
            raise Stop

    with pytest.raises(Stop):
        run_fit(tmp_path / "run", toy_measurement(), _cfg(), callbacks=StopAfterRound1(), make_plots=False)
    store = RunStore.open(tmp_path / "run" / "run.zarr")
    assert store.completed_rounds() == [0] and not store.is_begun(1)
    # the resumed fit draws round 2 from round 1's flow restored from the store: the same draws as without a break
    again = run_fit(tmp_path / "run", toy_measurement(), _cfg(), make_plots=False)
    np.testing.assert_array_equal(again.store.round_data(1)["u"], RunStore.open(out / "run.zarr").round_data(1)["u"])
    u = np.random.default_rng(5).random((30, 2))
    np.testing.assert_allclose(again.posterior.log_prob(u), res.posterior.log_prob(u), rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("damage", ["missing", "corrupt"])
def test_a_damaged_estimator_state_is_named_in_one_line_and_trained_again(flow_run, tmp_path, damage, monkeypatch):
    from softsbi.plugins import registry
    out, res = flow_run
    run = tmp_path / "run"
    shutil.copytree(out, run)
    state = run / "run.zarr" / "rounds" / "1" / "posterior" / "state"
    if damage == "missing":
        shutil.rmtree(state)
    else:  # every chunk of the largest array overwritten with other bytes of the same length
        chunks = max((p for p in state.rglob("*") if p.is_file() and p.name != "zarr.json"), key=lambda p: p.stat().st_size)
        chunks.write_bytes(bytes(255 - b for b in chunks.read_bytes()))
    with pytest.raises(PosteriorDamaged, match=r"round 2's stored posterior .*re-run the same `softsbi fit` command") as info:
        softsbi.open_run(run)
    assert "\n" not in str(info.value)
    messages = []

    class Log(FitCallbacks):
        def message(self, text):
            messages.append(text)

    trained = []  # the rows each training sees
    cls = registry().estimator("flow")
    fit = cls.fit
    monkeypatch.setattr(cls, "fit", lambda self, *a, **k: trained.append(len(a[0])) or fit(self, *a, **k))
    run_fit(run, toy_measurement(), _cfg(), callbacks=Log(), make_plots=False)
    # round 2 alone is trained again, on both rounds' 80 stored simulations; the fit says so, naming the problem
    # open_run named (PosteriorDamaged.problem, without its fix)
    assert trained == [80]
    assert sum(m.startswith(info.value.problem) for m in messages) == 1
    u = np.random.default_rng(6).random((30, 2))
    np.testing.assert_allclose(softsbi.open_run(run).posterior.unit.log_prob(u), res.posterior.log_prob(u),
                               rtol=1e-6, atol=1e-6)


def test_calibrate_runs_on_a_flow_run(flow_run, tmp_path):
    from softsbi.workflows.tasks.calibrate import calibrate_run

    run = tmp_path / "run"
    shutil.copytree(flow_run[0], run)
    out = calibrate_run(run, n_test=20, n_draws=100, workers=1, write=False)
    assert out.estimator == "flow" and out.n_test + out.n_test_failed == 50
    assert out.refit_max_mean_difference < 1e-6  # retrained as the fit trained it: the stored flow again
    assert 0 <= out.coverage.at_50 <= out.coverage.at_90 <= 1


def test_a_run_written_before_estimator_states_opens_as_before(tmp_path):
    """A version-1 run (every posterior a mixture, without kind, format or checksum) opens unchanged."""
    out = tmp_path / "run"
    softsbi.fit(toy_measurement(), out, backend="toy-gauss", estimator="mdnn", rounds=2, sims_per_round=40,
                n_points=8, n_eval=3, n_dense=32, workers=1, seed=3, plots=False,
                estimator_options={"max_epochs": 10, "hidden": [16]})
    before = softsbi.open_run(out).posterior.sample(100)
    root = zarr.open_group(str(out / "run.zarr"), mode="a")
    for r in ("0", "1"):
        p = root["rounds"][r]["posterior"]
        assert p.attrs["kind"] == "mixture"
        attrs = {k: v for k, v in p.attrs.items() if k not in ("kind", "format", "checksum")}
        p.attrs.clear()
        p.attrs.update(attrs)
    root.attrs["schema_version"] = 1
    np.testing.assert_array_equal(softsbi.open_run(out).posterior.sample(100), before)


def test_store_keeps_a_nested_estimator_state_and_checks_it(tmp_path):
    s = RunStore.create(tmp_path / "run.zarr", {"backend": "x"})
    th = np.random.default_rng(0).random((12, 2))
    s.begin_round(0, th, th, np.arange(12), (3, 5, 3), "prior")
    state = {"format": "x/1", "config": {"hidden": (8, 8), "lr": 1e-3, "max_seconds": None},
             "params": {"w": np.arange(6, dtype=np.float32).reshape(2, 3), "b": np.float32(0.5) * np.ones(0)},
             "members": [{"w": np.ones(2)}, {"w": np.zeros(2)}], "scale": np.array(2.0)}
    q = object()  # any posterior that is not a mixture is kept as its estimator's state
    with pytest.raises(SchemaError, match="state of its estimator"):
        s.finish_round(0, q, {})
    s.finish_round(0, q, {"epochs": 1}, estimator=EstimatorState("mine", {"hidden": [8, 8]}, state))
    back = RunStore.open(tmp_path / "run.zarr").read_posterior(0)
    assert back.name == "mine" and back.options == {"hidden": [8, 8]}
    assert back.state["config"] == {"hidden": [8, 8], "lr": 1e-3, "max_seconds": None}
    np.testing.assert_array_equal(back.state["params"]["w"], state["params"]["w"])
    assert back.state["params"]["w"].dtype == np.float32 and back.state["params"]["b"].shape == (0,)
    np.testing.assert_array_equal(back.state["members"][1]["w"], np.zeros(2))
    assert float(back.state["scale"]) == 2.0
    # a changed attribute no longer matches the checksum
    p = zarr.open_group(str(tmp_path / "run.zarr"), mode="a")["rounds"]["0"]["posterior"]
    p.attrs["options"] = {"hidden": [9, 9]}
    with pytest.raises(PosteriorDamaged, match="does not match its checksum"):
        RunStore.open(tmp_path / "run.zarr").read_posterior(0)
    with pytest.raises(SchemaError, match="holds a set"):
        s.finish_round(0, q, {}, estimator=EstimatorState("mine", {}, {"bad": {1, 2}}))
    s.finish_round(0, gaussian([0.5, 0.5], np.eye(2) * 0.01), {})  # replaces it with a mixture
    np.testing.assert_allclose(RunStore.open(tmp_path / "run.zarr").read_posterior(0).means, [[0.5, 0.5]])


def test_fit_names_a_missing_zuko_in_one_line_before_simulating(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "zuko", None)  # import zuko now raises ImportError
    with pytest.raises(DependencyMissing, match=r'^estimator \'flow\' needs the zuko package: pip install "softsbi\[flows\]"$'):
        run_fit(tmp_path / "run", toy_measurement(), _cfg(), make_plots=False)
    assert not (Path(tmp_path) / "run" / "run.zarr").exists()
