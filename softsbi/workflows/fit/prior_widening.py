"""Priors that follow the data: ``fit --widen``.

After each round but the last, a bound that the round's posterior presses against
(:func:`~softsbi.inference.contraction.bound_pressure`: at least 20 % of its mass within 5 % of the range from
it) and that is not a physical limit (nor an effect's switched-off value) moves outward by the rule ``fit``
prints (:func:`~softsbi.inference.contraction.widened_bounds`: half the prior's range in the parameter's own
scale, clipped to its physical limits); the following rounds draw from the widened prior truncated to the
posterior (TSNPE), and the widened prior is the fit's prior of record.

The run store stays consistent:

* the run's ``config`` holds the prior of record (``param_space``) and every widening (``widenings``: after
  which round, the bounds before and after, what pressed them); the config is written first, so a fit killed
  while widening resumes with the widening done;
* every stored round's ``u`` is in the unit cube of the prior of record (the widened parameters' columns are
  recomputed from the stored physical ``theta``, which is idempotent), so training, calibration and the
  best fit read one coordinate system; each round's posterior ``q`` stays in the coordinates of the prior it
  was trained under (:func:`space_of_round`) and is mapped with :func:`unit_map` where a later one is read;
* a resumed fit applies the stored widenings to the prior its command gives (:func:`prior_of_record`) and
  repeats no decision; a widening after a round that is redone (``--retry-failed``, damaged simulations) is
  dropped with it (:func:`reconcile`) and decided again when that round completes.

Statistics (why it is an option, not the default): TSNPE's posterior is ``q`` restricted to the prior box,
exact when every round's proposal is the prior restricted to a region holding the posterior's mass. The
rounds before a widening drew inside the old box, which a posterior pressing its bound does not fit in, so
the region beyond the old bound is covered by the later rounds only: it is under-weighted in the pooled
training data, by the share of the training simulations drawn there. The posterior moves towards the data
but is not exact; only truncated proposals (the default) with sequential estimators can widen (the
corrected proposals' importance weights and the bulk estimators' prior-only draws would be wrong).
"""
from __future__ import annotations

from typing import Any, Callable, Mapping, Sequence

import numpy as np

from softsbi.core.distributions import Distribution, MixtureOfGaussians
from softsbi.core.errors import SoftsbiError
from softsbi.core.store import RunStore
from softsbi.core.types import ParamSpace
from softsbi.inference.contraction import bound_pressure, bound_sentence, widened_bounds

__all__ = ["records", "apply_widenings", "space_of_round", "round_spaces", "MappedProposal", "unit_map", "map_mixture",
           "prior_of_record",
           "reconcile", "decide_widening", "check_widen", "widening_sentence"]

#: the run config's key of the widenings (a list of records, in order)
KEY = "widenings"


