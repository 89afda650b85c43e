"""The posterior predictive of a run and what ``check`` and ``diagnose`` compute on it, with the pure statistics of
:mod:`~softsbi.workflows.criticism.statistics` (Monte-Carlo p-values, max-T, the misspecification test, energy scores).

- :class:`PosteriorPredictive`: the posterior-predictive rollouts of a run, the null of both tests: the fit's own
  evaluation samples with their seeds first, then further posterior draws, simulated on demand
  (:meth:`PosteriorPredictive.ensure`), with their summaries (:func:`rollout_features`, computed in the simulation
  jobs: :func:`run_summarising`).
- :func:`energy_score`: the Chamfer energy score of a run's posterior predictive; :func:`posterior_mean_chamfer`:
  the posterior-mean rollout's Chamfer.
"""
from __future__ import annotations

from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from softsbi.core.results import EnergyScore
from softsbi.core.defaults import ALPHA  # noqa: F401 (re-exported)
from softsbi.core.seeds import EXTRA_ROLLOUT_SEED, SENSOR_VIEW_STREAM, surface_seed
from softsbi.perception.depth_sensor import sensor_from_json, views_or_highest
from softsbi.perception.pointcloud import (combined_min_z, effect_views, rollout_min_z, sample_surface,
                                           sensor_chamfer_per_frame)
from softsbi.core.defaults import MAX_NULL, MIN_ROLLOUTS, N_NULL  # noqa: F401 - null sizes, re-exported
from softsbi.workflows.criticism.statistics import trajectory_features
from softsbi.workflows.fit.jobs import JobItem, JobResult, SimContext, run_jobs
from softsbi.workflows.fit.runs import RunView, load_run









def run_features(run: "RunView", clouds: Sequence[np.ndarray]) -> np.ndarray:
    """``(T' * 14,)`` summaries of ``clouds`` under the run's own sensor model: the metric's visibility
    threshold (:attr:`RunView.metric_min_z`) and frames (:attr:`RunView.metric_frames`, ``T'`` of them).

    The misspecification test and the screening compare the measurement with simulations as the fit
    compared them: a real depth cloud lacks the cloth lying flat on the table, so summaries
    of full simulated clouds would reject every real recording for the sensor's sake.
    """
    return trajectory_features(clouds, run.metric_min_z, run.metric_frames)


def rollout_features(run: "RunView", rollout: JobResult, seed: int) -> np.ndarray:
    """``(T' * 14,)`` summaries of one simulated rollout (a job result with ``vertices (T, N, 3)``,
    ``faces``, ``gripper``) as the run's sensor model sees it (:func:`run_features`): area-weighted surface
    samples, as many per frame as the measurement's dense clouds, drawn with ``seed`` (common random
    numbers), seen through the visibility threshold; or, for a fit through the virtual depth sensor
    (``FitConfig.sensor == "camera"``), that sensor's clouds of the rollout."""
    return sensor_features(rollout, seed, run.dense.shape[1], run.metric_min_z, run.metric_frames,
                           run.record.metric_camera)


def sensor_features(rollout: JobResult, seed: int, n_dense: int, min_z: float | None,
                    frames: Sequence[int] | None, camera: dict[str, Any] | None) -> np.ndarray:
    """:func:`rollout_features` under a sensor model given by its settings (a fit's ``metric_*``, ``n_dense``
    points per frame) rather than by a run: what a task sees before any run of it exists."""
    if camera is not None:
        clouds = sensor_from_json(camera).observe_rollout(rollout.vertices, rollout.faces, rollout.gripper,
                                        np.random.default_rng([seed, SENSOR_VIEW_STREAM]))
        return trajectory_features(clouds, None, frames)
    clouds = effect_views(sampled_points(rollout.vertices, rollout.faces, n_dense, seed), rollout)
    # a sensor effect's threshold on the rollout (table-unseen) adds to the run's own; its arm mask hides more
    return trajectory_features(clouds, combined_min_z(min_z, rollout_min_z(rollout)), frames)


