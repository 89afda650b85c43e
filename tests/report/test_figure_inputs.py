"""The figures draw what they are given: report/ runs no simulation (it imports neither the plugin registry nor an
engine), and the fit's figures get their rollouts from softsbi.workflows.fit.plots, which simulates."""
import ast
import dataclasses
from pathlib import Path
from types import SimpleNamespace

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import softsbi.report
from softsbi.core.results.fitreport import FitReport
from softsbi.core.types import Handle, Param, ParamSpace, Rollout, Scenario
from softsbi.report.fit_figures import frames_figure
from softsbi.scenarios.handles import grasped_vertex, handle_tracks, pinned_vertices
from softsbi.workflows.fit import plots as fitplots

#: packages whose import would let a figure simulate or drive a run
ABOVE_DRAWING = ("softsbi.plugins", "softsbi.backends", "softsbi.executors", "softsbi.workflows", "softsbi.cli")


def _imports(path: Path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return out


def test_report_imports_no_simulator():
    """figures.py built a simulator from the plugin registry to draw clouds.png and frames.png."""
    for path in Path(softsbi.report.__file__).parent.glob("*.py"):
        bad = sorted(m for m in _imports(path) if m.startswith(ABOVE_DRAWING))
        assert not bad, f"{path.name} imports {bad}"


def _grid_scenario(T=4):
    up = np.linspace(0, 0.2, T)
    p0 = np.stack([np.zeros(T), np.zeros(T), up], 1)
    handles = [Handle("left", {"corner": 0}, p0 + [0.0, 0.05, 0.0]), Handle("held", {"corner": 2}),
               Handle("tip", {"point": [0.2, 0.0, 0.0]}, p0)]
    sc = Scenario(name="grid", times=np.arange(T) * 0.1, gripper=p0, table_z=0.0, object={"kind": "cloth"},
                  handles=handles)
    xs = np.linspace(0, 0.2, 3)
    rest = np.array([[x, y, 0.0] for x in xs for y in xs])
    return sc, np.repeat(rest[None], T, 0)


def test_handle_geometry_lives_with_the_scenarios():
    sc, verts = _grid_scenario()
    assert grasped_vertex({"corner": 2}, verts[0], rope=False) == 8
    assert grasped_vertex({"end": 1}, verts[0], rope=True) == 8
    assert grasped_vertex({"corner": 0}, verts[0, :5], rope=False) is None  # not a square grid
    (n0, left), (n1, tip) = handle_tracks(sc, verts[0])
    assert (n0, n1) == ("left", "tip")
    np.testing.assert_allclose(left[0], verts[0, 0])  # shifted from 5 cm off onto its corner
    np.testing.assert_allclose(tip[0], [0.2, 0.0, 0.0])
    assert pinned_vertices(sc, verts[0], rope=False) == [("held", 8)]


class _Sim:
    calls: list = []

    def __init__(self, **options):
        pass

    @staticmethod
    def _rollout():
        sc, verts = _grid_scenario()
        return Rollout(times=sc.times, gripper=sc.gripper, vertices=verts, faces=np.array([[0, 1, 3], [1, 4, 3]]))

    def simulate(self, scenario, theta, effects=(), seed=0):
        _Sim.calls.append(("simulate", dict(theta), seed))
        return self._rollout()

    def simulate_images(self, scenario, theta, camera=None, style=None, effects=(), seed=0):
        _Sim.calls.append(("simulate_images", dict(theta), seed))
        return dataclasses.replace(self._rollout(), rgb=np.zeros((4, 16, 16, 3), np.uint8))


class _Obs:
    camera = style = None

    def __init__(self, **options):
        pass

    def observe_images(self, images, gripper, times):
        return SimpleNamespace(points=np.full((len(images), 2, 2), 4.0))


def _fit(monkeypatch, metric="chamfer_m"):
    reg = SimpleNamespace(simulator=lambda name: _Sim, observer=lambda name: _Obs)
    monkeypatch.setattr(fitplots, "registry", lambda: reg)
    _Sim.calls = []
    sc, verts = _grid_scenario()
    space = ParamSpace([Param("bend", 1e-6, 1e-3, "N*m", log=True), Param("mass", 0.1, 0.3, "kg/m^2")])
    store = SimpleNamespace(has=lambda g: False)
    report = {"observed": "x", "backend": "toy", "effects": [], "metric": metric, "chamfer_prior_m": 0.04,
              "per_round": [{"round": 0, "chamfer_posterior_m": 0.02, "chamfer_posterior_std_m": 0.01}],
              "posterior_median": {"bend": 1e-4, "mass": 0.2}, "parameters": space.to_json()}
    result = SimpleNamespace(report=FitReport.from_json(report), param_space=space, store=store)
    images = np.zeros((4, 16, 16, 3), np.uint8)
    images[:, 4:12, 4:12] = (200, 40, 40)
    meas = SimpleNamespace(truth={}, scenario=sc, dense=verts, images=images)
    cfg = SimpleNamespace(fixed={"mass": 0.25}, backend="toy", backend_options={}, effects=[], observer="toy")
    samples = space.from_unit(np.random.default_rng(0).uniform(size=(50, 2)))
    return result, meas, cfg, samples


def test_the_fit_figures_simulate_in_workflows_at_the_posterior_median(tmp_path, monkeypatch):
    result, meas, cfg, samples = _fit(monkeypatch)
    paths = fitplots.write_fit_plots(tmp_path, result, meas, cfg, samples)
    assert [p.name for p in paths] == ["chamfer_rounds.png", "posterior_pairs.png", "clouds.png"]
    assert all(p.stat().st_size > 10_000 for p in paths)
    assert _Sim.calls == [("simulate", {"bend": 1e-4, "mass": 0.25}, 0)]  # the fixed parameters win


def test_image_fits_draw_measured_and_rendered_frames(tmp_path, monkeypatch):
    result, meas, cfg, samples = _fit(monkeypatch, metric="mask_chamfer_px")
    paths = fitplots.write_fit_plots(tmp_path, result, meas, cfg, samples)
    assert paths[-1].name == "frames.png" and not (tmp_path / "frames_error.txt").exists()
    assert [c[0] for c in _Sim.calls] == ["simulate_images"]


def test_frames_figure_draws_one_row_per_source():
    imgs = np.zeros((4, 16, 16, 3), np.uint8)
    kp = np.full((4, 2, 2), 4.0)
    masks = np.zeros((4, 16, 16), bool)
    masks[:, 4:12, 4:12] = True
    rep = {"backend": "toy", "effects": [], "mask_chamfer_prior_px": 5.0, "mask_chamfer_posterior_px": 1.5}
    fig = frames_figure([("measured", imgs, kp, masks), ("posterior median", imgs, kp, masks)], (0, 3), rep,
                        "grid", "toy")
    assert [ax.get_title() for ax in fig.axes] == ["measured, frame 0", "measured, frame 3",
                                                   "posterior median, frame 0", "posterior median, frame 3"]
    assert "mask Chamfer prior 5.00 px → posterior 1.500 px" in fig.texts[1].get_text()
    plt.close(fig)
