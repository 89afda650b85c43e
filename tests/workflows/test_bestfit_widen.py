"""fit's best fit and ``--refine`` (CMA-ES from the posterior), and ``--widen`` (priors that follow the data), on
the toy simulator: its centres are ``A theta`` plus noise of ``sigma`` (tests/plugins/softsbi_toy), so with a
tiny ``sigma`` the Chamfer to a recording at ``theta*`` is smallest at ``theta*`` (the analytic optimum)."""
import json
import shutil

import numpy as np
import pytest
from typer.testing import CliRunner

import softsbi
from softsbi.cli import app
from softsbi.core.errors import SoftsbiError
from softsbi.core.store import RunStore
from softsbi.core.types import STATUS_PENDING, Param, ParamSpace
from softsbi.workflows.fit.bestfit import REFINE, _numpy_seed, _strategy
from softsbi.workflows.fit.run import FitConfig
from softsbi.workflows.measurement import simulate_recording
from softsbi.workflows.fit.prior_widening import decide_widening, records

pytestmark = pytest.mark.integration

toy = pytest.importorskip("softsbi_toy.plugin", reason="install tests/plugins/softsbi_toy (pip install -e)")

OPTS = dict(hidden=(32, 32), max_epochs=60, patience=10, batch_size=32, lr=3e-3, ensemble=1, recalibrate=False,
            n_components=2, rkhs_features=16)


def _fit_kw(sigma: float, **kw):
    return dict(backend="toy-gauss", backend_options={"sigma": sigma}, estimator="rkhs", n_points=8, n_eval=5,
                n_dense=64, workers=1, seed=3, plots=False, estimator_options=OPTS, **kw)


def _recording(truth, sigma, T=3):
    return simulate_recording("toy-gauss", toy.toy_scenario(T), truth, backend_options={"sigma": sigma}, n_points=16,
                              n_dense=64, seed=5)


def test_refine_finds_the_analytic_optimum_leaves_the_posterior_and_resumes_to_the_same_result(tmp_path):
    truth = {"a": 0.3, "b": -0.4}
    meas = _recording(truth, 1e-4)
    kw = _fit_kw(1e-4, rounds=1, sims_per_round=60)
    out = tmp_path / "run"
    plain = softsbi.fit(meas, out, **kw).report.to_json()
    assert plain["best_fit"]["refine"] is None and plain["best_fit"]["simulations_searched"] == 65
    before = plain["best_fit"]["chamfer_m"]
    refined = softsbi.fit(meas, out, refine=48, **kw).report.to_json()  # the finished run, refined
    assert refined["posterior_mean"] == plain["posterior_mean"] and refined["posterior_q95"] == plain["posterior_q95"]
    b = refined["best_fit"]
    assert b["source"] == "refinement (CMA-ES)" and b["refine"]["simulations"] == 48 and b["chamfer_m"] < before
    assert b["refine"]["best_before"] == before and b["simulations_searched"] == 65 + 48
    assert all(abs(b["theta"][k] - v) < 0.02 for k, v in truth.items()), b["theta"]
    run = softsbi.open_run(out)  # the Python API
    assert run.best_fit.theta == pytest.approx(b["theta"]) and run.best_fit.value == b["chamfer_m"]
    assert run.best_fit.vertices.shape == (3, 4, 3) and run.best_fit.source == b["source"]
    # the stored rollout repeats the best simulation: its per-frame Chamfer is the one searched
    np.testing.assert_allclose(run.best_fit.per_frame, b["chamfer_per_frame_m"])
    # a refinement killed mid-generation (the last 9 results missing) and one killed before its last two
    # generations were asked resume to the same simulations and the same best fit
    rows, _ = RunStore.open(out / "run.zarr").read_rows(REFINE)
    for cut, drop in ((39, False), (36, True)):
        other = tmp_path / f"killed{cut}"
        shutil.copytree(out, other)
        store = RunStore.open(other / "run.zarr")
        if drop:
            for k in store.root[REFINE].array_keys():
                arr = store.root[REFINE][k]
                arr.resize((cut,) + tuple(arr.shape[1:]))
        else:
            store.write_rows(REFINE, cut, {"chamfer": np.full((48 - cut, 3), np.nan),
                                           "status": np.full(48 - cut, STATUS_PENDING, np.uint8)})
        store.remove_group("best_fit")
        again = softsbi.fit(meas, other, refine=48, **kw).report.to_json()["best_fit"]
        assert again["theta"] == b["theta"] and again["chamfer_m"] == b["chamfer_m"]
        resumed, _ = RunStore.open(other / "run.zarr").read_rows(REFINE)
        np.testing.assert_array_equal(resumed["u"], rows["u"])
        np.testing.assert_array_equal(resumed["chamfer"], rows["chamfer"])
    # fewer refinement simulations than stored: only the first ones count
    fewer = softsbi.fit(meas, out, refine=12, **kw).report.to_json()["best_fit"]
    assert fewer["refine"]["simulations"] == 12 and fewer["chamfer_m"] >= b["chamfer_m"]


