"""``softsbi view``: the GIF and the rerun recording of a finished fit's posterior-predictive rollouts."""
from __future__ import annotations

import json
from dataclasses import replace
import sys

import numpy as np
import pytest
from PIL import Image

from softsbi.backends.mujoco_flex import MujocoFlex
from softsbi.scenarios.builtin import lift_scenario
from softsbi.core.errors import DependencyMissing, SoftsbiError
from softsbi.workflows.fit.run import FitConfig, run_fit
from softsbi.workflows.measurement import simulate_recording
from softsbi.report.animation import _edges
from softsbi.workflows.view import posterior_rollouts, write_animation, write_rerun, write_view

pytestmark = pytest.mark.integration

T = 8  # recorded frames of the small lift
S = 3  # posterior rollouts shown


@pytest.fixture(scope="module")
def lift_run(tmp_path_factory):
    """A small finished mujoco-flex lift fit (grid 5, 8 frames, one round of 12 simulations: ~8 s)."""
    sc = lift_scenario(None, n_frames=T)
    truth = MujocoFlex(grid=5).param_space(sc).midpoint()
    meas = simulate_recording("mujoco-flex", sc, truth, backend_options={"grid": 5}, n_points=16, n_dense=200,
                                seed=3)
    cfg = FitConfig(backend="mujoco-flex", backend_options={"grid": 5}, rounds=1, sims_per_round=12, n_eval=5,
                    n_points=16, n_dense=200, workers=1, seed=0,
                    estimator_options={"max_epochs": 20, "hidden": [16]})
    out = tmp_path_factory.mktemp("view") / "lift"
    run_fit(out, meas, cfg, make_plots=False)
    return out


def test_posterior_rollouts(lift_run):
    view, rollouts, ch = posterior_rollouts(lift_run, n_eval=S, workers=1)
    assert len(rollouts) == S and [r.sample for r in rollouts] == list(range(S))
    for r in rollouts:
        assert r.vertices.shape == (T, 25, 3) and r.faces.shape == (32, 3)
    assert ch.shape == (S, T) and np.all(np.isfinite(ch))
    # a fit to a simulated measurement: its posterior rollouts are within centimetres of it
    assert 0 < ch.mean() < 0.05
    assert view.dense.shape == (T, 200, 3)
    with pytest.raises(SoftsbiError, match="n_eval"):
        posterior_rollouts(lift_run, n_eval=0)


def test_edges_of_a_mesh_and_of_a_rope():
    outer, inner = _edges(np.array([[0, 1, 2], [0, 2, 3]]), 4)
    assert len(outer) == 4 and inner.tolist() == [[0, 2]]
    outer, inner = _edges(np.zeros((0, 3), int), 3)
    assert outer.tolist() == [[0, 1], [1, 2]] and len(inner) == 0


def _frames(path) -> list[np.ndarray]:
    im = Image.open(path)
    out = []
    for k in range(im.n_frames):
        im.seek(k)
        out.append(np.asarray(im.convert("RGB"), dtype=float))
    return out


def _has_colour(frame: np.ndarray, rgb: tuple[int, int, int], tol: float = 30, n: int = 20) -> bool:
    return int((np.abs(frame - np.array(rgb)).max(-1) < tol).sum()) >= n