def summarising(ctx: SimContext, n_dense: int, min_z: float | None, frames: Sequence[int] | None,
                camera: dict[str, Any] | None) -> SimContext:
    """``ctx`` whose jobs compute each rollout's :func:`sensor_features` (``n_dense`` points per frame, the sensor
    model ``min_z``, ``frames``, ``camera``) in the worker, for the items with a ``summary_seed``
    (:class:`~softsbi.workflows.fit.jobs.JobItem`): the main process reads them from the results' ``features``
    instead of sampling surfaces and summarising every rollout itself."""
    return replace(ctx, summarise=partial(sensor_features, n_dense=int(n_dense), min_z=min_z,
                                          frames=None if frames is None else list(frames), camera=camera))


def run_summarising(run: "RunView", keep_rollout: bool = True) -> SimContext:
    """The run's own job context (:meth:`~softsbi.workflows.fit.runs.RunView.sim_context`) computing each rollout's
    :func:`rollout_features` in the worker (:func:`summarising`)."""
    return summarising(run.sim_context(keep_rollout=keep_rollout), run.dense.shape[1], run.metric_min_z,
                       run.metric_frames, run.record.metric_camera)


def features_of(run: "RunView", result: JobResult, seed: int) -> np.ndarray:
    """A successful job result's summaries: those its worker computed (``result.features``), else
    :func:`rollout_features` here (a result simulated without :func:`run_summarising`)."""
    return result.features if result.features is not None else rollout_features(run, result, seed)


def run_frames(run: "RunView") -> list[int]:
    """The frame indices :func:`run_features` summarises, in order (all frames when the fit used all)."""
    return list(range(len(run.dense))) if run.metric_frames is None else list(run.metric_frames)


def sampled_points(vertices: np.ndarray, faces: np.ndarray, n: int, seed: int,
                   frames: Sequence[int] | None = None) -> np.ndarray:
    """``(T, n, 3)`` area-weighted surface samples, drawn exactly like the measurement's dense
    clouds so that summaries compare like with like (the same ``seed`` gives common random
    numbers across finite-difference simulations of the same mesh). With ``frames``, only those
    frames ``(len(frames), n, 3)``, each drawn as it would be among all ``T``."""
    idx = range(len(vertices)) if frames is None else frames
    return np.stack([sample_surface(vertices[t], faces, n, np.random.default_rng([seed, t])) for t in idx])


# ----------------------------------------------------------------------------------------
# Monte-Carlo p-values










# ----------------------------------------------------------------------------------------
# the null: posterior-predictive rollouts


