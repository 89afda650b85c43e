"""Posterior predictive check (Gelman et al., *Bayesian Data Analysis*, ch. 6).

:func:`check_run` re-simulates a finished fit at its own posterior samples (the fit's evaluation
samples and seeds, through :func:`~softsbi.workflows.jobs.simulate_job`) and compares them with
the measurement: Chamfer error per frame, per region of the object and per phase of the motion,
and a misspecification test (is the measurement's summary vector inside the distribution of
posterior-predictive summaries, in any direction or along an installed effect's?) with a
simulation-based p-value.

Every distance sees the simulated and the measured clouds through the fit's own sensor model
(:func:`~softsbi.workflows.fit.metric_sensor`: the height cut ``min_height`` above the table, or for
``--sensor camera`` the recording's virtual depth sensor, and the headline averages the fit's
``frames``), so the check's mean Chamfer is the fit's ``chamfer_posterior_m`` and neither it nor the
per-region errors blame what the sensor cannot see (issue 17). Both the bidirectional and the
one-sided (measured -> simulated) Chamfer are reported per frame.

Summaries are per-frame statistics of the point cloud (centroid, spread, height quantiles,
horizontal extent), which both simulated surfaces and real partial clouds have.
"""
from __future__ import annotations

import json
import time
import warnings
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from scipy.spatial import cKDTree

from softsbi.core.errors import SoftsbiError
from softsbi.core.types import STATUS_OK, Scenario
from softsbi.inference.contraction import bound_sentence
from softsbi.perception.depth_sensor import VirtualDepthSensor, sensor_from_json, views_or_highest
from softsbi.perception.pointcloud import sensor_indices, sensor_view
from softsbi.report import plot_check
from softsbi.workflows.fit import chamfer_stats
from softsbi.workflows.lock import check_out_dir
from softsbi.workflows.runs import RunView, load_run
from softsbi.workflows.screening import candidate_effects, misspecification_verdict
from softsbi.workflows.stats import (ALPHA, FEATURE_FLOOR, FEATURE_NAMES, MAX_NULL, N_NULL,  # noqa: F401 (re-exported)
                                     PosteriorPredictive, cloud_features, energy_score, misspecification_test,
                                     sampled_points, trajectory_features)

#: posterior rollouts the check needs at least (its error maps and the first stage of its test's null)
MIN_ROLLOUTS = 5