def test_gif_has_one_frame_per_recorded_frame(lift_run, tmp_path):
    p = write_animation(lift_run, tmp_path / "anim.gif", n_eval=S, workers=1, fps=10)
    assert p == tmp_path / "anim.gif"
    im = Image.open(p)
    assert im.n_frames == T
    assert im.info.get("duration") == 100  # ms per frame at 10 fps
    frames = _frames(p)
    assert frames[0].shape[0] > 400 and frames[0].shape[1] > 700
    for f in frames:  # not blank: real content in every frame
        assert f.std() > 20
    # the scene moves: every frame differs from the previous one, the last one clearly from the first
    diffs = [np.abs(frames[k + 1] - frames[k]).mean() for k in range(T - 1)]
    assert min(diffs) > 0.2, diffs
    assert np.abs(frames[-1] - frames[0]).mean() > 1.0
    # the views (upper part) use the palette of every figure: the measured cloud in its grey and the
    # faded rollouts in the posterior's blue
    from matplotlib.colors import to_rgb
    from softsbi.report import ROLE_COLOURS
    views = frames[T // 2][: int(0.7 * frames[0].shape[0])]
    assert _has_colour(views, tuple(int(255 * c) for c in to_rgb(ROLE_COLOURS["measured"])))
    bluish = (views[..., 2] > views[..., 0] + 40) & (views[..., 2] > 150)
    assert bluish.sum() > 300


def test_write_view_gif_only_default_path(lift_run):
    res = write_view(lift_run, n_eval=S, workers=1, gif=True, rrd=False)
    assert res["gif"] == lift_run / "view.gif" and res["rrd"] is None
    assert Image.open(res["gif"]).n_frames == T
    assert len(res["chamfer_per_frame_m"]) == T and len(res["times_s"]) == T
    assert res["n_rollouts"] == S and res["failed_rollouts"] == 0
    assert res["chamfer_mean_m"] == pytest.approx(np.mean(res["chamfer_per_frame_m"]))


def test_rrd_missing_rerun_names_the_extra(lift_run, monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun", None)  # import rerun -> ImportError
    with pytest.raises(DependencyMissing, match=r'pip install "softsbi\[view\]"'):
        write_rerun(lift_run, n_eval=S, workers=1)
    with pytest.raises(DependencyMissing, match="rerun"):
        write_view(lift_run, n_eval=S, workers=1, gif=False, rrd=True)


def test_view_without_rerun_writes_the_gif_and_names_the_extra(lift_run, monkeypatch):
    """`softsbi view RUN` with its defaults exited 2 and wrote no GIF on a machine without rerun-sdk."""
    from typer.testing import CliRunner

    from softsbi.cli import app
    monkeypatch.setitem(sys.modules, "rerun", None)  # import rerun -> ImportError
    (lift_run / "view.gif").unlink(missing_ok=True)
    res = CliRunner().invoke(app, ["view", str(lift_run), "--n-eval", str(S), "--workers", "1"])
    assert res.exit_code == 0, res.output
    assert Image.open(lift_run / "view.gif").n_frames == T
    said = " ".join(res.output.split())
    assert "view.rrd" in said and 'pip install "softsbi[view]"' in said  # the file not written and the extra
    res = CliRunner().invoke(app, ["view", str(lift_run), "--rrd", "--workers", "1"])  # asked for: refused at once
    assert res.exit_code == 2 and 'pip install "softsbi[view]"' in " ".join(res.output.split())
    assert 'softsbi[view]' in " ".join(CliRunner().invoke(app, ["view", "--help"]).output.split())


def _read_rrd(path) -> dict[str, list]:
    """``{entity path: [non-static chunks]}`` of an .rrd, plus the static ones under ``"static:" + path``."""
    from rerun.chunk import RrdReader
    out: dict[str, list] = {}
    for c in RrdReader(path).stream():
        out.setdefault(("static:" if c.is_static else "") + c.entity_path, []).append(c)
    return out


def test_rrd_has_the_entities_on_a_time_timeline(lift_run):
    pytest.importorskip("rerun")
    from rerun.chunk import RrdReader
    p = write_rerun(lift_run, n_eval=S, workers=1)
    assert p == lift_run / "view.rrd"
    paths = set(RrdReader(p).store().schema().entity_paths())
    expected = {"/world/measured", "/world/gripper", "/world/gripper_path", "/error/chamfer_cm"}
    expected |= {f"/world/posterior/{i}" for i in range(S)} | {f"/error/rollouts/{i}" for i in range(S)}
    expected |= {"/world/best_fit", "/error/best_fit_cm"}  # the fit's best fit, its rollout stored in the run
    assert expected <= paths
    chunks = _read_rrd(p)
    for ent in ("/world/measured", "/world/gripper", "/world/posterior/0", "/error/chamfer_cm", "/world/best_fit",
                "/error/best_fit_cm"):
        rows = sum(c.num_rows for c in chunks[ent])
        assert rows == T, ent
        assert all(c.timeline_names == ["time"] for c in chunks[ent])
    rb = chunks["/world/posterior/0"][0].to_record_batch()
    assert "Mesh3D:vertex_positions" in rb.schema.names and "Mesh3D:triangle_indices" in rb.schema.names
    assert len(rb.column("Mesh3D:vertex_positions").to_pylist()[0]) == 25
    assert "static:/world/gripper_path" in chunks
    # the time line is in seconds, the scalars are the mean Chamfer in cm
    rows = sorted((t.total_seconds(), v[0]) for c in chunks["/error/chamfer_cm"]
                  for t, v in zip(c.to_record_batch().column("time").to_pylist(),
                                  c.to_record_batch().column("Scalars:scalars").to_pylist()))
    view, _, ch = posterior_rollouts(lift_run, n_eval=S, workers=1)
    np.testing.assert_allclose([r[0] for r in rows], view.scenario.times, atol=1e-6)
    np.testing.assert_allclose([r[1] for r in rows], ch.mean(0) * 100, rtol=1e-6)
    # the best fit's Chamfer per frame is the fit's own metric of its stored simulation (report.json)
    best = [v[0] for c in chunks["/error/best_fit_cm"] for v in c.to_record_batch().column("Scalars:scalars").to_pylist()]
    rep = json.loads((lift_run / "report.json").read_text())["best_fit"]
    np.testing.assert_allclose(best, np.array(rep["chamfer_per_frame_m"]) * 100, rtol=1e-5)


def test_write_view_both_from_one_simulation(lift_run, monkeypatch):
    pytest.importorskip("rerun")
    from softsbi.workflows import view as viewer
    calls = []
    real = viewer.posterior_rollouts
    monkeypatch.setattr(viewer, "posterior_rollouts", lambda *a, **k: calls.append(a) or real(*a, **k))
    res = viewer.write_view(lift_run, n_eval=S, workers=1)
    assert len(calls) == 1
    assert res["gif"] == lift_run / "view.gif" and res["rrd"] == lift_run / "view.rrd"
    assert Image.open(res["gif"]).n_frames == T and res["rrd"].stat().st_size > 10_000


def test_rrd_of_a_rope_logs_line_strips(lift_run, tmp_path):
    """A rollout without faces (a rope) is logged as its centre line."""
    pytest.importorskip("rerun")
    import rerun as rr

    from softsbi.report.animation import log_rrd as _log_rrd
    view, rollouts, ch = posterior_rollouts(lift_run, n_eval=1, workers=1)
    rope = [replace(rollouts[0], vertices=rollouts[0].vertices[:, :5], faces=np.zeros((0, 3), int))]
    p = _log_rrd(rr, view, rope, ch, tmp_path / "rope.rrd")
    names = _read_rrd(p)["/world/posterior/0"][0].to_record_batch().schema.names
    assert "LineStrips3D:strips" in names and not any(n.startswith("Mesh3D") for n in names)
