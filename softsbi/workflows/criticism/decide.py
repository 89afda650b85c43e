"""The diagnosis' decision: sequential model criticism and selection among M0, M0+E_k and M0+E_j+E_k.

Pure functions of typed results (:mod:`softsbi.core.results`); no simulation here. The rule:

1. *Detect.* ``nothing-missing`` iff ``check``'s joint test of the nominal fit does not reject at ``alpha``.
2. *Propose.* The top ``confirm`` named (non-generic) candidates of :func:`refit_order` are refitted: first those
   whose trained model's amortised posterior predictive lowers the nominal fit's score (their evidence,
   :mod:`~softsbi.workflows.criticism.evidence`), lowest score first, then the untrained ones the screening ranks
   (:func:`next_refit`). The order spends the refit budget; it decides nothing.
3. *Decide* on the refits by three criteria only (:func:`decide`):
   - *adequate*: ``check``'s test of the refit does not reject at the same ``alpha``;
   - *improves*: the refit lowers the summary energy score (of the posterior predictive of ``check``'s summary
     statistics, a strictly proper score, Gneiting & Raftery 2007; every model in the nominal fit's scale,
     :class:`~softsbi.core.results.Score`) below the model it extends by more than ``k_se`` standard errors of the
     difference (:func:`gain`);
   - *switched on*: for each added effect, the posterior of at least one of its parameters excludes the value that
     switches the effect off at the level :data:`~softsbi.core.results.joint.CHANCE_EXCLUDED` (its 90% interval, or at a
     prior bound the Savage-Dickey density ratio: :func:`~softsbi.workflows.criticism.diagnose.may_be_off`;
     :attr:`~softsbi.core.results.Refit.maybe_off`); a refit whose added effect the data leave possibly off has
     absorbed the misfit by widening its predictions, not identified a cause.
   A refit that is not switched on takes no further part, unless it can be *refined* (:func:`to_refine`): an
   amortised single refit that is adequate and improving but whose effect the data may leave off is fitted again in
   sequential rounds after its amortised posterior (a trained task's posterior is amortised over the whole prior, so
   an effect the task barely informs stays near its prior there even when this recording wants it on), and the
   refinement takes its place, judged by the same criteria (adequate only when the amortised refit was too).
   The adequate, improving single refit with the lowest
   score is named; every other adequate, improving refit whose score is not ``k_se`` standard errors above it is
   listed as indistinguishable. When no single refit
   qualifies, one greedy step: the improving single refit with the lowest score is extended by the first
   named candidate of its own screening, and the pair is named if it is adequate and improves on that single
   refit by the same margin. Otherwise ``misspecified-unexplained``, naming the improving refit with the lowest
   score as explaining a part.

Why the summary energy score (not ``check``'s and ``compare``'s Chamfer energy score): it is a strictly proper score,
so no forecast scores better in expectation than the distribution the measurement comes from, and it lives in the
space ``check``'s test detects the misfit in.
The posterior-predictive Chamfer is not proper: a model that predicts no spread minimises it, and a correct noise
model raises it. An added parameter the data do not inform widens the posterior predictive, which the score
charges for unless the measurement needs that spread.

Knobs: ``alpha`` (the level of every test: the false-alarm rate tolerated), ``k_se`` (:data:`K_SE`), the
refit budget (``confirm`` refits, their rounds and simulations) and the refinement budget (``refine`` refits,
:data:`~softsbi.core.defaults.REFINE_ROUNDS` x :data:`~softsbi.core.defaults.REFINE_SIMS` each).
"""
from __future__ import annotations

from dataclasses import replace
from typing import Sequence

from softsbi.core.results import Candidate, Decision, Gain, JointTest, Refit, RefitGain, Score
from softsbi.core import defaults

#: standard errors by which a score must fall to count as an improvement, and within which two refits are
#: indistinguishable (:data:`softsbi.core.defaults.K_SE`)
K_SE = defaults.K_SE


def gain(base: Score | None, new: Score | None) -> Gain | None:
    """How much lower ``new``'s summary energy score is than ``base``'s (:meth:`Gain.of`: the difference, its
    standard error and ``z``); None when either is missing."""
    return Gain.of(base, new)


def improves(base: Score | None, new: Score | None, k_se: float = K_SE) -> bool:
    """True when ``new`` scores more than ``k_se`` standard errors below ``base`` (:func:`gain`)."""
    g = gain(base, new)
    return g is not None and g.exceeds(k_se)


def _best(refits: Sequence[Refit]) -> Refit | None:
    return min(refits, key=lambda r: r.score.value, default=None)  # type: ignore[union-attr]


def decide(test: JointTest, nominal: Score | None, refits: Sequence[Refit], k_se: float = K_SE) -> Decision:
    """The verdict on a diagnosis' refits (module docstring): ``nothing-missing``, ``missing-effect`` (the
    named effect or pair, with the indistinguishable alternatives) or ``misspecified-unexplained`` (with the
    refit that explains a part, if any).

    Args:
        test: ``check``'s test of the nominal fit.
        nominal: the nominal fit's summary energy score.
        refits: the refits made (singles and at most one pair), each tested at the nominal test's level.
        k_se: standard-error margin of every score comparison.
    """
    if not test.misspecified:
        return Decision(verdict="nothing-missing")
    return replace(_decide(test, nominal, refits, k_se), gains=refit_gains(nominal, refits))


