""""Switched on", calibrated: does a refit's posterior sit farther from its effect's off value than the same
model's posteriors do when the effect is absent?

A refit that lowers the score may have absorbed the misfit by widening its predictions with a parameter the data
leave near its prior; "switched on" asks the posterior of the added effect itself. An uncalibrated rule (a 90%
interval excluding the off value, a Savage-Dickey ratio at a bound) holds its 10% rate only for a calibrated
posterior: on data without wind, the wind model's amortised interval excluded 0 in 48.5% of cases, while at a bound
a ratio threshold set aside real effects whose posterior was merely wide. So, where a task is trained, the rule is
a Monte-Carlo test (Davison & Hinkley 1997, eq. 4.11) of its own null:

1. *Statistic* (:func:`~softsbi.workflows.criticism.statistics.off_distance`): the largest distance of the effect's
   parameters' posterior mean from their off values, in posterior standard deviations (unit coordinates).
2. *Null* (:func:`train_off_null`, once per trained candidate, stored with its task as ``off-null.json``): the
   statistic of the candidate model's amortised posterior on each of the model-without-it's held-out prior
   simulations (the training report's, read from the simulation bank: nothing is simulated). The effect is absent
   in every one; the other parameters range over their prior.
3. *Decision* (:func:`off_test`): switched on when ``p = (1 + #{null >= observed}) / (n + 1) <= CHANCE_EXCLUDED``
   (0.10). On data without the effect its rate is then at most 10% by construction, whatever the posterior's
   calibration; its power is measured on the posterior-calibration page.

It decides amortised single refits of a trained task; sequential refits and pairs keep the estimates' rule
(:func:`~softsbi.workflows.criticism.diagnose.may_be_off`), whose null is not simulated.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from softsbi.core.errors import PosteriorError
from softsbi.core.jsonfile import write_json_atomic
from softsbi.core.results.joint import CHANCE_EXCLUDED
from softsbi.core.results import OffTest
from softsbi.inference import calibration as cal
from softsbi.workflows.criticism.statistics import mc_pvalue, off_distance

#: the file beside a trained candidate's task that holds its null
OFF_NULL_FILE = "off-null.json"


def unit_off_values(effect: Any, space: Any) -> np.ndarray:
    """``(D,)``: the off values of ``effect``'s parameters in unit coordinates of ``space`` (the fit's ParamSpace,
    whose bounds may differ from the effect's own), NaN for every other parameter and for one without an off value.
    An off value at or beyond a prior bound is that bound (0 or 1)."""
    off = effect.nominal()
    own = {p.name for p in effect.param_space()}
    has = np.array([p.name in own and p.name in off for p in space])
    # an off value at or beyond a bound is that bound (a log parameter's 0 included); other parameters at their low
    row = [min(max(float(off[p.name]), p.low), p.high) if h else p.low for p, h in zip(space, has)]
    return np.where(has, space.to_unit(np.array(row)), np.nan)


def draws_off_distance(unit_draws: np.ndarray, unit_off: np.ndarray) -> float:
    """:func:`~softsbi.workflows.criticism.statistics.off_distance` of posterior draws ``(S, D)`` in unit
    coordinates."""
    return off_distance(unit_draws.mean(0), unit_draws.std(0), unit_off)


def train_off_null(est: Any, x: np.ndarray, unit_off: np.ndarray, n_draws: int, seed: int) -> np.ndarray:
    """``(n,)``: the statistic of ``est``'s posterior (a trained candidate model's estimator) at each of ``x``
    (``(n, ...)``, simulations without the effect, at the fit's frames), from ``n_draws`` draws in the prior box;
    NaN where a posterior puts no mass in the box."""
    rng = np.random.default_rng([seed, 7])
    qs = cal.posteriors_at(est, x)
    out = np.full(len(qs), np.nan)
    for i, q in enumerate(qs):
        try:
            out[i] = draws_off_distance(cal.draws_in_box(q, n_draws, rng), unit_off)
        except PosteriorError:
            continue
    return out


def store_off_null(task_path: Path, values: np.ndarray, n_draws: int) -> None:
    """Write the null (``values``, NaN left out) beside the task.

    Raises:
        ResultUnwritable: the file cannot be written (one line)."""
    v = [float(a) for a in np.asarray(values, float) if np.isfinite(a)]
    write_json_atomic(Path(task_path) / OFF_NULL_FILE, {"statistic": "off_distance", "n_draws": int(n_draws),
                                                        "values": v})


def stored_off_null(task_path: Path | None, damaged: Callable[[str], None] | None = None) -> np.ndarray | None:
    """The task's stored null; None when it has none or the file cannot be read (told to ``damaged``)."""
    if task_path is None or not (Path(task_path) / OFF_NULL_FILE).is_file():
        return None
    path = Path(task_path) / OFF_NULL_FILE
    try:
        d = json.loads(path.read_text())
        values = np.asarray(d["values"], float)
        if values.ndim != 1 or not len(values) or not np.all(np.isfinite(values)):
            raise ValueError("no finite values")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        (damaged or (lambda _: None))(f"'{path}' is damaged ({exc}); its refits use the estimates' rule")
        return None
    return values


def off_test(contraction: Mapping[str, Any], effect: Any, space: Any, null: np.ndarray,
             level: float = CHANCE_EXCLUDED) -> OffTest | None:
    """The calibrated test of ``effect`` (an instance) on a refit whose report's contraction (per parameter, with
    ``unit_mean``/``unit_std``) is ``contraction``, against ``null`` (:func:`stored_off_null`); None when the
    report lacks the unit moments (an older report) or the effect has no off value."""
    names = list(space.names)
    off = unit_off_values(effect, space)
    m, sd = np.full(len(names), np.nan), np.full(len(names), np.nan)
    for j, n in enumerate(names):
        c = contraction.get(n)
        if c is not None and np.isfinite(off[j]):
            if c.unit_mean is None or c.unit_std is None:
                return None
            m[j], sd[j] = c.unit_mean, c.unit_std
    stat = off_distance(m, sd, off)
    if not np.isfinite(stat):
        return None
    return OffTest(statistic=stat, p_value=mc_pvalue(stat, null), level=level)
