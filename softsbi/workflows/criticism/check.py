"""Posterior predictive check (Gelman et al., *Bayesian Data Analysis*, ch. 6).

:func:`check_run` re-simulates a finished fit at its own posterior samples (the fit's evaluation
samples and seeds, through :func:`~softsbi.workflows.fit.jobs.simulate_job`) and compares them with
the measurement: Chamfer error per frame, per region of the object and per phase of the motion,
and a misspecification test (is the measurement's summary vector inside the distribution of
posterior-predictive summaries, in any direction or along an installed effect's?) with a
simulation-based p-value.

Every distance sees the simulated and the measured clouds through the fit's own sensor model
(:func:`~softsbi.workflows.fit.run.metric_sensor`: the height cut ``min_height`` above the table, or for
``--sensor camera`` the recording's virtual depth sensor, and the headline averages the fit's
``frames``), so the check's mean Chamfer is the fit's ``chamfer_posterior_m`` and neither it nor the
per-region errors blame what the sensor cannot see. Both the bidirectional and the
one-sided (measured -> simulated) Chamfer are reported per frame.

Summaries are per-frame statistics of the point cloud (centroid, spread, height quantiles,
horizontal extent), which both simulated surfaces and real partial clouds have.
"""
from __future__ import annotations

import hashlib
import time
import warnings
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
from scipy.spatial import cKDTree

from softsbi.core.errors import SoftsbiError
from softsbi.core.metrics import offset_direction
from softsbi.core.results import (Band, CheckResult, Phase, ResidualShape, ResultDamaged, check_result_path, from_json,
                                  read_json, write_result)
from softsbi.core.types import STATUS_OK, Scenario
from softsbi.core.seeds import SENSOR_VIEW_STREAM, surface_seed
from softsbi.perception.depth_sensor import VirtualDepthSensor, sensor_from_json, views_or_highest
from softsbi.perception.pointcloud import sensor_indices, sensor_view
from softsbi.report import plot_check
from softsbi.scenarios.spec import keyframe_times
from softsbi.core import defaults
from softsbi.workflows import pools
from softsbi.core.defaults import CheckSettings
from softsbi.workflows.criticism.check_null import run_check_null
from softsbi.workflows.fit.report_file import chamfer_stats
from softsbi.workflows.fit.jobs import JobResult
from softsbi.workflows.lock import check_out_dir
from softsbi.workflows.fit.runs import RunView, load_run
from softsbi.workflows.criticism.screening import candidate_effects, check_resolution, misspecification_verdict
from softsbi.workflows.criticism.stats import (
    N_NULL,
    PosteriorPredictive,
    energy_score,
    posterior_mean_chamfer,
    run_features,
    run_frames,
    sampled_points,
)
from softsbi.workflows.criticism.statistics import FEATURE_NAMES, summary_floor

#: posterior rollouts the check needs at least (its error maps and the first stage of its test's null)
MIN_ROLLOUTS = defaults.MIN_ROLLOUTS