def test_cma_es_starts_at_the_posteriors_mean_with_its_covariance():
    mean, cov = np.array([0.4, 0.6]), np.array([[0.01, 0.008], [0.008, 0.01]])
    draws = []
    for g in range(300):
        es = _strategy(mean, cov)
        with _numpy_seed([0, g]):
            draws += es.ask()
    draws = np.array(draws)
    np.testing.assert_allclose(draws.mean(0), mean, atol=0.01)
    np.testing.assert_allclose(np.cov(draws.T), cov, atol=0.0015)
    assert draws.min() >= 0 and draws.max() <= 1  # inside the prior box


@pytest.mark.slow
def test_widen_moves_a_pressed_bound_only_while_pressed_and_a_resumed_run_gives_the_same_result(tmp_path):
    """Hidden a = 1.3 beyond the prior [-1, 1]: an early round's posterior presses the upper bound, which moves half
    the range outward ([-1, 2]) for the following rounds; their posterior sits inside, so nothing moves again."""
    meas = _recording({"a": 1.3, "b": -0.4}, 0.01, T=6)
    kw = _fit_kw(0.01, rounds=3, sims_per_round=80, widen=True)
    out = tmp_path / "run"
    rep = softsbi.fit(meas, out, **kw).report.to_json()
    assert [(w["bounds"], w["before"]) for w in rep["widened"]] == [({"a": [-1.0, 2.0]}, {"a": [-1.0, 1.0]})]
    r0 = rep["widened"][0]["after_round"]
    assert r0 in (0, 1) and rep["widened"][0]["pressed"][0]["side"] == "upper"
    space = ParamSpace.from_json(rep["parameters"])
    assert (space["a"].low, space["a"].high) == (-1.0, 2.0) and rep["posterior_at_bounds"] == []
    assert rep["posterior_mean"]["a"] > 1.05  # beyond the old bound, towards the hidden 1.3
    store = RunStore.open(out / "run.zarr")
    assert store.config["param_space"] == rep["parameters"]  # the prior of record is the widened one
    for r in range(3):  # every stored u is in the widened prior's unit cube
        d = store.round_data(r)
        np.testing.assert_allclose(d["u"], space.to_unit(d["theta"]), atol=1e-12)
    assert store.round_data(r0 + 1)["theta"][:, 0].max() > 1.0  # the next round drew beyond the old bound
    assert store.round_data(r0)["theta"][:, 0].max() <= 1.0
    # killed right after widening (later rounds never stored), and before the stored u were rewritten
    for rewrite in (False, True):
        other = tmp_path / f"killed{int(rewrite)}"
        shutil.copytree(out, other)
        for name in [f"rounds/{r}" for r in range(r0 + 1, 3)] + ["evaluation", "best_fit"]:
            shutil.rmtree(other / "run.zarr" / name)
        (other / "report.json").unlink()
        if rewrite:
            s = RunStore.open(other / "run.zarr")
            for r in range(r0 + 1):
                g = s.root["rounds"][str(r)]
                g["u"][...] = ParamSpace([Param("a", -1.0, 1.0), Param("b", -1.0, 1.0)]).to_unit(g["theta"][...])
        again = softsbi.fit(meas, other, **kw).report.to_json()
        assert again["posterior_mean"] == rep["posterior_mean"] and again["widened"] == rep["widened"]
        assert again["parameters"] == rep["parameters"]
    # resumed without --widen: the prior of record is kept and nothing is decided again
    same = softsbi.fit(meas, out, **{**kw, "widen": False}).report.to_json()
    assert same["posterior_mean"] == rep["posterior_mean"] and same["widened"] == rep["widened"]
    # a redone round (--retry-failed, damaged simulations): its widening is dropped, decided again
    s = RunStore.open(out / "run.zarr")
    s.redo(r0, [0])
    redone = softsbi.fit(meas, out, **kw).report.to_json()
    assert redone["widened"][0]["bounds"] == rep["widened"][0]["bounds"]
    assert redone["posterior_mean"] == rep["posterior_mean"]