class PosteriorPredictive:
    """Posterior-predictive rollouts of a finished run, the null of ``check`` and ``diagnose``.

    Rollout ``i < len(run.post_theta)`` is the fit's own evaluation sample ``i`` with its seed
    (so check's mean Chamfer is the fit's); further rollouts are posterior draws
    (:meth:`~softsbi.workflows.fit.runs.RunView.posterior`, draw seed ``seed``) with simulation
    seeds ``EXTRA_ROLLOUT_SEED + i``. Each rollout's summaries use surface samples seeded by ``surface_seed(i)``, so
    the same run gives the same null in both commands.

    Attributes:
        rollouts: successful job results (``vertices (T, N, 3)``, ``faces``, ``chamfer (T,)``, ...).
        features: ``(len(rollouts), T' * 14)`` summaries under the fit's sensor model
            (:func:`run_features`: its visibility threshold and its ``T'`` metric frames).
        requested: rollouts simulated so far (failed ones included).
        sensitivities: the screening's finite-difference simulations at the posterior median, kept so that
            ``check`` and ``diagnose`` sharing this pool simulate them once.
        energy_scores: :func:`energy_score`'s results, kept for the same reason.
    """

    def __init__(self, run: "RunView | str | Path", workers: int | None = None, seed: int = 0):
        # every stored evaluation sample: the null's order is the run's. A run loaded with all of them
        # (load_run(path, None)) is used as it is, so a command loads its run once
        if not (isinstance(run, RunView) and run.post_complete):
            run = load_run(run.path if isinstance(run, RunView) else Path(run), None, seed)
        self.run: RunView = run
        self.workers, self.seed = workers, seed
        self.rollouts: list[JobResult] = []
        self._feats: list[np.ndarray] = []
        self.requested = 0
        self.first = 0  # size of the first request: the null's starting size
        self._extra: np.ndarray | None = None
        #: the screening's finite-difference simulations, by (candidates, steps)
        #: (:func:`softsbi.workflows.criticism.screening.screening_of`)
        self.sensitivities: dict[tuple, Any] = {}
        #: :func:`energy_score` results, by (n, the rollouts' samples), so that check and diagnose sharing this
        #: pool score it once
        self.energy_scores: dict[tuple, EnergyScore] = {}

    @property
    def features(self) -> np.ndarray:
        """``(S, T' * 14)`` summaries of the successful rollouts (:func:`run_features`)."""
        return np.array(self._feats)

    def _items(self, lo: int, hi: int) -> list[JobItem]:
        run = self.run
        n_ev = len(run.post_theta)
        items: list[JobItem] = []
        for i in range(lo, hi):
            if i < n_ev:
                items.append(JobItem(run.post_theta[i], int(run.post_seeds[i])))
            else:
                if self._extra is None or len(self._extra) < hi - n_ev:
                    self._extra = run.posterior().sample(max(hi - n_ev, 2 * MAX_NULL), seed=self.seed)
                items.append(JobItem(self._extra[i - n_ev], EXTRA_ROLLOUT_SEED + i))
        return items

    def ensure(self, n: int) -> "PosteriorPredictive":
        """Simulate rollouts up to ``n`` requested in all (no-op when already there)."""
        if n <= self.requested:
            return self
        self.first = self.first or n
        items = [replace(t, summary_seed=surface_seed(i)) for i, t in enumerate(self._items(self.requested, n),
                                                                               start=self.requested)]
        res = run_jobs(run_summarising(self.run), items, self.workers,
                       label=f"posterior-predictive rollouts {self.requested + 1}-{n}")
        for i, r in enumerate(res, start=self.requested):
            if r is None or not r.ok or r.vertices is None:
                continue
            self.rollouts.append(replace(r, sample=i))
            self._feats.append(features_of(self.run, r, surface_seed(i)))
        self.requested = n
        return self

    def ensure_successful(self, n: int, max_requests: int | None = None) -> "PosteriorPredictive":
        """Simulate until ``n`` rollouts succeeded (a null grown to its cap must have the cap's size: with
        failed rollouts, 193 successes resolve only ``2/194 > 0.01`` in the joint test at ``alpha = 0.01``), requesting at most
        ``max_requests`` in all (default ``2 n``). The stopping rule depends on failures only, never on a
        test statistic, so the tests keep their level."""
        limit = max_requests or 2 * n
        while len(self.rollouts) < n and self.requested < limit:
            self.ensure(min(limit, self.requested + n - len(self.rollouts)))
        return self

#: the energy score's spread term compares each posterior-predictive rollout with the next ``ENERGY_PAIRS``
#: ones (cyclically): about ``ENERGY_PAIRS * n`` pairs instead of all ``n (n - 1) / 2``, an unbiased estimate of
#: the same mean at a tenth of the cost for ``n = 30`` (each pair is a Chamfer per metric frame)
ENERGY_PAIRS = 3