def surface_points(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Deterministic surface points ``(T, N + F, 3)``: vertices and face centroids."""
    if len(faces) == 0:
        return vertices
    return np.concatenate([vertices, vertices[:, faces].mean(2)], axis=1)



#: an object whose rest pose is narrower than this fraction of its length (second to first principal extent) is a
#: line, a rope: its regions are segments along it
LINE_WIDTH = 0.01


def material_regions(vertices0: np.ndarray, grasp: np.ndarray, n_side: int = 3) -> tuple[np.ndarray, list[str]]:
    """Partition the object into ``n_side x n_side`` regions in its rest configuration.

    A rope (a rest pose without width: its second principal extent under :data:`LINE_WIDTH` of its first) is cut
    instead into ``n_side**2`` segments along it (at most one per vertex), each with the same number of vertices,
    numbered from its grasped end ("R1 (grasped end)" ... "R9 (far end)").

    Args:
        vertices0: ``(N, 3)`` vertex positions at frame 0 (material coordinates).
        grasp: ``(3,)`` gripper position at frame 0.

    Returns:
        ``labels (N,)`` int region of each vertex, and region names ordered by the distance of
        the region's centre from the grasp point ("R1 at the grasp" ... "R9 farthest").
    """
    v = vertices0 - vertices0.mean(0)
    _, s, vt = np.linalg.svd(v, full_matrices=False)
    uv = v @ vt[:2].T
    if len(s) < 2 or s[1] <= LINE_WIDTH * s[0]:  # a rope: segments along it, from the end nearer the grasp
        along = uv[:, 0]
        ends = np.linalg.norm(vertices0[[np.argmin(along), np.argmax(along)]] - grasp, axis=1)
        along = along if ends[0] <= ends[1] else -along
        R = min(n_side * n_side, len(v))
        labels = np.argsort(np.argsort(along, kind="stable")) * R // len(v)
        return labels, [f"R{r + 1}" + (" (grasped end)" if r == 0 else " (far end)" if r == R - 1 else "")
                        for r in range(R)]
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
    camera = run.record.metric_camera
    return None if camera is None else sensor_from_json(camera)


def sensor_model(run: RunView) -> dict[str, Any]:
    """The run's sensor model as stored (what its metric used): ``kind`` (``"camera"``, ``"height"`` or
    ``"none"``: full clouds), ``min_z`` (m or None), ``frames`` (None = all) and ``camera`` (the virtual
    sensor's JSON or None). Two runs measure the same thing only when these are equal."""
    camera = run.record.metric_camera
    kind = "camera" if camera is not None else ("height" if run.metric_min_z is not None else "none")
    return {"kind": kind, "min_z": run.metric_min_z, "frames": run.metric_frames, "camera": camera}


def rollout_region_errors(run: RunView, rollout: JobResult, labels: np.ndarray, n_regions: int,
                          measured: Any, measured_rollout: JobResult | None = None) -> np.ndarray:
    """:func:`region_errors` ``(T, R)`` m of one posterior rollout under the run's own sensor model
    (its height cut :attr:`~softsbi.workflows.fit.runs.RunView.metric_min_z`, or its virtual depth sensor),
    as :func:`~softsbi.workflows.criticism.stats.rollout_features` sees rollouts.

    Args:
        rollout: a job result (:class:`~softsbi.workflows.fit.jobs.JobResult`) with ``vertices (T, N, 3)``,
            ``faces``, ``gripper (T, 3)``.
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
        return region_errors(rollout.vertices, rollout.faces, labels, measured, n_regions, run.metric_min_z)
    if measured_rollout is not None:
        mr = measured_rollout
        # seeded like the null's summaries of that rollout (rollout_features, surface_seed of its sample)
        sample = 0 if mr.sample is None else mr.sample
        views = sensor.observe_rollout(mr.vertices, mr.faces, mr.gripper,
                                       np.random.default_rng([surface_seed(sample), SENSOR_VIEW_STREAM]))
        measured = views_or_highest(views, measured)
    return region_errors(rollout.vertices, rollout.faces, labels, measured, n_regions, None, sensor,
                         rollout.gripper)


def grasp_handle(scenario: Scenario) -> str | None:
    """The handle whose grasp the regions are ranked from (:func:`material_regions`: the first moving handle) when the
    scenario has several handles; None with one grasp."""
    handles = list(getattr(scenario, "handles", None) or [])
    moving = [h for h in handles if h.path is not None]
    return moving[0].name if len(handles) > 1 and moving else None


def motion_phases(scenario: Scenario) -> list[dict[str, Any]]:
    """The phases of the motion, with the gripper's height: the moves between the keyframes of the scenario's
    gripper path (``options["keyframe_times"]``, a scenario file's keyframes: ``move 1``, ``move 2``, ... and
    ``after the last move``), else three phases of equal duration (``early``, ``middle``, ``late``)."""
    T = scenario.n_frames
    times = np.asarray(scenario.times, float)
    kt = keyframe_times(scenario)
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


def residual_shape(run: RunView, pool: PosteriorPredictive, n: int = N_NULL, n_regions: int = 20,
                   phase_chamfer: dict[str, float] | None = None) -> ResidualShape:
    """When, where and in which direction the measurement leaves the posterior predictive distribution.

    - frames: per frame, the mean squared standardised deviation of the measurement's summaries from the
      posterior-predictive rollouts, against the same statistic of each rollout (leave-one-out); a frame is
      flagged when the measurement exceeds the rollouts' 95% quantile.
    - direction: the measured centroid minus the rollouts' mean centroid (cm), over the flagged frames.
    - regions: per region of the cloth (:func:`~softsbi.workflows.criticism.check.material_regions`), the nearest-neighbour
      error of the measurement to the rollouts minus that of another rollout to them (cm; the first
      ``n_regions`` rollouts): the error the nominal model's own spread does not produce.

    Uses the first ``n`` successful rollouts of ``pool`` (the null's first stage), so the shape does not depend on
    whether the null was extended. ``phase_chamfer`` (phase name -> m, every phase of :func:`motion_phases`): the
    posterior-predictive Chamfer of each phase as ``check``'s table shows it, stored with the phase so that the words
    name the table's worst phase (None: no Chamfer stored with the phases).
    """
    fit_frames = np.array(run_frames(run))
    T = len(fit_frames)
    F = pool.features[:n].reshape(min(n, len(pool.rollouts)), T, -1)
    f_obs = run_features(run, run.dense).reshape(T, -1)
    floor = summary_floor(F.shape[-1])
    mu, sd = F.mean(0), np.maximum(F.std(0), floor)
    z_obs = (((f_obs - mu) / sd) ** 2).mean(-1)
    z_null = np.array([(((F[i] - o.mean(0)) / np.maximum(o.std(0), floor)) ** 2).mean(-1)
                       for i, o in ((i, np.delete(F, i, axis=0)) for i in range(len(F)))])
    flagged = z_obs > np.quantile(z_null, 0.95, axis=0)
    times = run.scenario.times
    spans, t = [], 0
    while t < T:  # runs of flagged frames that are consecutive in the recording (fit frames may skip some)
        if not flagged[t]:
            t += 1
            continue
        e = t
        while e + 1 < T and flagged[e + 1] and fit_frames[e + 1] == fit_frames[e] + 1:
            e += 1
        spans.append((int(fit_frames[t]), int(fit_frames[e]), float(times[fit_frames[t]]), float(times[fit_frames[e]])))
        t = e + 1
    phases = []
    for ph in motion_phases(run.scenario):
        inside = (fit_frames >= ph["frames"][0]) & (fit_frames <= ph["frames"][1])
        phases.append({"phase": ph["phase"], "frames": list(ph["frames"]),
                       "fraction_flagged": float(flagged[inside].mean()) if inside.any() else None,
                       "chamfer_m": None if phase_chamfer is None else phase_chamfer[ph["phase"]]})
    sel = flagged if flagged.any() else np.ones(T, bool)
    off = (f_obs[sel, :3] - mu[sel, :3]).mean(0) * 100
    zf = (((f_obs[sel] - mu[sel]) / sd[sel]) ** 2).mean(0)
    ro = pool.rollouts[:max(2, min(n, n_regions))]
    labels, names = material_regions(ro[0].vertices[0], run.scenario.gripper[0])
    exc = []
    for k, r in enumerate(ro):
        j = (k + 1) % len(ro)
        other = sampled_points(ro[j].vertices, ro[j].faces, run.dense.shape[1], surface_seed(ro[j].sample))
        exc.append(rollout_region_errors(run, r, labels, len(names), run.dense)
                   - rollout_region_errors(run, r, labels, len(names), other, ro[j]))
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        per_region = np.nanmean(np.array(exc)[:, fit_frames[sel]], axis=(0, 1)) * 100
    per_region = np.nan_to_num(per_region, nan=-np.inf)
    return ResidualShape(
        frames_flagged=tuple(int(fit_frames[i]) for i in np.flatnonzero(flagged)),
        frame_spans=tuple(spans),
        phases=tuple(phases),
        centroid_offset_cm=tuple(float(v) for v in off),
        direction=offset_direction(off),
        worst_summary=FEATURE_NAMES[int(np.argmax(zf))],
        region_excess_cm={n: (float(v) if np.isfinite(v) else None) for n, v in zip(names, per_region)},
        worst_regions=tuple(names[int(i)] for i in np.argsort(per_region)[::-1][:2]),
    )


# ----------------------------------------------------------------------------------------
# check


def loaded(run: str | Path | RunView, pool: PosteriorPredictive | None = None, seed: int = 0) -> RunView:
    """The run a command works on, loaded once: ``run`` itself when loaded already, else ``pool``'s when it is the
    same run directory, else :func:`~softsbi.workflows.fit.runs.load_run` with every evaluation sample (so that the
    posterior-predictive null is built on it without loading it again)."""
    if isinstance(run, RunView):
        return run
    if pool is not None and Path(pool.run.path).resolve() == Path(run).resolve():
        return pool.run
    return load_run(run, None, seed)


def result_key(run: RunView, **settings: Any) -> dict[str, Any]:
    """What determines a check or a diagnosis of ``run``: a digest of the fit's ``report.json`` (it changes
    whenever the fit does) and the command's ``settings``. A stored result is reused only under the same key."""
    digest = hashlib.sha256((run.path / "report.json").read_bytes()).hexdigest()[:16]
    return {"report": digest, **{k: (list(v) if isinstance(v, tuple) else v) for k, v in settings.items()}}


def stored_result(path: Path, cls: type, key: dict[str, Any], say: Callable[[str], None] | None = None) -> Any:
    """The result stored at ``path`` if it was computed under ``key`` (:func:`result_key`), else None: no file,
    other settings, or a file that cannot be used (damaged, or from another softsbi), which is told to ``say`` in
    one line (the caller computes it again and replaces the file)."""
    if not path.is_file():
        return None
    try:
        data = read_json(path, "", ("key",))
        return from_json(cls, data) if data["key"] == key else None  # read_json requires the key
    except ResultDamaged as exc:
        problem = exc.problem
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        problem = f"not a {cls.__name__}: {exc}"
    (say or (lambda _: None))(f"{path} cannot be used ({problem}): computing it again")
    return None


def reused(path: Path) -> str:
    """The line that says a stored result was reused rather than written."""
    return f"reused {path} (computed before for this fit and these settings; --recompute computes it again)"


@pools.shared_executors()
def check_run(run_dir: str | Path | RunView, settings: CheckSettings | None = None, *, plot: bool = True,
              pool: PosteriorPredictive | None = None, effects: Sequence[str] | None = None,
              recompute: bool = False, message: Callable[[str], None] | None = None,
              out_dir: str | Path | None = None) -> CheckResult:
    """Posterior predictive check of a finished fit; writes ``check.json`` and ``check.png``.

    Args:
        run_dir: the run directory, or the run already loaded (:func:`~softsbi.workflows.fit.runs.load_run`), which is
            then not loaded again (nor when ``pool`` holds it).
        settings: the posterior rollouts of the error maps and the start of the test's null (``n_eval``), the cap of
            its adaptive extension (``max_null``, :func:`~softsbi.workflows.criticism.statistics.resolution_needed`), the
            level of the verdict (``p <= alpha``), workers and seed (:class:`~softsbi.core.defaults.CheckSettings`;
            None: the defaults).
        pool: already simulated posterior-predictive rollouts of this run (``diagnose`` shares its own).
        effects: the directional test's family (default: every installed effect the run's backend can apply
            and the run lacks, generic force terms included, as ``diagnose``'s default candidates).
        recompute: simulate again even when ``check.json`` holds the result for the same fit and settings.
        message: told in one line what was written, or that the stored result was reused (or could not be).
        out_dir: the folder ``check.json`` and ``check.png`` are written to (default: the run directory, which is
            then never written; ``diagnose --out``). A result stored there is reused, or else the run directory's own
            when it holds the same fit and settings.

    Returns:
        the :class:`~softsbi.core.results.CheckResult`: Chamfer per frame with its band, error per region (ranked
        from ``grasp_handle``, the first moving handle's grasp) and phase (``phases_at_keyframes``: how they were cut)
        under the fit's sensor model, the joint misspecification test
        (:func:`~softsbi.workflows.criticism.screening.misspecification_verdict`, the test ``diagnose`` detects with) and the
        posterior predictive's Chamfer energy score, the posterior-mean rollout's Chamfer and, when the test rejects, the
        residual's shape (:func:`residual_shape`).

    Raises:
        SoftsbiError: a null cap that cannot resolve ``alpha`` (before simulating); fewer posterior rollouts
            succeeded; RunDirError, ResultUnwritable: the run directory or its
            check.json cannot be written (before simulating; ResultUnwritable also when the disk fills up at the end).
    """
    t0 = time.perf_counter()
    s = settings or CheckSettings()
    n_eval, workers, seed, alpha, max_null = s.n_eval, s.workers, s.seed, s.alpha, s.max_null
    check_resolution(alpha, max_null)
    run = loaded(run_dir, pool, seed)
    cands = candidate_effects(run, effects, message)
    null = run_check_null(run, n_eval, message, [c.name for c in cands])
    if null is not None and null.directional is None and cands:
        (message or (lambda _: None))(
            f"the check is the omnibus test alone: its task's {len(null.statistics)} replicates were not screened "
            f"(a candidate model's, `task train --refit-null`), so they calibrate that test and no directional one")
        cands = []
    key = result_key(run, n_eval=n_eval, seed=seed, alpha=alpha, max_null=max_null,
                     family=sorted(c.name for c in cands), replicates=0 if null is None else len(null.statistics))
    say = message or (lambda _: None)
    out = run.path if out_dir is None else Path(out_dir)
    writable = (lambda: check_out_dir(out)) if out_dir is not None else (lambda: check_out_dir(
        run.path, "run directory", "check writes check.json and check.png into it: copy the run directory to a "
                                   "writable place and check the copy"))
    json_path = check_result_path(out / "check.json")
    if plot:  # a folder in the figure's place: refused before any work, as check.json is
        check_result_path(out / "check.png")
    for path in [] if recompute else [json_path] + ([run.path / "check.json"] if out != run.path else []):
        stored = stored_result(path, CheckResult, key, say)
        if stored is not None:
            if plot and not (path.parent / "check.png").exists():
                writable()
                plot_check(out / "check.png", stored)
                say(f"wrote {out / 'check.png'}")
            say(reused(path))
            return stored
    writable()
    pool = (pool or PosteriorPredictive(run, workers, seed)).ensure(n_eval)
    # the fit's own job, samples and seeds: the mean Chamfer equals report.json's chamfer_posterior_m
    ok = [r for r in pool.rollouts if r.sample < n_eval]
    if len(ok) < MIN_ROLLOUTS:
        raise SoftsbiError(f"only {len(ok)} of {n_eval} posterior rollouts succeeded, and the check needs "
                           f"{MIN_ROLLOUTS}; look at why the simulations fail (report.json)")
    dense = run.dense
    T = len(dense)
    frames = run.metric_frames
    in_fit = np.zeros(T, bool)
    in_fit[slice(None) if frames is None else frames] = True
    ch = np.array([r.chamfer for r in ok])
    ch1 = np.array([r.chamfer_one_sided if r.chamfer_one_sided is not None else np.full(T, np.nan) for r in ok])
    stats = chamfer_stats(ch, np.full(len(ok), STATUS_OK), frames, ch1)
    labels, names = material_regions(ok[0].vertices[0], run.scenario.gripper[0])
    reg = np.array([rollout_region_errors(run, r, labels, len(names), dense) for r in ok])
    test, _, ranking = misspecification_verdict(pool, cands, alpha, max_null, null=null)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # regions a small mesh lacks, or the sensor never sees
        reg_mean = np.nanmean(reg, axis=0)
        reg_avg = np.nanmean(reg_mean[in_fit], axis=0)
    mean_t, mean_t1 = ch.mean(0), ch1.mean(0)
    phases = []
    for ph in motion_phases(run.scenario):
        a, b = ph["frames"]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            worst = int(np.nanargmax(np.nan_to_num(np.nanmean(reg_mean[a:b + 1], axis=0), nan=-np.inf)))
        # frames the fit's sensor model does not use (e.g. the cloth still flat) are reported, not blamed
        phases.append(
            Phase(
                phase=ph["phase"],
                frames=(a, b),
                t_s=tuple(ph["t_s"]),
                chamfer_m=float(mean_t[a : b + 1].mean()),
                chamfer_one_sided_m=float(mean_t1[a : b + 1].mean()),
                in_fit=bool(in_fit[a : b + 1].any()),
                worst_region=names[worst],
            )
        )
    fit_idx = np.nonzero(in_fit)[0]
    one = stats.one_sided_mean_m  # chamfer_stats of one-sided Chamfers: always there

    def band(c: np.ndarray) -> Band:
        return Band(mean=tuple(c.mean(0).tolist()), q05=tuple(np.quantile(c, 0.05, 0).tolist()),
                    q95=tuple(np.quantile(c, 0.95, 0).tolist()))

    one = float(one) if one is not None and np.isfinite(one) else None
    worst_frames = tuple(int(i) for i in fit_idx[np.argsort(mean_t[fit_idx])[::-1][:3]])
    worst_regions = tuple(names[int(i)] for i in np.argsort(np.nan_to_num(reg_avg, nan=-np.inf))[::-1][:2])
    residual = (residual_shape(run, pool, n_eval, phase_chamfer={p.phase: p.chamfer_m for p in phases})
                if test.misspecified else None)
    result = CheckResult(
        run=str(run.path), n_rollouts=len(ok), failed_rollouts=n_eval - len(ok),
        times_s=tuple(run.scenario.times.tolist()), chamfer=band(ch), chamfer_one_sided=band(ch1),
        chamfer_mean_m=float(stats.mean_m), chamfer_one_sided_mean_m=one, metric_min_z_m=run.metric_min_z,
        metric_frames=None if frames is None else tuple(frames), metric_sensor=sensor_model(run)["kind"],
        table_z_m=float(run.scenario.table_z), regions=tuple(names),
        region_error_m=tuple(map(tuple, np.nan_to_num(reg_mean).tolist())),
        region_compared=tuple(map(tuple, np.isfinite(reg_mean).tolist())),
        region_mean_m=dict(zip(names, np.nan_to_num(reg_avg).tolist())), phases=tuple(phases),
        worst_frames=worst_frames, worst_regions=worst_regions, test=test, ranking=ranking,
        energy=energy_score(pool, n_eval), posterior_mean=posterior_mean_chamfer(run, workers=workers),
        residual=residual, posterior_at_bounds=tuple(b.to_json() for b in run.report.posterior_at_bounds), key=key,
        seconds=time.perf_counter() - t0, grasp_handle=grasp_handle(run.scenario),
        phases_at_keyframes=bool(keyframe_times(run.scenario)))
    out.mkdir(parents=True, exist_ok=True)
    write_result(json_path, result)
    if plot:
        plot_check(out / "check.png", result)
    say(f"wrote {json_path}" + (f" and {out / 'check.png'}" if plot else ""))
    return result