def records(config: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The widenings stored in a run's config, in order (``[]`` for a fit that never widened)."""
    return [dict(w) for w in (config.get(KEY) or [])]


def apply_widenings(space: ParamSpace, recs: Sequence[Mapping[str, Any]], before_round: int | None = None
                    ) -> ParamSpace:
    """``space`` (the prior the fit's command gives) with the widenings of ``recs`` applied in order; with
    ``before_round``, only those decided after a round ``< before_round`` (the prior that round drew in)."""
    for w in recs:
        if before_round is None or int(w["after_round"]) < before_round:
            space = space.with_bounds({k: (float(v[0]), float(v[1])) for k, v in w["bounds"].items()})
    return space


def space_of_round(base: ParamSpace, config: Mapping[str, Any], r: int) -> ParamSpace:
    """The prior round ``r`` drew in and its posterior ``q`` is expressed in: ``base`` (the command's prior)
    with the widenings decided after rounds before ``r``."""
    return apply_widenings(base, records(config), before_round=r)


def unit_map(src: ParamSpace, dst: ParamSpace) -> tuple[np.ndarray, np.ndarray]:
    """``(a, b)`` (each ``(D,)``) with ``u_dst = a * u_src + b`` for the same physical value: unit coordinates are
    affine in the parameter's own scale (log for log-scaled parameters), so a change of bounds is affine.

    Raises:
        SoftsbiError: the spaces differ in names or scales.
    """
    if src.names != dst.names or any(p.log != q.log for p, q in zip(src, dst)):
        raise SoftsbiError(f"cannot map unit coordinates between {src} and {dst}: other parameters or scales")
    lo_s, hi_s, _ = src._t()
    lo_d, hi_d, _ = dst._t()
    a = (hi_s - lo_s) / (hi_d - lo_d)
    return a, (lo_s - lo_d) / (hi_d - lo_d)


def map_mixture(q: Distribution, a: np.ndarray, b: np.ndarray) -> Distribution:
    """The distribution ``q`` of ``u`` as the distribution of ``a * u + b``: for a Gaussian mixture exact (means
    ``a mu + b``, Cholesky ``diag(a) L``), for any other posterior (a flow) through its ``sample`` and ``log_prob``
    with the change of variables' Jacobian."""
    if isinstance(q, MixtureOfGaussians):
        return MixtureOfGaussians(q.weights, q.means * a + b, q.scale_tril * a[:, None])
    return _Mapped(q, a, b)


class _Mapped(Distribution):
    """``a * u + b`` for ``u ~ q`` (:func:`map_mixture` of a posterior that is not a mixture)."""

    def __init__(self, q: Distribution, a: np.ndarray, b: np.ndarray):
        self.q, self.a, self.b, self.dim = q, np.asarray(a, float), np.asarray(b, float), len(a)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        return self.q.sample(n, rng) * self.a + self.b

    def log_prob(self, u: np.ndarray) -> np.ndarray:
        return self.q.log_prob((np.atleast_2d(u) - self.b) / self.a) - float(np.log(np.abs(self.a)).sum())


def round_spaces(record: ParamSpace, config: Mapping[str, Any], last: int) -> list[ParamSpace]:
    """The priors rounds ``0..last`` drew in, from the prior of record (a run's ``param_space``) and its
    widenings: each with the widenings decided at or after it undone."""
    recs = records(config)
    out = []
    for r in range(last + 1):
        space = record
        for w in reversed(recs):
            if int(w["after_round"]) >= r:
                space = space.with_bounds({k: (float(v[0]), float(v[1])) for k, v in w["before"].items()})
        out.append(space)
    return out


class MappedProposal:
    """A proposal over one prior's unit cube (``dist``, None = that prior itself), sampled in another's:
    ``u_dst = a * u + b`` (:func:`unit_map`)."""

    def __init__(self, dist: Any, a: np.ndarray, b: np.ndarray):
        self.dist, self.a, self.b = dist, a, b

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        u = rng.random((n, len(self.a))) if self.dist is None else self.dist.sample(n, rng)
        return u * self.a + self.b


def prior_of_record(store_path: Any, base: ParamSpace) -> ParamSpace:
    """The prior a stored run was widened to, from the prior ``base`` its command gives (``base`` itself for a
    new run or one that never widened): the stored widenings applied to ``base``."""
    if not RunStore.exists(store_path):
        return base
    return apply_widenings(base, records(RunStore.open(store_path).config))


def _rewrite_u(store: RunStore, space: ParamSpace, names: set[str]) -> None:
    """Every stored round's ``u`` columns of ``names`` recomputed from its ``theta`` in ``space``'s unit cube."""
    dims = [space.names.index(n) for n in sorted(names) if n in space.names]
    if not dims:
        return
    for r in store.round_ids():
        if not store.is_begun(r):
            continue
        g = store.root["rounds"][str(r)]
        u = g["u"][...]
        new = space.to_unit(g["theta"][...])
        if not np.allclose(u[:, dims], new[:, dims], rtol=0, atol=1e-12):
            u[:, dims] = new[:, dims]
            g["u"][...] = u


def reconcile(store: RunStore, base: ParamSpace, message: Callable[[str], None]) -> ParamSpace:
    """Make the store consistent with its widenings and return the prior of record (module docstring): drop a
    widening after a round that is not complete (redone), store the prior of record in the config and put
    every round's ``u`` in its unit cube."""
    cfg = store.config
    recs = records(cfg)
    if not recs:
        return base
    keep = [w for w in recs if store.is_complete(int(w["after_round"]))]
    for w in [w for w in recs if w not in keep]:
        message(f"round {int(w['after_round']) + 1} is redone: its widening of {', '.join(w['bounds'])} is "
                f"dropped and decided again when the round completes")
    space = apply_widenings(base, keep)
    if keep != recs or cfg["param_space"] != space.to_json():
        store.update_config(**{KEY: keep, "param_space": space.to_json()})
    _rewrite_u(store, space, {n for w in recs for n in w["bounds"]})
    return space


def decide_widening(store: RunStore, space: ParamSpace, samples: np.ndarray, r: int,
           keep: Mapping[str, float] | None = None) -> ParamSpace | None:
    """After round ``r``: widen the bounds its posterior presses (module docstring) and store the widening.

    Args:
        space: the prior round ``r`` drew in (the prior of record so far).
        samples: ``(S, D)`` round ``r``'s posterior draws, physical units.
        keep: an effect's switched-off values, never moved (:func:`~softsbi.inference.contraction.widened_bounds`).

    Returns:
        The widened prior (now the prior of record), or None when no bound is pressed or none can move.
    """
    pressed = bound_pressure(space, samples)
    new = widened_bounds(space, pressed, keep=keep)
    if not new:
        return None
    wide = space.with_bounds(new)
    rec = {"after_round": int(r), "before": {k: [space[k].low, space[k].high] for k in new},
           "bounds": {k: [float(v[0]), float(v[1])] for k, v in new.items()},
           "pressed": [e for e in pressed if e["param"] in new]}
    store.update_config(**{KEY: records(store.config) + [rec], "param_space": wide.to_json()})  # config first
    _rewrite_u(store, wide, set(new))
    return wide


def check_widen(proposal: str, sequential: bool, sensor_draws: int) -> None:
    """Raise :class:`SoftsbiError` naming the fix unless ``--widen`` can work with these settings (module
    docstring: truncated proposals, a sequential estimator, no sensor draws)."""
    if proposal != "truncated" or not sequential:
        raise SoftsbiError("--widen needs truncated proposals and a sequential estimator (the default --proposal "
                           "truncated with rkhs, mdnn, ...): the corrected proposals' and the bulk estimators' "
                           "posteriors assume one prior for every round; drop --widen, or widen with --bounds")
    if sensor_draws:
        raise SoftsbiError("--widen does not combine with --sensor-draws (their draws are stored in the unit cube "
                           "of the prior they were drawn in); drop one of them")


def widening_sentence(w: Mapping[str, Any]) -> str:
    """One stored widening in words: which bounds moved after which round, and what pressed them."""
    moves = []
    for k, (lo, hi) in w["bounds"].items():
        blo, bhi = w["before"][k]
        side = [s for s, a, b in (("lower", blo, lo), ("upper", bhi, hi)) if not np.isclose(a, b)]
        moves.append(f"{k} [{blo:.4g}, {bhi:.4g}] -> [{lo:.4g}, {hi:.4g}] ({' and '.join(side)} bound)")
    why = "; ".join(bound_sentence(e).split(": the data")[0] for e in w["pressed"])
    return f"prior widened after round {int(w['after_round']) + 1}: " + ", ".join(moves) + (f" ({why})" if why else "")
