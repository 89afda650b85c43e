"""Honest Monte-Carlo statistics shared by ``check`` and ``diagnose``.

One implementation of every p-value the verdicts rest on, so two commands never disagree about
the same run:

- :func:`mc_pvalue`: the Monte-Carlo p-value ``(k + 1) / (n + 1)`` of an observed statistic
  against ``n`` null simulations, ``k`` of them at least as extreme (Davison & Hinkley 1997,
  eq. 4.11; North, Curtis & Sham 2002). It is never smaller than ``1 / (n + 1)``: no tail model
  extrapolates beyond the simulations (none has been validated on nulls here).
- :func:`max_t_adjusted`: family-wise error control over several candidate statistics by the
  single-step max-T null (Westfall & Young 1993, alg. 2.8): every null simulation gives every
  candidate's statistic; each is normalised by its own null (centre and spread), and a candidate's
  adjusted p-value is the Monte-Carlo p-value of its normalised statistic against the null
  distribution of the *maximum* over candidates. Exact under the joint null, needs resolution
  ``1 / (n + 1)`` rather than Bonferroni's ``1 / (C (n + 1))``.
- :func:`misspecification_test`: the posterior predictive check's test (Gelman et al., *BDA*
  ch. 6): mean squared standardised deviation of the measurement's summaries from the posterior
  predictive ones, against leave-one-out nulls.
- :class:`PosteriorPredictive`: the posterior-predictive rollouts of a run, the null of both
  tests: the fit's own evaluation samples with their seeds first, then further posterior draws,
  simulated on demand (:meth:`PosteriorPredictive.ensure`).
- :func:`resolution_needed`: adaptive resolution. When a decision at level ``alpha`` cannot be
  reached with ``n`` nulls (``1 / (n + 1) > alpha``) and the first stage is promising (the observation
  beyond all nulls, or ``p <= EXTEND_P``), the null is extended once to the cap; a rejection can then
  only happen at the cap's size, so the test keeps its level (the first stage can never reject).
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from softsbi.core.errors import SoftsbiError
from softsbi.core.results import EnergyScore, MCPValue, Score
from softsbi.core.defaults import ALPHA  # noqa: F401 (re-exported)
from softsbi.core.seeds import EXTRA_ROLLOUT_SEED, SENSOR_VIEW_STREAM, surface_seed
from softsbi.inference.summaries import local_thickness
from softsbi.perception.depth_sensor import sensor_from_json, views_or_highest
from softsbi.perception.pointcloud import (combined_min_z, rollout_min_z, sample_surface, sensor_chamfer_per_frame,
                                          sensor_view)
from softsbi.core.defaults import MAX_NULL, MIN_ROLLOUTS, N_NULL  # noqa: F401 - null sizes, re-exported
from softsbi.workflows.fit.jobs import JobItem, JobResult, run_jobs
from softsbi.workflows.fit.runs import RunView, load_run

#: names of the per-frame summary statistics
FEATURE_NAMES = ("mean_x", "mean_y", "mean_z", "std_x", "std_y", "std_z", "z_q10", "z_q50", "z_q90",
                 "x_q05", "x_q95", "y_q05", "y_q95", "thickness")
#: floor of a position summary's standard deviation (m): sensor resolution, keeps weights finite
FEATURE_FLOOR = 0.003
#: floor of the local thickness's standard deviation (m): 0.1 mm, the thickness that sensor noise of 1% of the
#: point-noise prior's range (1 cm) adds. A lift's rollouts vary by about 0.03 mm per frame in thickness, so
#: without the floor a 0.1 mm difference of mesh resolution between two engines would count as a misfit
THICKNESS_FLOOR = 1e-4
#: the floors of :data:`FEATURE_NAMES`, in order
FEATURE_FLOORS = np.array([FEATURE_FLOOR] * (len(FEATURE_NAMES) - 1) + [THICKNESS_FLOOR])
#: a first-stage p-value at or below this extends the null to its cap (:func:`resolution_needed`). A round
#: level, not fitted: it cannot change a test's level, only its cost and power
EXTEND_P = 0.1
#: the fewest successful posterior-predictive rollouts a null may hold: the fewest ``check`` simulates
#: (:data:`~softsbi.core.defaults.MIN_ROLLOUTS`, the smallest ``--n-eval``), so that the test refuses only
#: rollouts that failed; each leave-one-out statistic then standardises by the spread of at least 4 others
MIN_NULL = MIN_ROLLOUTS


def cloud_features(points: np.ndarray) -> np.ndarray:
    """Summary statistics ``(14,)`` (m) of one point set ``(P, 3)``; see :data:`FEATURE_NAMES`.

    Thirteen place the cloud (mean, spread, height and horizontal quantiles); the fourteenth is its mean local
    thickness (:func:`~softsbi.inference.summaries.local_thickness`, 8 neighbours; 0 for fewer than 3 points),
    the one summary that sees independent sensor noise: a noise of 1 cm moves a 30 cm cloud's spread by under
    1 mm, its thickness by several."""
    p = np.asarray(points, float)
    q = np.quantile(p, [0.05, 0.95], axis=0)
    thick = float(local_thickness(p)) if len(p) >= 3 else 0.0
    return np.concatenate([p.mean(0), p.std(0), np.quantile(p[:, 2], [0.1, 0.5, 0.9]),
                           [q[0, 0], q[1, 0], q[0, 1], q[1, 1], thick]])


def summary_floor(n_features: int) -> "np.ndarray | float":
    """The standard-deviation floors ``(F,)`` (m) of ``F`` summaries laid out as :func:`trajectory_features` lays
    them out (:data:`FEATURE_FLOORS` once per frame); :data:`FEATURE_FLOOR` for any other layout."""
    k = len(FEATURE_NAMES)
    return np.tile(FEATURE_FLOORS, n_features // k) if n_features and n_features % k == 0 else FEATURE_FLOOR


def trajectory_features(clouds: Sequence[np.ndarray], min_z: float | None = None,
                        frames: Sequence[int] | None = None) -> np.ndarray:
    """``(T' * 14,)`` summaries of a sequence of ``T`` point sets ``(P_t, 3)`` m, as a sensor model sees them.

    Args:
        clouds: the ``T`` clouds.
        min_z: the sensor's visibility threshold (absolute height, m): each cloud is first reduced to
            :func:`~softsbi.perception.pointcloud.sensor_view` (points at or below it are not seen);
            None = full clouds.
        frames: the frames summarised (``T' = len(frames)``, in this order); None = all ``T``.
    """
    idx = range(len(clouds)) if frames is None else frames
    return np.concatenate([cloud_features(sensor_view(np.asarray(clouds[t], float), min_z)) for t in idx])


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
    clouds = sampled_points(rollout.vertices, rollout.faces, n_dense, seed)
    # a sensor effect's threshold on the rollout (table-unseen) adds to the run's own
    return trajectory_features(clouds, combined_min_z(min_z, rollout_min_z(rollout)), frames)


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


def mc_pvalue(observed: float, null: np.ndarray) -> MCPValue:
    """Monte-Carlo p-value of ``observed`` against the null statistics ``null (n,)`` (larger is
    more extreme; NaNs are not allowed).

    Raises:
        SoftsbiError: empty null or non-finite statistics.
    """
    null = np.asarray(null, float).ravel()
    if len(null) == 0:
        raise SoftsbiError("a Monte-Carlo p-value needs at least one null simulation")
    if not (np.isfinite(null).all() and np.isfinite(observed)):
        raise SoftsbiError("non-finite test statistic: a null simulation or the measurement gave NaN/inf summaries")
    return MCPValue(exceed=int((null >= observed - 1e-12 * max(1.0, abs(observed))).sum()), n=len(null))


def max_t_adjusted(observed: np.ndarray, null: np.ndarray) -> tuple[list[MCPValue], np.ndarray]:
    """Westfall-Young single-step max-T adjusted p-values.

    Args:
        observed: ``(C,)`` the candidates' statistics on the measurement.
        null: ``(n, C)`` the same statistics on each of ``n`` null simulations (one simulation gives
            every candidate's statistic, so their dependence is kept).

    Each column is normalised by the mean and standard deviation (floored at ``1e-12``) of all
    ``n + 1`` values, the measurement's included: a symmetric function of the exchangeable sample,
    so the test is exact (normalising by the nulls alone is anti-conservative: the nulls are then
    shrunk towards their own mean; measured 7.3% family-wise error at a 5% level in
    ``tests/workflows/test_stats.py``). The adjusted p-value of candidate ``c`` is
    ``(1 + #{i: max_c' z_ic' >= z_c}) / (n + 1)``.
    It controls the family-wise error rate at any level under the complete null (Westfall & Young
    1993, section 2.6).

    Returns:
        one :class:`MCPValue` per candidate, and the normalised observed statistics ``(C,)``.

    Raises:
        SoftsbiError: shapes disagree or there are no null simulations.
    """
    observed = np.asarray(observed, float).ravel()
    null = np.asarray(null, float)
    if null.ndim != 2 or null.shape[1] != len(observed) or len(null) == 0:
        raise SoftsbiError(f"max-T needs null statistics of shape (n, {len(observed)}), got {null.shape}")
    both = np.vstack([observed[None], null])
    mu, sd = both.mean(0), np.maximum(both.std(0), 1e-12)
    z_obs = (observed - mu) / sd
    z_max = ((null - mu) / sd).max(1)
    return [mc_pvalue(z, z_max) for z in z_obs], z_obs


def resolution_needed(p: MCPValue, alpha: float, cap: int, promising: float = EXTEND_P) -> bool:
    """True when more null simulations (up to ``cap``) are needed to decide ``p <= alpha``: the
    current ``n`` nulls cannot give any p-value at or below ``alpha`` (``1 / (n + 1) > alpha``; so
    stopping here never rejects), and either the exceedances so far would allow it at the cap
    (``(exceed + 1) / (cap + 1) <= alpha``; e.g. the observation beyond all nulls) or the first stage's
    p-value is at most ``promising`` (:data:`EXTEND_P`).

    Rejections happen only at the cap's fixed size, on the p-value of all ``cap`` nulls, so the two-stage
    test keeps its level ``alpha`` whatever the extension rule: ``P(extend and p_cap <= alpha) <=
    P(p_cap <= alpha) <= alpha``. The rule sets only the cost and the power. The second clause matters
    because the tests' exceedance counts are not monotone in ``n``: max-T renormalises every column over
    all ``n + 1`` values and the omnibus test's leave-one-out null re-standardises, so 1 exceedance in 30
    can become 0 in 200, and a first stage of ``p = 2/31`` can end at ``p = 1/201``."""
    return p.floor > alpha and p.n < cap and ((p.exceed + 1) / (cap + 1) <= alpha or p.value <= promising)


def misspecification_test(f_obs: np.ndarray, f_sims: np.ndarray) -> tuple[float, MCPValue]:
    """Is ``f_obs (F,)`` inside the distribution of ``f_sims (S, F)``?

    Statistic: mean squared standardised deviation (per-summary standard deviation from the
    simulations, floored at :func:`summary_floor`). Null: each simulation against the others
    (leave-one-out). p-value: :func:`mc_pvalue` (no tail model).

    Returns:
        the measurement's statistic and its Monte-Carlo p-value.

    Raises:
        SoftsbiError: fewer than :data:`MIN_NULL` simulations.
    """
    S = len(f_sims)
    if S < MIN_NULL:
        raise SoftsbiError(f"the misspecification test needs at least {MIN_NULL} successful posterior rollouts "
                           f"(got {S})")

    floor = summary_floor(f_sims.shape[1])

    def stat(f, others):
        sd = np.maximum(others.std(0), floor)
        return float((((f - others.mean(0)) / sd) ** 2).mean())

    d_obs = stat(f_obs, f_sims)
    null = np.array([stat(f_sims[i], np.delete(f_sims, i, axis=0)) for i in range(S)])
    return d_obs, mc_pvalue(d_obs, null)


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
        res = run_jobs(self.run.sim_context(keep_rollout=True), self._items(self.requested, n), self.workers,
                       label=f"posterior-predictive rollouts {self.requested + 1}-{n}")
        for i, r in enumerate(res, start=self.requested):
            if r is None or not r.ok or r.vertices is None:
                continue
            self.rollouts.append(replace(r, sample=i))
            self._feats.append(rollout_features(self.run, r, surface_seed(i)))
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
    convention). ``min_z`` is the visibility threshold still to apply to them (the run's, combined with a
    sensor effect's on the rollout; None for the camera, whose clouds are already what it sees)."""
    frames = run_frames(run)
    surface = sampled_points(rollout.vertices, rollout.faces, run.dense.shape[1], seed, frames)
    camera = run.record.metric_camera
    if camera is None:
        return list(surface), combined_min_z(run.metric_min_z, rollout_min_z(rollout))
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


def summary_scale(f_sims: np.ndarray) -> np.ndarray:
    """``(F,)`` the scale of summaries ``f_sims (S, F)``: their standard deviation floored at :func:`summary_floor` (the
    omnibus test's weights)."""
    f_sims = np.asarray(f_sims, float)
    return np.maximum(f_sims.std(0), summary_floor(f_sims.shape[1]))


def summary_energy_score(f_obs: np.ndarray, f_sims: np.ndarray, scale: np.ndarray) -> Score:
    """The summary energy score: the energy score of posterior-predictive summaries ``f_sims (S, F)`` against the
    measurement's ``f_obs (F,)`` in a fixed ``scale (F,)``: ``mean_i |z_i - z| - mean_(i<j) |z_i - z_j| / 2`` with
    ``z = f / scale`` (Gneiting & Raftery 2007, eq. 22; strictly proper for the Euclidean norm), with its jackknife
    standard error over rollouts.

    Raises:
        SoftsbiError: fewer than 3 rollouts or shapes that disagree.
    """
    z = np.asarray(f_sims, float) / scale
    z_obs = np.asarray(f_obs, float) / scale
    S = len(z)
    if S < 3 or z.ndim != 2 or z.shape[1] != len(z_obs):
        raise SoftsbiError(f"an energy score needs at least 3 rollouts of {len(z_obs)} summaries, got {z.shape}")
    d_obs = np.linalg.norm(z - z_obs, axis=1)
    sq = (z * z).sum(1)
    d_pair = np.sqrt(np.maximum(sq[:, None] + sq[None, :] - 2 * z @ z.T, 0.0))

    def score(keep: np.ndarray) -> float:
        m = int(keep.sum())
        return float(d_obs[keep].mean() - 0.5 * d_pair[np.ix_(keep, keep)].sum() / (m * (m - 1)))

    loo = np.array([score(np.arange(S) != i) for i in range(S)])
    se = float(np.sqrt((S - 1) / S * np.sum((loo - loo.mean()) ** 2)))
    return Score(value=score(np.ones(S, bool)), se=se, n=S)


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