def rollout_views(run: "RunView", rollout: JobResult, seed: int) -> tuple[list[np.ndarray], float | None]:
    """What the run's sensor model sees of one simulated rollout, in its metric frames: ``(views, min_z)``.

    ``views`` are ``T'`` clouds ``(P_t, 3)`` m (:func:`run_frames`' order): area-weighted surface samples (as
    many per frame as the measurement's, drawn with ``seed``), or for a fit through the virtual depth sensor
    that sensor's clouds (the highest 10 % of the surface samples where it sees nothing, the metric's
    convention), with what the rollout's arm mask hides left out. ``min_z`` is the visibility threshold still to
    apply to them (the run's, combined with a sensor effect's on the rollout; None for the camera, whose clouds are
    already what it sees)."""
    frames = run_frames(run)
    surface = sampled_points(rollout.vertices, rollout.faces, run.dense.shape[1], seed, frames)
    camera = run.record.metric_camera
    if camera is None:
        return list(effect_views(list(surface), rollout, frames)), combined_min_z(run.metric_min_z,
                                                                                   rollout_min_z(rollout))
    v = np.asarray(rollout.vertices)[frames]
    g = rollout.gripper
    views = sensor_from_json(camera).observe_rollout(v, rollout.faces, None if g is None else np.asarray(g)[frames],
                                                    np.random.default_rng([seed, SENSOR_VIEW_STREAM]))
    return views_or_highest(views, surface), None


def energy_score(pool: PosteriorPredictive, n: int | None = None) -> EnergyScore | None:
    """The Chamfer energy score: the posterior predictive's energy score against the measured clouds, with the fit's
    metric as distance.

    ``ES = mean_i d(X_i, y) - 1/2 mean_(i,j) d(X_i, X_j)`` (Gneiting & Raftery 2007, eq. 22, with the
    Chamfer of :func:`~softsbi.perception.pointcloud.sensor_chamfer_per_frame`, averaged over the metric frames,
    in place of the Euclidean norm): ``X_i`` the posterior-predictive rollouts, ``y`` the measurement. The first
    term is the posterior-predictive Chamfer the fit reports; the second credits a model whose rollouts differ
    from one another as much as the measurement differs from them. The posterior-predictive Chamfer alone is
    smallest for a model that predicts no spread at all, so a sensor effect that adds the measurement's own
    noise raises it even when it is the right model; the energy score falls (it is a proper score: in
    expectation no prediction scores better than the measurement's own distribution). With a correct model it
    is half the distance between two independent measurements, so it does not fall to 0 either.

    Args:
        pool: the run's posterior-predictive rollouts (:class:`PosteriorPredictive`, rollouts kept).
        n: use the rollouts of samples ``< n`` (default: the fit's own evaluation samples, whose mean Chamfer
            is the report's ``chamfer_posterior_m``).

    Returns:
        an :class:`~softsbi.core.results.EnergyScore` (m): the score, its jackknife standard error over rollouts, the two
        terms (``spread_m`` is the mean distance between two rollouts) and the rollouts scored; None with fewer
        than 3 successful rollouts or an image fit (no clouds).
    """
    run = pool.run
    n = len(run.post_theta) if n is None else n
    ok = [r for r in pool.rollouts if r.sample < n and r.chamfer is not None]
    m = len(ok)
    if m < 3 or run.dense is None:
        return None
    key = (n, tuple(int(r.sample) for r in ok))
    if key in pool.energy_scores:  # check and diagnose sharing one pool score it once
        return pool.energy_scores[key]
    frames = run_frames(run)
    d_obs = np.array([float(np.mean(np.asarray(r.chamfer, float)[frames])) for r in ok])
    views = [rollout_views(run, r, 2000 + int(r.sample)) for r in ok]
    pairs = sorted({tuple(sorted((i, (i + k) % m))) for i in range(m) for k in range(1, min(ENERGY_PAIRS, m - 1) + 1)})
    d_pair = np.array([sensor_chamfer_per_frame(views[i][0], views[j][0],
                                                combined_min_z(views[i][1], views[j][1]))[0].mean() for i, j in pairs])
    a = np.array(pairs)

    def score(keep: np.ndarray) -> float:
        use = keep[a[:, 0]] & keep[a[:, 1]]
        return float(d_obs[keep].mean() - 0.5 * d_pair[use].mean())

    full = score(np.ones(m, bool))
    loo = np.array([score(np.arange(m) != i) for i in range(m)])
    se = float(np.sqrt((m - 1) / m * np.sum((loo - loo.mean()) ** 2)))
    pool.energy_scores[key] = EnergyScore(energy_m=full, se_m=se, chamfer_m=float(d_obs.mean()),
                                          spread_m=float(d_pair.mean()), n=m)
    return pool.energy_scores[key]