def refit_gains(nominal: Score | None, refits: Sequence[Refit]) -> tuple[RefitGain, ...]:
    """Every scored refit's :func:`gain` over the model it extends: the nominal fit for one effect, the refit of its
    first effect for a pair."""
    out = []
    for r in refits:
        base = nominal if len(r.effects) == 1 else next(
            (x.score for x in refits if x.effects == r.effects[:1]), None)
        g = gain(base, r.score)
        if g is not None:
            out.append(RefitGain(effects=r.effects, gain=g))
    return tuple(out)


def _better_singles(nominal: Score | None, refits: Sequence[Refit], k_se: float) -> list[Refit]:
    """The single refits that improve on the nominal fit (:func:`improves`) with their effect switched on."""
    return [r for r in refits if len(r.effects) == 1 and r.score is not None and improves(nominal, r.score, k_se)
            and not r.maybe_off]


def _decide(test: JointTest, nominal: Score | None, refits: Sequence[Refit], k_se: float) -> Decision:
    better = _better_singles(nominal, refits, k_se)
    good = [r for r in better if r.adequate]
    if good:
        best = _best(good)
        ties = tuple(r.effects for r in good if r is not best and not improves(r.score, best.score, k_se))
        return Decision(verdict="missing-effect", named=best.effects, alternatives=ties, gain=gain(nominal, best.score))
    base = _best(better)
    for pair in (r for r in refits if len(r.effects) == 2 and r.score is not None):
        if base is not None and set(base.effects) < set(pair.effects) and pair.adequate and not pair.maybe_off \
                and improves(base.score, pair.score, k_se):
            return Decision(verdict="missing-effect", named=pair.effects, gain=gain(base.score, pair.score))
    if base is None:
        return Decision(verdict="misspecified-unexplained")
    return Decision(verdict="misspecified-unexplained", partial=base.effects, gain=gain(nominal, base.score))


def to_refine(test: JointTest, nominal: Score | None, refits: Sequence[Refit], k_se: float = K_SE
              ) -> list[tuple[str, ...]]:
    """The refits to refine by sequential rounds (module docstring, step 3), lowest score first: the amortised single
    refits of a fit the test rejects that are adequate, improve on the nominal fit (:func:`improves`) and whose effect
    the data may leave off (:attr:`~softsbi.core.results.Refit.maybe_off`), not refined yet. The caller spends at
    most its refinement budget on the first ones."""
    if not test.misspecified:
        return []
    open_ = [r for r in refits if len(r.effects) == 1 and r.amortised and r.refined_from is None and r.adequate
             and r.score is not None and improves(nominal, r.score, k_se) and r.maybe_off]
    return [r.effects for r in sorted(open_, key=lambda r: r.score.value)]  # type: ignore[union-attr]


def refit_order(ranking: Sequence[Candidate], nominal: Score | None, k_se: float = K_SE) -> list[str]:
    """The named (non-generic) candidates in the order the refit budget goes to them.

    A candidate with amortised evidence (:attr:`~softsbi.core.results.Candidate.amortised`: its trained model's
    posterior predictive, scored as its refit will be) comes first when that score improves on the nominal fit's
    (:func:`improves`), lowest score first, and is left out otherwise: its refit's score estimates the same quantity,
    so it could not be named. The candidates without such evidence follow in the screening's order, those it
    screened."""
    named = [c for c in ranking if not c.generic]
    ahead = sorted((c for c in named if c.amortised is not None and improves(nominal, c.amortised, k_se)),
                   key=lambda c: c.amortised.value)  # type: ignore[union-attr]
    return [c.effect for c in ahead] + [c.effect for c in named if c.amortised is None and c.screened]


def next_refit(test: JointTest, ranking: Sequence[Candidate], nominal: Score | None, refits: Sequence[Refit],
               confirm: int, k_se: float = K_SE) -> tuple[str, ...] | None:
    """The refit to spend the budget on next, or None when the diagnosis is complete.

    First the top ``confirm`` candidates of :func:`refit_order`; then, when no single refit is adequate and
    improving, one pair: the improving single refit with the lowest score and the first named candidate of that
    refit's own screening (its check's ranking over the same family, less its effect), or, when its check screened
    nothing (a trained task's refit, checked by the omnibus test alone), the next improving single refit. Nothing
    for a fit the test does not reject.
    """
    if not test.misspecified or confirm <= 0:
        return None
    done = {frozenset(r.effects) for r in refits}
    for effect in refit_order(ranking, nominal, k_se)[:confirm]:
        if frozenset([effect]) not in done:
            return (effect,)
    if decide(test, nominal, refits, k_se).verdict == "missing-effect" or confirm < 2:
        return None
    better = _better_singles(nominal, refits, k_se)
    base = _best(better)
    if base is None:
        return None
    second = next((c.effect for c in base.ranking if c.screened and not c.generic and c.effect not in base.effects),
                  None)
    if second is None and not any(c.screened for c in base.ranking):
        # its check screened nothing (a trained task's refit, checked by the omnibus test alone): the next improving
        # single refit, lowest score first
        second = next((r.effects[0] for r in sorted(better, key=lambda r: r.score.value)  # type: ignore[union-attr]
                       if r is not base), None)
    if second is None or frozenset(base.effects + (second,)) in done:
        return None
    return base.effects + (second,)
