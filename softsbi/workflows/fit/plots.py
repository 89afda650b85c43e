"""The figures of a fit (``chamfer_rounds.png``, ``posterior_pairs.png``, ``clouds.png`` or ``frames.png``): the
simulations they show run here, at the posterior median, and :mod:`softsbi.report.fit_figures` draws them."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from softsbi.core.results.fitreport import FitReport
from softsbi.core.types import Rollout
from softsbi.perception.masks import hsv_mask
from softsbi.perception.pointcloud import rollout_clouds
from softsbi.plugins import registry
from softsbi.report.fit_figures import clouds_figure, frames_figure, plot_chamfer_rounds, plot_pairs
from softsbi.report.style import source_name, fit_label, save_figure
from softsbi.workflows.fit.config import CHAMFER_M, MASK_CHAMFER_PX

#: surface points per frame of the simulated clouds in ``clouds.png``
CLOUD_POINTS = 800
#: the figures a fit writes into its run directory (:func:`write_fit_plots`; ``frames.png`` for an image fit)
FIGURES = ("chamfer_rounds.png", "posterior_pairs.png", "clouds.png", "frames.png")


def write_fit_plots(out_dir: Path, result: Any, meas: Any, cfg: Any, samples: np.ndarray,
                    observer_options: dict[str, Any] | None = None) -> list[Path]:
    """Write ``chamfer_rounds.png``, ``posterior_pairs.png`` and ``clouds.png`` (``frames.png`` for
    image fits) into ``out_dir``; a clouds or frames figure that fails leaves ``<name>_error.txt`` instead.

    Args:
        result: :class:`~softsbi.workflows.fit.run.FitResult`. meas: the measurement.
        samples: ``(S, D)`` final-posterior samples, physical units.
        observer_options: the fit's observer constructor options (image fits draw its keypoints).
    """
    rep = result.report.to_json()
    subtitle = f"fit: {fit_label(rep)}; measurement: {source_name(result.report.observed)}"
    paths = [plot_chamfer_rounds(out_dir / "chamfer_rounds.png", rep),
             plot_pairs(out_dir / "posterior_pairs.png", result.param_space, samples, meas.truth, subtitle=subtitle)]
    image_fit = result.report.metric == MASK_CHAMFER_PX
    name = "frames.png" if image_fit else "clouds.png"
    try:
        if image_fit:
            paths.append(plot_frames(out_dir / name, result, meas, cfg, observer_options=observer_options))
        else:
            paths.append(plot_clouds(out_dir / name, result, meas, cfg))
    except Exception as exc:  # noqa: BLE001 - a failed preview must not lose the fit
        (out_dir / name.replace(".png", "_error.txt")).write_text(f"could not draw {name}: {exc}\n")
    return paths


def _four_frames(n_frames: int) -> tuple[int, ...]:
    """The first, last and two evenly spaced frames in between."""
    return tuple(sorted({0, n_frames // 3, 2 * n_frames // 3, n_frames - 1}))


def best_fit_clouds(store: Any, report: FitReport, n: int = CLOUD_POINTS) -> tuple[np.ndarray | None, str]:
    """The best fit's stored rollout (``report.best_fit``, the run store's ``best_fit`` group) as surface
    clouds ``(T, n, 3)`` m and its legend text (with its Chamfer for a point-cloud fit); ``(None, "")`` when the run
    stored none."""
    best = report.best_fit
    if best is None or not best.rollout or not store.has("best_fit"):
        return None, ""
    a, _ = store.read_group("best_fit")
    if "vertices" not in a:
        return None, ""
    ro = Rollout(times=np.arange(len(a["vertices"]), dtype=float), gripper=a["gripper"], vertices=a["vertices"],
                 faces=np.asarray(a["faces"], int))
    value = best.value if report.metric == CHAMFER_M else None
    what = f"best fit ({best.source}{'' if value is None else f', Chamfer {value * 100:.2f} cm'})"
    return rollout_clouds(ro, n, np.random.default_rng(1)), what


def plot_clouds(path: Path, result: Any, meas: Any, cfg: Any, frames: tuple[int, ...] | None = None) -> Path:
    """Measured (grey) vs simulated at the posterior median (blue) clouds and the best fit's stored rollout
    (purple, :func:`best_fit_clouds`): side view and top view. Simulates one rollout at the posterior median
    (``cfg``'s backend, effects and fixed parameters, seed 0)."""
    theta = dict(result.report.posterior_median)
    theta.update(cfg.fixed)
    sim = registry().simulator(cfg.backend)(**cfg.backend_options)
    ro = sim.simulate(meas.scenario, theta, effects=cfg.effects, seed=0)
    frames = frames or _four_frames(meas.scenario.n_frames)
    sim_pts = rollout_clouds(ro, CLOUD_POINTS, np.random.default_rng(0)) if ro.ok else None
    status = "" if ro.ok else f" (simulation failed: {ro.reason})"
    rep = result.report.to_json()
    title = f"fit: {fit_label(rep)}; measurement: {source_name(result.report.observed)}"
    best_pts, best_label = best_fit_clouds(result.store, result.report)
    return save_figure(clouds_figure(meas.scenario, meas.dense, sim_pts, frames, title, status,
                                     ro.vertices if ro.ok else None, len(ro.faces) == 0, best_pts, best_label), path)


def plot_frames(path: Path, result: Any, meas: Any, cfg: Any, frames: tuple[int, ...] | None = None,
                observer_options: dict[str, Any] | None = None) -> Path:
    """Image fits: measured frames (top) and frames rendered at the posterior median (bottom), with
    the extractor's keypoints (cyan) and the HSV cloth-mask outline (yellow) of each. Renders one rollout at
    the posterior median with the fit's observer's camera and style (seed 0)."""
    theta = dict(result.report.posterior_median)
    theta.update(cfg.fixed)
    obs = registry().observer(cfg.observer)(**dict(observer_options or {}))
    sim = registry().simulator(cfg.backend)(**cfg.backend_options)
    ro = sim.simulate_images(meas.scenario, theta, camera=obs.camera, style=obs.style, effects=cfg.effects, seed=0)
    sc = meas.scenario
    rows = [(label, imgs, obs.observe_images(imgs, sc.gripper, sc.times).points, hsv_mask(imgs))
            for label, imgs in [("measured", meas.images)] + ([("posterior median", ro.rgb)] if ro.ok else [])]
    status = "" if ro.ok else f" (posterior simulation failed: {ro.reason})"
    fig = frames_figure(rows, frames or _four_frames(sc.n_frames), result.report.to_json(), sc.name, cfg.observer,
                        status)
    return save_figure(fig, path)