def surface_points(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Deterministic surface points ``(T, N + F, 3)``: vertices and face centroids."""
    if len(faces) == 0:
        return vertices
    return np.concatenate([vertices, vertices[:, faces].mean(2)], axis=1)



def material_regions(vertices0: np.ndarray, grasp: np.ndarray, n_side: int = 3) -> tuple[np.ndarray, list[str]]:
    """Partition the object into ``n_side x n_side`` regions in its rest configuration.

    Args:
        vertices0: ``(N, 3)`` vertex positions at frame 0 (material coordinates).
        grasp: ``(3,)`` gripper position at frame 0.

    Returns:
        ``labels (N,)`` int region of each vertex, and region names ordered by the distance of
        the region's centre from the grasp point ("R1 at the grasp" ... "R9 farthest").
    """
    v = vertices0 - vertices0.mean(0)
    _, _, vt = np.linalg.svd(v, full_matrices=False)
    uv = v @ vt[:2].T
    bins = []
    for k in range(2):
        edges = np.quantile(uv[:, k], np.linspace(0, 1, n_side + 1)[1:-1])
        bins.append(np.searchsorted(edges, uv[:, k], side="right"))
    raw = bins[0] * n_side + bins[1]
    centres = np.array([vertices0[raw == r].mean(0) if (raw == r).any() else np.full(3, np.inf)
                        for r in range(n_side * n_side)])
    order = np.argsort(np.linalg.norm(centres - grasp, axis=1))
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    labels = rank[raw]
    names = []
    for r in range(n_side * n_side):
        tag = " (at the grasp)" if r == 0 else (" (farthest from the grasp)" if r == n_side * n_side - 1 else "")
        names.append(f"R{r + 1}{tag}")
    return labels, names


def region_errors(vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray, dense: np.ndarray,
                  n_regions: int | None = None, min_z: float | None = None,
                  camera: VirtualDepthSensor | None = None, gripper: np.ndarray | None = None) -> np.ndarray:
    """Bidirectional nearest-neighbour error ``(T, R)`` (m) per frame and region.

    Simulated points of a region (its vertices and the centroids of faces whose first vertex
    is in it) contribute their distance to the nearest measured point; measured points are
    assigned to the region of their nearest simulated point and contribute that distance.
    Both sides keep only what the fit's sensor model sees, so a region lying flat on the table is
    not compared (NaN) unless no point of the frame is seen (then the highest 10 % of the simulated
    points stand in, :func:`~softsbi.perception.pointcloud.sensor_indices`' fallback, as in the metric):

    - ``min_z`` (the height cut, m): both sides through
      :func:`~softsbi.perception.pointcloud.sensor_view`;
    - ``camera`` (the fit's virtual depth sensor): the simulated points the sensor sees
      (:meth:`~softsbi.perception.depth_sensor.VirtualDepthSensor.seen` against the rollout's mesh, robot
      mask at ``gripper``); ``dense`` is used as given (the recording as recorded, or a simulated
      cloud the sensor made: :func:`rollout_region_errors`).

    Args:
        vertices: ``(T, N, 3)`` m. faces: ``(F, 3)`` int. labels: ``(N,)`` region per vertex.
        dense: ``T`` measured clouds ``(m_t, 3)`` m. n_regions: ``R`` (default ``labels.max() + 1``).
        gripper: ``(T, 3)`` m, the grasp point per frame (camera only; None = no robot mask).

    Raises:
        SoftsbiError: both ``min_z`` and ``camera`` given (a fit has one sensor model).
    """
    if min_z is not None and camera is not None:
        raise SoftsbiError("region_errors takes one sensor model: min_z (height cut) or camera, not both")
    R = n_regions or int(labels.max()) + 1
    pts = surface_points(vertices, faces)
    lab_all = labels if len(faces) == 0 else np.concatenate([labels, labels[faces[:, 0]]])
    out = np.full((len(vertices), R), np.nan)
    for t in range(len(vertices)):
        p_t, lab = pts[t], lab_all
        if min_z is not None:  # the simulated points the sensor sees, with their regions
            idx = sensor_indices(p_t, min_z)
            p_t, lab = p_t[idx], lab_all[idx]
        elif camera is not None:
            idx = np.flatnonzero(camera.seen(p_t, vertices[t], faces, None if gripper is None else gripper[t]))
            if not len(idx):  # nothing seen: the metric's fallback (camera_chamfer_per_frame)
                idx = sensor_indices(p_t, np.inf)
            p_t, lab = p_t[idx], lab_all[idx]
        m_t = sensor_view(np.asarray(dense[t], float), min_z)
        d_sr, _ = cKDTree(m_t).query(p_t)
        d_rs, idx = cKDTree(p_t).query(m_t)
        lr = lab[idx]
        for r in range(R):
            parts = [d_sr[lab == r].mean()] if (lab == r).any() else []
            if (lr == r).any():
                parts.append(d_rs[lr == r].mean())
            out[t, r] = np.mean(parts) if parts else np.nan
    return out


def run_sensor(run: RunView) -> VirtualDepthSensor | None:
    """The run's virtual depth sensor (its stored ``metric_camera``) for a ``--sensor camera`` fit, else None."""
    camera = run.config.get("metric_camera")
    return None if camera is None else sensor_from_json(camera)


def sensor_model(run: RunView) -> dict[str, Any]:
    """The run's sensor model as stored (what its metric used): ``kind`` (``"camera"``, ``"height"`` or
    ``"none"``: full clouds), ``min_z`` (m or None), ``frames`` (None = all) and ``camera`` (the virtual
    sensor's JSON or None). Two runs measure the same thing only when these are equal."""
    camera = run.config.get("metric_camera")
    kind = "camera" if camera is not None else ("height" if run.metric_min_z is not None else "none")
    return {"kind": kind, "min_z": run.metric_min_z, "frames": run.metric_frames, "camera": camera}


def rollout_region_errors(run: RunView, rollout: dict[str, Any], labels: np.ndarray, n_regions: int,
                          measured: Any, measured_rollout: dict[str, Any] | None = None) -> np.ndarray:
    """:func:`region_errors` ``(T, R)`` m of one posterior rollout under the run's own sensor model
    (its height cut :attr:`~softsbi.workflows.runs.RunView.metric_min_z`, or its virtual depth sensor),
    as :func:`~softsbi.workflows.stats.rollout_features` sees rollouts.

    Args:
        rollout: a job result with ``vertices (T, N, 3)``, ``faces``, ``gripper (T, 3)``.
        measured: ``T`` clouds ``(m_t, 3)`` m: the run's measurement (``run.dense``, used as recorded by a
            camera fit), or surface samples of another rollout standing in for it (``diagnose``'s null).
        measured_rollout: when ``measured`` are surface samples of a simulated rollout, that rollout (job
            result): a camera fit's sensor sees its mesh (its cloud per frame,
            :meth:`~softsbi.perception.depth_sensor.VirtualDepthSensor.observe_rollout`; the highest 10 % of
            ``measured[t]`` where it sees nothing), as the real sensor made the measurement. The height cut
            sees ``measured`` itself.
    """
    sensor = run_sensor(run)
    if sensor is None:
        return region_errors(rollout["vertices"], rollout["faces"], labels, measured, n_regions, run.metric_min_z)
    if measured_rollout is not None:
        mr = measured_rollout
        # seeded like the null's summaries of that rollout (rollout_features, seed 1000 + its sample)
        views = sensor.observe_rollout(mr["vertices"], mr["faces"], mr.get("gripper"),
                                       np.random.default_rng([1000 + int(mr.get("sample", 0)), 23]))
        measured = views_or_highest(views, measured)
    return region_errors(rollout["vertices"], rollout["faces"], labels, measured, n_regions, None, sensor,
                         rollout.get("gripper"))


def _grasp_words(scenario: Scenario) -> str:
    """Whose grasp the regions are ranked from (:func:`material_regions`: the gripper's, the first moving handle)."""
    handles = list(getattr(scenario, "handles", None) or [])
    moving = [h for h in handles if h.path is not None]
    return f"the grasp of handle '{moving[0].name}'" if len(handles) > 1 and moving else "the grasp"


def _sensor_words(min_z: float | None, frames: list[int] | None, table_z: float, T: int,
                  camera: bool = False) -> str:
    """The metric's sensor model in words, for the check's summary ("" when it sees everything)."""
    parts = []
    if camera:
        parts.append("simulated clouds made by the recording's virtual depth sensor")
    elif min_z is not None:
        parts.append(f"points within {(min_z - table_z) * 100:.1f} cm of the table unseen")
    if frames is not None and len(frames) < T:
        parts.append(f"frames {_ranges(frames)}")
    return f" under the fit's sensor model: {', '.join(parts)}" if parts else ""


def _ranges(idx: list[int]) -> str:
    """``[10, 11, 12, 20]`` -> ``"10-12, 20"``."""
    out, start = [], None
    s = sorted(int(i) for i in idx)
    for k, i in enumerate(s):
        start = i if start is None else start
        if k == len(s) - 1 or s[k + 1] != i + 1:
            out.append(f"{start}-{i}" if i > start else f"{i}")
            start = None
    return ", ".join(out)


def motion_phases(scenario: Scenario) -> list[dict[str, Any]]:
    """The phases of the motion, with the gripper's height: the moves between the keyframes of the scenario's
    gripper path (``options["keyframe_times"]``, a scenario file's keyframes: ``move 1``, ``move 2``, ... and
    ``after the last move``), else three phases of equal duration (``early``, ``middle``, ``late``)."""
    T = scenario.n_frames
    times = np.asarray(scenario.times, float)
    kt = sorted(float(t) for t in (scenario.options or {}).get("keyframe_times") or [])
    if len(kt) >= 2:
        edges = np.searchsorted(times, np.array(kt[1:-1]) - 1e-9)  # frame k belongs to the move it starts in
        cuts = [0, *[int(e) for e in edges], int(np.searchsorted(times, kt[-1] + 1e-9)), T]
        names = [f"move {k + 1}" for k in range(len(kt) - 1)] + ["after the last move"]
    else:
        cuts = list(np.linspace(0, T, 4).round().astype(int))
        names = ["early", "middle", "late"]
    out = []
    for k, name in enumerate(names):
        idx = list(range(cuts[k], cuts[k + 1]))
        if not idx:
            continue
        h = scenario.gripper[idx, 2] - scenario.table_z
        out.append({"phase": name, "frames": [idx[0], idx[-1]],
                    "t_s": [float(scenario.times[idx[0]]), float(scenario.times[idx[-1]])],
                    "gripper_height_m": [float(h.min()), float(h.max())]})
    return out


# ----------------------------------------------------------------------------------------
# check


def check_run(run_dir: str | Path, n_eval: int = N_NULL, workers: int | None = None, plot: bool = True,
              seed: int = 0, alpha: float = ALPHA, max_null: int = MAX_NULL,
              pool: PosteriorPredictive | None = None, effects: Sequence[str] | None = None) -> dict[str, Any]:
    """Posterior predictive check of a finished fit; writes ``check.json`` and ``check.png``.

    Args:
        n_eval: posterior rollouts for the error maps and the start of the test's null.
        alpha: level of the misspecification verdict (``p <= alpha``).
        max_null: cap of the adaptive extension of the null (:class:`PosteriorPredictive`): when
            ``1 / (n_eval + 1) > alpha`` and the first stage is promising (the measurement beyond all
            ``n_eval`` rollouts, or ``p <= EXTEND_P``: :func:`~softsbi.workflows.stats.resolution_needed`),
            the test simulates up to ``max_null`` posterior-predictive rollouts before deciding.
        pool: already simulated posterior-predictive rollouts of this run (``diagnose`` shares its own).
        effects: the directional test's family (default: every installed effect the run's backend can apply
            and the run lacks, generic force terms included, as ``diagnose``'s default candidates).

    Returns:
        dict with ``chamfer_per_frame_m`` (mean and 5/95% band over posterior rollouts), ``regions`` ranked by their
        distance from ``regions_from`` (the first moving handle's grasp, named when the scenario has several
        handles), ``phases`` (:func:`motion_phases`; ``phases_from`` says how they were cut),
        ``region_error_m`` (T x R mean under the fit's sensor model, :func:`rollout_region_errors`; 0 where
        no rollout's region is seen), ``region_compared`` (T x R bool: False where it is 0 for that
        reason, not for a perfect fit), ``regions``, ``phases`` (mean error per phase), ``metric_sensor``
        (``"camera"``, ``"height"`` or ``"none"``, :func:`sensor_model`),
        ``worst_frames``, ``worst_regions``, ``energy`` (the same rollouts'
        :func:`~softsbi.workflows.stats.energy_score`; None for an image fit), ``misspecification`` (the omnibus and the directional test,
        each a Monte-Carlo p-value, their Bonferroni-combined ``p_value`` with ``p_text`` stating its
        resolution, ``misspecified``, ``rule``), ``posterior_at_bounds`` (the fit's parameters whose posterior
        presses against a prior bound, :func:`~softsbi.inference.contraction.bound_pressure`, from its
        ``report.json``; the summary then says so) and a ``summary`` sentence. The misspecification verdict is
        :func:`~softsbi.workflows.screening.misspecification_verdict`, the same test ``diagnose`` uses as its
        first verdict; its directional part simulates the screening's finite differences (one simulation per
        nominal and effect parameter, about 40 for mujoco-flex's installed effects).

    Raises:
        SoftsbiError: ``n_eval`` < :data:`MIN_ROLLOUTS` or fewer posterior rollouts succeeded (before / after
            simulating); RunDirError: the run directory cannot be written (before simulating).
    """
    t0 = time.perf_counter()
    if not isinstance(n_eval, int) or n_eval < MIN_ROLLOUTS:
        raise SoftsbiError(f"--n-eval {n_eval}: the check needs at least {MIN_ROLLOUTS} posterior rollouts; give "
                           f"--n-eval {MIN_ROLLOUTS} or more (default {N_NULL})")
    run = load_run(run_dir, n_eval, seed)
    check_out_dir(run_dir, "run directory", "check writes check.json and check.png into it: copy the run "
                                            "directory to a writable place and check the copy")
    pool = pool or PosteriorPredictive(run, workers, seed)
    pool.ensure(n_eval)
    # the fit's own job, samples and seeds: the mean Chamfer equals report.json's
    # chamfer_posterior_m when all of the fit's evaluation samples are used
    ok = [r for r in pool.rollouts if r["sample"] < n_eval]
    if len(ok) < MIN_ROLLOUTS:
        raise SoftsbiError(f"only {len(ok)} of {n_eval} posterior rollouts succeeded, and the check needs "
                           f"{MIN_ROLLOUTS}; cannot check the fit")
    dense = run.dense
    T = len(dense)
    min_z, frames = run.metric_min_z, run.metric_frames
    in_fit = np.zeros(T, bool)
    in_fit[slice(None) if frames is None else frames] = True
    ch = np.array([r["chamfer"] for r in ok])
    ch1 = np.array([r["chamfer_one_sided"] if r.get("chamfer_one_sided") is not None else np.full(T, np.nan)
                    for r in ok])
    stats = chamfer_stats(ch, np.full(len(ok), STATUS_OK), frames, ch1)
    labels, names = material_regions(ok[0]["vertices"][0], run.scenario.gripper[0])
    reg = np.zeros((len(ok), T, len(names)))
    for k, r in enumerate(ok):
        reg[k] = rollout_region_errors(run, r, labels, len(names), dense)
    mis = misspecification_verdict(pool, candidate_effects(run, effects), alpha, max_null)[0]
    warnings.filterwarnings("ignore", "Mean of empty slice", RuntimeWarning)  # regions a small mesh lacks
    reg_mean = np.nanmean(reg, axis=0)
    phases = motion_phases(run.scenario)
    mean_t = ch.mean(0)
    mean_t1 = ch1.mean(0)
    for ph in phases:
        a, b = ph["frames"]
        ph["chamfer_m"] = float(mean_t[a:b + 1].mean())
        ph["chamfer_one_sided_m"] = float(mean_t1[a:b + 1].mean())
        # frames the fit's sensor model does not use (e.g. the cloth still flat) are reported, not blamed
        ph["in_fit"] = bool(in_fit[a:b + 1].any())
        ph["worst_region"] = names[int(np.nanargmax(np.nan_to_num(np.nanmean(reg_mean[a:b + 1], axis=0),
                                                                  nan=-np.inf)))]
    fit_idx = np.nonzero(in_fit)[0]
    worst_frames = [int(i) for i in fit_idx[np.argsort(mean_t[fit_idx])[::-1][:3]]]
    reg_avg = np.nanmean(reg_mean[in_fit], axis=0)
    # regions a small mesh lacks (or the sensor never sees) are NaN: never the worst
    worst_regions = [names[int(i)] for i in np.argsort(np.nan_to_num(reg_avg, nan=-np.inf))[::-1][:2]]
    worst_phase = max((p for p in phases if p["in_fit"]), key=lambda p: p["chamfer_m"])
    verdict = (f"the measurement is NOT explained by the model ({mis['p_text']} <= {alpha:g})" if mis["misspecified"]
               else f"no evidence of misspecification ({mis['p_text']} > {alpha:g})")
    model = sensor_model(run)
    sensor = _sensor_words(min_z, frames, run.scenario.table_z, T, model["kind"] == "camera")
    one = stats.get("one_sided_mean_m")
    summary = (f"Posterior rollouts miss the measurement by {stats['mean_m'] * 100:.2f} cm on average (Chamfer"
               f"{sensor}" + (f"; measured -> simulated {one * 100:.2f} cm" if one is not None and np.isfinite(one)
                              else "") + "); "
               f"worst in the {worst_phase['phase']} phase (t {worst_phase['t_s'][0]:.2f}-"
               f"{worst_phase['t_s'][1]:.2f} s, {worst_phase['chamfer_m'] * 100:.2f} cm) and in region "
               f"{worst_regions[0]}; {verdict}.")
    # a posterior piled against a prior bound: too narrow a prior, or the model compensating for what it lacks
    pressed = list((run.report or {}).get("posterior_at_bounds") or [])
    if pressed:
        summary += " The fit's posterior: " + " ".join(bound_sentence(e) + "." for e in pressed)
    out = {"run": str(run.path), "n_rollouts": len(ok), "failed_rollouts": n_eval - len(ok),
           "times_s": run.scenario.times.tolist(),
           "chamfer_per_frame_m": {"mean": mean_t.tolist(), "q05": np.quantile(ch, 0.05, 0).tolist(),
                                   "q95": np.quantile(ch, 0.95, 0).tolist()},
           "chamfer_one_sided_per_frame_m": {"mean": mean_t1.tolist(), "q05": np.quantile(ch1, 0.05, 0).tolist(),
                                             "q95": np.quantile(ch1, 0.95, 0).tolist()},
           "chamfer_mean_m": stats["mean_m"], "chamfer_one_sided_mean_m": one,
           "metric_min_z_m": min_z, "metric_frames": frames, "metric_sensor": model["kind"],
           "regions": names, "regions_from": _grasp_words(run.scenario),
           "phases_from": ("the scenario's keyframes" if (run.scenario.options or {}).get("keyframe_times")
                           else "equal thirds of the motion"),
           "region_error_m": np.nan_to_num(reg_mean).tolist(),
           "region_compared": np.isfinite(reg_mean).tolist(),
           "region_mean_m": dict(zip(names, np.nan_to_num(reg_avg).tolist())),
           "phases": phases, "worst_frames": worst_frames, "worst_regions": worst_regions,
           "misspecification": mis, "energy": energy_score(pool, n_eval), "summary": summary,
           "posterior_at_bounds": pressed, "seconds": time.perf_counter() - t0}
    run_dir = Path(run_dir)
    (run_dir / "check.json").write_text(json.dumps(out, indent=2))
    if plot:
        plot_check(run_dir / "check.png", out, ch)
    return out


