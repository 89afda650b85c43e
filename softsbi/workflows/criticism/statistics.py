"""The pure statistics the verdicts rest on: arrays in, arrays out (as sbi's diagnostics are), no runs, no
simulations. :mod:`~softsbi.workflows.criticism.stats` applies them to a run's posterior predictive.

- :func:`mc_pvalue`: the Monte-Carlo p-value ``(k + 1) / (n + 1)`` of an observed statistic against ``n`` null
  simulations, ``k`` of them at least as extreme (Davison & Hinkley 1997, eq. 4.11; North, Curtis & Sham 2002). It
  is never smaller than ``1 / (n + 1)``: no tail model extrapolates beyond the simulations.
- :func:`min_p_combined`: two tests on one null combined by the null's own distribution of their smaller p-value
  (Westfall & Young's min-P), not Bonferroni's doubling.
- :func:`max_t_adjusted`: family-wise error control over several candidate statistics by the single-step max-T null
  (Westfall & Young 1993, alg. 2.8): each candidate's statistic is normalised by its own null, and its adjusted
  p-value is the Monte-Carlo p-value of its normalised statistic against the null of the *maximum* over candidates.
- :func:`misspecification_test`: the posterior predictive check's test (Gelman et al., *BDA* ch. 6): mean squared
  standardised deviation of the measurement's summaries from the posterior predictive ones, against leave-one-out
  nulls.
- :func:`resolution_needed`: adaptive resolution: when a decision at level ``alpha`` cannot be reached with ``n``
  nulls and the first stage is promising, the null is extended once to the cap, so the test keeps its level.
- :func:`summary_energy_score`: the energy score (Gneiting & Raftery 2007) of the measurement's summaries against a
  posterior predictive's, in a fixed scale (:func:`summary_scale`).
- :func:`cloud_features`, :func:`trajectory_features`: the per-frame summary statistics of point clouds.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from softsbi.core.defaults import MIN_ROLLOUTS
from softsbi.core.errors import SoftsbiError
from softsbi.core.results import MCPValue, Score
from softsbi.inference.summaries import local_thickness
from softsbi.perception.pointcloud import sensor_view


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


#: the smallest posterior standard deviation (unit coordinates: a fraction of the prior's range) that
#: :func:`off_distance` divides by; a posterior narrower than that is a point
OFF_SD_FLOOR = 1e-6


def off_distance(unit_mean: np.ndarray, unit_std: np.ndarray, unit_off: np.ndarray) -> float:
    """The "switched on" statistic of one added effect: the largest distance, over the effect's parameters, of the
    posterior mean from the parameter's off value in posterior standard deviations, all in unit coordinates (the
    prior box mapped to [0, 1] in each parameter's own scale). Larger is farther from "off". A Wald-type distance;
    its null distribution is not assumed but simulated (:mod:`~softsbi.workflows.criticism.switched_on`).

    Args:
        unit_mean, unit_std, unit_off: ``(D,)`` the posterior's mean and standard deviation and the off values of
            the effect's ``D`` parameters (NaN: a parameter without an off value, left out).

    Returns:
        The statistic; NaN when no parameter has an off value.
    """
    m, sd, off = (np.asarray(a, float).ravel() for a in (unit_mean, unit_std, unit_off))
    keep = np.isfinite(off) & np.isfinite(m) & np.isfinite(sd)
    if not keep.any():
        return float("nan")
    return float(np.max(np.abs(m[keep] - off[keep]) / np.maximum(sd[keep], OFF_SD_FLOOR)))


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
    z_obs, z_max = max_t_statistics(observed, null)
    return [mc_pvalue(z, z_max) for z in z_obs], z_obs


def max_t_statistics(observed: np.ndarray, null: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The normalised statistics of :func:`max_t_adjusted`: the observed ones ``(C,)`` and each null simulation's
    maximum over the candidates ``(n,)`` (each column normalised over all ``n + 1`` values). The observed maximum
    against the nulls' is the directional test, a statistic of the exchangeable sample like the omnibus one, so the
    two combine by :func:`min_p_combined`.

    Raises:
        SoftsbiError: shapes disagree or there are no null simulations.
    """
    observed = np.asarray(observed, float).ravel()
    null = np.asarray(null, float)
    if null.ndim != 2 or null.shape[1] != len(observed) or len(null) == 0:
        raise SoftsbiError(f"max-T needs null statistics of shape (n, {len(observed)}), got {null.shape}")
    both = np.vstack([observed[None], null])
    mu, sd = both.mean(0), np.maximum(both.std(0), 1e-12)
    return (observed - mu) / sd, ((null - mu) / sd).max(1)