def test_decide_never_moves_a_physical_limit_nor_an_unpressed_bound(tmp_path):
    space = ParamSpace([Param("k", 0.0, 1.0, "N/m", limits=(0.0, 1.2)), Param("f", 0.1, 10.0, "1", log=True)])
    store = RunStore.create(tmp_path / "run.zarr", {"param_space": space.to_json()})
    rng = np.random.default_rng(0)
    flat = space.from_unit(rng.random((2000, 2)))
    assert decide_widening(store, space, flat, 0) is None and records(store.config) == []
    low = flat.copy()
    low[:, 0] = rng.uniform(0.0, 0.03, 2000)  # piled at k's lower bound, its physical limit
    assert decide_widening(store, space, low, 0) is None
    high = flat.copy()
    high[:, 0] = rng.uniform(0.97, 1.0, 2000)  # piled at the upper bound: moved, clipped to the limit 1.2
    wide = decide_widening(store, space, high, 0)
    assert (wide["k"].low, wide["k"].high) == (0.0, 1.2) and (wide["f"].low, wide["f"].high) == (0.1, 10.0)
    assert store.config["param_space"] == wide.to_json() and records(store.config)[0]["bounds"] == {"k": [0.0, 1.2]}
    at_limit = flat.copy()
    at_limit[:, 0] = rng.uniform(1.17, 1.2, 2000)
    assert decide_widening(store, wide, at_limit, 1) is None  # the widened bound is now the physical limit
    logs = flat.copy()
    logs[:, 1] = np.exp(rng.uniform(np.log(0.1), np.log(0.12), 2000))  # a log-scaled lower bound, no limit above 0
    f = decide_widening(store, space, logs, 0)["f"]
    assert np.isclose(f.low, 0.1 / 10.0) and f.high == 10.0  # half the range in log scale: one decade
    # an effect's switched-off value stays
    assert decide_widening(store, space, logs, 0, keep={"f": 0.1}) is None


def test_widen_and_refine_refuse_settings_they_cannot_work_with(tmp_path):
    for cfg, match in ((FitConfig(widen=True, proposal="corrected"), "--widen needs truncated"),
                       (FitConfig(widen=True, estimator="nn-bulk"), "--widen needs truncated"),
                       (FitConfig(widen=True, sensor_draws=2), "--sensor-draws"),
                       (FitConfig(refine=-1), "--refine")):
        with pytest.raises(SoftsbiError, match=match):
            cfg.validate()
    res = CliRunner().invoke(app, ["fit", "--observed", str(tmp_path / "none"), "--out", str(tmp_path / "o"),
                                   "--widen", "--proposal", "corrected"])
    assert res.exit_code == 2 and "--widen" in res.output and "truncated" in res.output  # the flag, the proposal
    assert not (tmp_path / "o").exists()


def test_fit_table_and_report_say_what_was_widened_and_the_best_fit(tmp_path, capsys):
    """The fit prints a note per widening of its report and a line for its best fit, under the table, as
    softsbi.report.fit_text renders them (their wording: tests/report/test_fit_text.py)."""
    from toy_helpers import printed_fit_report
    from softsbi.report.fit_text import best_fit_lines
    from softsbi.workflows.fit.prior_widening import widening_sentence
    meas = _recording({"a": 0.3, "b": -0.4}, 1e-4)
    rep = softsbi.fit(meas, tmp_path / "run", **_fit_kw(1e-4, rounds=1, sims_per_round=30)).report.to_json()
    b = rep["best_fit"]  # what the best-fit line reads: the parameters, the Chamfer, where it comes from
    assert set(b["theta"]) == {"a", "b"} and b["chamfer_m"] > 0 and b["source"] and b["simulations_searched"] == 35
    plain = best_fit_lines(rep)
    widened = {"after_round": 0, "before": {"a": [-1.0, 1.0]}, "bounds": {"a": [-1.0, 2.0]},
               "pressed": [{"param": "a", "side": "upper", "bound": 1.0, "unit": "1", "mass": 0.36}]}
    rep["widened"] = [widened]
    _, lines = printed_fit_report(rep, tmp_path / "run", capsys)
    noted = best_fit_lines(rep, [widening_sentence(widened)])
    assert len(plain) == 1 and noted[1:] == plain and widening_sentence(widened) in noted[0]
    k = lines.index(plain[0])  # the widening's note, then the best fit, each printed once
    assert lines[k - 1:k + 1] == noted and lines.count(plain[0]) == 1
    saved = json.loads((tmp_path / "run" / "report.json").read_text())
    assert saved["best_fit"]["rollout"] == "run.zarr/best_fit" and saved["widened"] == []