#: rollouts at the posterior mean whose mean Chamfer is a fit's posterior-mean rollout error
#: (:func:`posterior_mean_chamfer`); they differ only in their simulation seeds (point sampling, sensor noise)
PM_ROLLOUTS = 3
#: the seeds of those rollouts are ``PM_SEED + k``, apart from the fit's and the null's
PM_SEED = 3000


def rollout_chamfers(run: RunView, items: Sequence[JobItem], workers: int | None = None) -> np.ndarray:
    """Simulate job ``items`` through the fit's own job (:meth:`RunView.sim_context`: its simulator, effects,
    observer and sensor model) and score each: the mean Chamfer (m) over the fit's metric frames, as the report's
    ``chamfer_posterior_m`` scores one rollout.

    Args:
        run: a finished fit with a point-cloud measurement.
        items: :func:`~softsbi.workflows.fit.jobs.simulate_job` items (:class:`~softsbi.workflows.fit.jobs.JobItem`).
        workers: simulation processes (None: the executor's default).

    Returns:
        ``(k,)`` scores of the ``k <= len(items)`` rollouts that succeeded, in item order.
    """
    res = run_jobs(run.sim_context(keep_rollout=False), list(items), workers, label="posterior-mean rollouts")
    frames = run_frames(run)
    return np.array([float(np.mean(np.asarray(r.chamfer, float)[frames])) for r in res
                     if r is not None and r.ok and r.chamfer is not None])


def posterior_mean_chamfer(run: RunView, n: int = PM_ROLLOUTS, workers: int | None = None) -> dict[str, Any] | None:
    """The error of the fitted model's point estimate: the mean Chamfer between the measurement and ``n``
    rollouts at the posterior mean (the report's ``posterior_mean``, physical units), through the fit's own job
    and metric (sensor model and frames, as the report's ``chamfer_posterior_m``).

    The posterior-predictive Chamfer averages the Chamfer over posterior draws, so it carries the posterior's
    width too: an honest posterior from a small simulation budget is wide, and its draws usually score worse
    than its mean (not always: a misspecified fit's mean can miss more than its draws do).
    This is the number a user who simulates with the fitted parameters sees, the one to set beside an
    optimiser's best simulation ("the posterior-mean rollout").

    Args:
        run: a finished fit (:class:`~softsbi.workflows.fit.runs.RunView`) with a point-cloud measurement.
        n: rollouts, seeds ``PM_SEED + k``; they differ only in their seeds (the point sampling of the simulated
            clouds, a sensor effect's noise).
        workers: simulation processes (None: the executor's default).

    Returns:
        ``{"chamfer_m", "chamfer_se_m", "n"}`` (m; the standard error over the ``n`` seeds, 0 with one), or None
        for an image fit, a report without a posterior mean, or when every rollout fails.
    """
    pm = run.report.posterior_mean
    if not pm or run.dense is None or any(name not in pm for name in run.space.names):
        return None
    theta = run.space.as_array(pm)
    vals = rollout_chamfers(run, [JobItem(theta, PM_SEED + k) for k in range(n)], workers)
    if not len(vals):
        return None
    se = float(vals.std(ddof=1) / np.sqrt(len(vals))) if len(vals) > 1 else 0.0
    return {"chamfer_m": float(vals.mean()), "chamfer_se_m": se, "n": int(len(vals))}