def min_p_combined(observed: np.ndarray, null: np.ndarray) -> MCPValue:
    """The Monte-Carlo p-value of the smaller of ``k`` tests' p-values, calibrated against the null's own
    distribution of that minimum (Westfall & Young 1993, the single-step min-P procedure, alg. 2.5) instead of
    Bonferroni's ``k x min p``.

    Every member of the exchangeable sample (the observation and the ``n`` null simulations) gets each test's
    p-value from its rank among all ``n + 1`` members (``#{members at least as large} / (n + 1)``, larger is more
    extreme); the combined p-value is the Monte-Carlo p-value of the observation's smallest one against the
    nulls' smallest ones, ``(1 + #{i: m_i <= m_obs}) / (n + 1)``. A symmetric function of the sample, so it is
    exactly uniform when the members are exchangeable (ties are counted as extreme: conservative), never below
    ``1 / (n + 1)`` and never above Bonferroni's ``k x min p`` by more than the rank resolution; unlike
    Bonferroni it does not pay for the tests' dependence, and it puts no mass at 1.

    Args:
        observed: ``(k,)`` the observation's statistics (larger is more extreme).
        null: ``(n, k)`` each null simulation's statistics, the same tests on the same scale (posterior-predictive
            rollouts, each against the others; or replicate recordings of the task, each checked like the
            observation).

    Raises:
        SoftsbiError: shapes disagree, no null simulations, or non-finite statistics.
    """
    observed = np.asarray(observed, float).ravel()
    null = np.asarray(null, float)
    if null.ndim != 2 or null.shape[1] != len(observed) or len(null) == 0:
        raise SoftsbiError(f"a min-p combination needs null statistics of shape (n, {len(observed)}), got {null.shape}")
    if not (np.isfinite(null).all() and np.isfinite(observed).all()):
        raise SoftsbiError("non-finite test statistic: a null simulation or the measurement gave NaN/inf summaries")
    both = np.vstack([observed[None], null])                                     # (n + 1, k)
    tol = 1e-12 * np.maximum(1.0, np.abs(both))
    # p[i, j]: the share of members whose statistic j is at least member i's
    p = ((both[None, :, :] >= both[:, None, :] - tol[:, None, :]).sum(1)) / len(both)
    m = p.min(1)
    return MCPValue(exceed=int((m[1:] <= m[0] + 1e-12).sum()), n=len(null))


def resolution_needed(p: MCPValue, alpha: float, cap: int, promising: float = EXTEND_P) -> bool:
    """True when the null must grow to ``cap`` simulations before ``p <= alpha`` is decided: the first stage's
    ``n < cap`` nulls are not the cap, and either the cap could reject (``(exceed + 1) / (cap + 1) <= alpha``: e.g.
    the observation beyond all nulls, or a first stage that rejects already) or the first stage's p-value is at most
    ``promising`` (:data:`EXTEND_P`). Otherwise the first stage accepts, and no more nulls could change that.

    Rejections happen only at the cap's fixed size, on the p-value of all ``cap`` nulls, so the two-stage test keeps
    its level ``alpha`` whatever the extension rule: ``P(extend and p_cap <= alpha) <= P(p_cap <= alpha) <= alpha``
    (a first stage that rejects is not enough: rejecting there as well would add its own chance of a false alarm).
    The rule sets only the cost and the power. The second clause matters because the tests' exceedance counts are
    not monotone in ``n``: max-T renormalises every column over all ``n + 1`` values and the omnibus test's
    leave-one-out null re-standardises, so 1 exceedance in 30 can become 0 in 200, and a first stage of ``p = 2/31``
    can end at ``p = 1/201``."""
    return p.n < cap and ((p.exceed + 1) / (cap + 1) <= alpha or p.value <= promising)


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
    d_obs, null = omnibus_statistics(f_obs, f_sims)
    return d_obs, mc_pvalue(d_obs, null)


def omnibus_statistics(f_obs: np.ndarray, f_sims: np.ndarray) -> tuple[float, np.ndarray]:
    """:func:`misspecification_test`'s statistic of ``f_obs (F,)`` against ``f_sims (S, F)`` and its leave-one-out
    null ``(S,)`` (each simulation against the others).

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

    return stat(f_obs, f_sims), np.array([stat(f_sims[i], np.delete(f_sims, i, axis=0)) for i in range(S)])


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
