"""A task's diagnosis across its recordings: the decision for the set, from each recording's diagnosis and the refits
of the set's candidates on every recording. Pure functions of typed results (:mod:`softsbi.core.results`,
:mod:`softsbi.core.results.joint`); no simulation here.

The rule (``R`` recordings, ``R >= 3``; ``alpha`` and ``k_se`` as in a single diagnosis,
:mod:`~softsbi.workflows.criticism.decide`):

1. *Detect.* ``nothing-missing`` iff Fisher's method over the nominal fits' ``check`` p-values
   (:class:`~softsbi.core.results.joint.CombinedTest`: ``-2 sum ln p_r ~ chi^2_{2R}``) does not reject at ``alpha``.
2. *Propose.* The candidates compared on the set are refitted on every recording, so that their scores can be summed
   (:func:`set_candidates`: those the recordings' own diagnoses refitted, most often refitted first).
3. *Decide.* A candidate is named for the task when all three hold:
   - *improves*: its summary energy score is lower than the nominal model's, summed over the recordings, by more than
     ``k_se`` standard errors *paired over recordings*: ``d_r = S_nominal,r - S_candidate,r``, the standard error
     of ``sum d_r`` is ``sd(d_r) sqrt(R)`` (never below the scores' Monte-Carlo one,
     :meth:`~softsbi.core.results.Gain.paired`). This is the one-sample t statistic of the ``d_r``: one recording's
     large gain among ``R - 1`` null ones gives ``z`` about 1, however large it is, so it cannot name an effect for
     the set;
   - *adequate on the set*: Fisher's method over its refits' check p-values does not reject at ``alpha``;
   - *switched on*: more recordings' refits exclude the effect's off value than chance allows: a one-sided binomial
     test at ``alpha`` against the rate :data:`~softsbi.core.results.joint.CHANCE_EXCLUDED` per parameter
     (:class:`~softsbi.core.results.joint.SwitchedOn`).
   The qualifying candidate with the lowest summed score is named (``missing-effect``); the others whose summed
   score is not ``k_se`` paired standard errors above it are listed as indistinguishable. Otherwise
   ``misspecified-unexplained``, naming the improving, switched-on candidate with the lowest summed score as
   explaining a part.

With fewer than :data:`MIN_RECORDINGS` recordings the spread of the ``d_r`` cannot be judged, and the set is not
diagnosed.

*A rig* (recordings of several motions of one object and rig: the same simulator, model and observer, the scenarios
differing; at least :data:`MIN_RIG_RECORDINGS`) is decided by another rule, since the paired standard error assumes
every recording shows the effect alike, and across motions they do not (a sticky patch moves a wipe, not a lift: one
motion's large gain among null ones would have ``z`` about 1). With ``I_c`` the recordings whose motion informs ``c``
(:func:`informed_by_recording`: a 90% interval narrower than half the prior's, on the trained task's held-out
simulations, else on the recording's refit; every recording when none does), :func:`rig_candidate` and
:func:`decide_joint` name ``c`` when

- *improves*: ``sum_{r in I_c} d_r > k_se sqrt(sum_{r in I_c} se_r^2)``, each ``d_r`` in its recording's own nominal
  scale with its own Monte-Carlo standard error ``se_r`` (:meth:`~softsbi.core.results.Gain.of`): a single
  diagnosis' margin, applied to the evidence of the motions that inform the effect;
- *not contradicted*: no recording's refit scores worse than its nominal fit by more than ``k_se`` of its own
  standard errors;
- *adequate on every recording*: Fisher's method over all its refits' checks does not reject at ``alpha``;
- *switched on*: on ``I_c``, the one-sided binomial test of the recordings whose refit switches it on, against the
  chance rate, at the chance rate itself (:data:`~softsbi.core.results.joint.CHANCE_EXCLUDED` per parameter): one
  informing recording then decides it as its own diagnosis does, and several need more than chance allows.

Ties and the ranking compare summed scores over every recording with the Monte-Carlo standard errors.
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import replace
from typing import Sequence

from softsbi.core.errors import SoftsbiError
from softsbi.core.results.joint import CHANCE_EXCLUDED, CombinedTest, JointCandidate, SwitchedOn
from softsbi.core.results import Decision, Diagnosis, Gain, Refit, RefitGain

#: the fewest recordings whose spread of score gains a standard error can be judged from (two give one degree of
#: freedom: a standard error from two numbers is too rough to decide on)
MIN_RECORDINGS = 3
#: the fewest recordings of a rig (several motions): each recording's evidence carries its own standard errors
MIN_RIG_RECORDINGS = 2


def check_recordings(n: int, rig: bool = False) -> None:
    """Refuse a set of fewer than :data:`MIN_RECORDINGS` recordings of one task (:data:`MIN_RIG_RECORDINGS` of a
    rig's several motions), in one line.

    Raises:
        SoftsbiError: too few recordings.
    """
    if rig and n < MIN_RIG_RECORDINGS:
        raise SoftsbiError(f"a rig's diagnosis across its motions needs {MIN_RIG_RECORDINGS} recordings or more (got "
                           f"{n}); diagnose the run alone (`softsbi diagnose RUN`)")
    if not rig and n < MIN_RECORDINGS:
        raise SoftsbiError(f"a task's diagnosis across its recordings needs {MIN_RECORDINGS} recordings or more (got "
                           f"{n}): the standard error of a summed score gain comes from its spread across recordings, "
                           f"which fewer cannot judge; diagnose each run alone (`softsbi diagnose RUN`)")


def nominal_test(recordings: Sequence[Diagnosis], alpha: float) -> CombinedTest:
    """Fisher's method over the recordings' nominal ``check`` tests (detect, on the set)."""
    return CombinedTest(p_values=tuple(d.test.p_value for d in recordings),
                        resolutions=tuple(d.test.resolution for d in recordings), alpha=alpha)


def set_candidates(recordings: Sequence[Diagnosis], confirm: int) -> tuple[str, ...]:
    """The candidates to compare on the set: the single effects the recordings' own diagnoses refitted (each
    recording's budget went to its most promising candidates, :func:`~softsbi.workflows.criticism.decide.refit_order`),
    the ones refitted on most recordings first, then by the screening's share of the residual summed over the
    recordings; the first ``confirm`` (the refit budget, now per recording of the set)."""
    count = Counter(r.effects[0] for d in recordings for r in d.refits if len(r.effects) == 1)
    share = {e: sum(max(c.explained or 0.0, 0.0) for d in recordings for c in d.ranking if c.effect == e)
             for e in count}
    return tuple(sorted(count, key=lambda e: (-count[e], -share[e], e))[:max(confirm, 0)])


def joint_candidate(effect: str, recordings: Sequence[Diagnosis], refits: Sequence[Refit],
                    alpha: float) -> JointCandidate:
    """Candidate ``effect`` on the set from its refit on each recording (``refits``, in the order of
    ``recordings``): its summed gain over the nominal model (paired over recordings), Fisher's method over its refits'
    checks, and the binomial test of the recordings that switch it on (module docstring)."""
    if len(refits) != len(recordings):
        raise ValueError(f"{effect}: {len(refits)} refits for {len(recordings)} recordings")
    gain = None
    if all(d.nominal is not None for d in recordings) and all(r.score is not None for r in refits):
        ds = [d.nominal.value - r.score.value for d, r in zip(recordings, refits)]  # type: ignore[union-attr]
        mc = math.sqrt(sum(d.nominal.se ** 2 + r.score.se ** 2 for d, r in zip(recordings, refits)))  # type: ignore
        gain = Gain.paired(ds, mc)
    own = [[e for e in r.estimates if e.effect in ("", effect)] for r in refits]
    n_params = max((len(o) for o in own), default=1) or 1
    on = SwitchedOn(on=tuple(any(e.may_be_off is False for e in o) for o in own),
                    chance=min(1.0, CHANCE_EXCLUDED * n_params), alpha=alpha)
    adequacy = CombinedTest(p_values=tuple(r.test.p_value for r in refits),
                            resolutions=tuple(r.test.resolution for r in refits), alpha=alpha)
    return JointCandidate(effect=effect, refits=tuple(refits), gain=gain, adequacy=adequacy, on=on)


def rig_candidate(effect: str, recordings: Sequence[Diagnosis], refits: Sequence[Refit], alpha: float,
                  k_se: float) -> JointCandidate:
    """Candidate ``effect`` on a rig's recordings (several motions) from its refit on each (``refits``, in the order
    of ``recordings``), by the rig's rule (module docstring): its gain summed over the recordings that inform it with
    their own Monte-Carlo standard errors, the recordings that contradict it, Fisher's method over all its refits'
    checks, and the binomial test of the informing recordings that switch it on at the chance rate."""
    if len(refits) != len(recordings):
        raise ValueError(f"{effect}: {len(refits)} refits for {len(recordings)} recordings")
    informs = tuple(informed_by_recording(effect, d, r) for d, r in zip(recordings, refits))
    idx = [i for i, x in enumerate(informs) if x] or list(range(len(recordings)))
    gains = [Gain.of(d.nominal, r.score) for d, r in zip(recordings, refits)]
    gain = None
    if all(g is not None for g in gains):
        gain = Gain.summed(sum(gains[i].difference for i in idx),  # type: ignore[union-attr]
                           math.sqrt(sum(gains[i].se ** 2 for i in idx)))  # type: ignore[union-attr]
    worse = tuple(i for i, g in enumerate(gains) if g is not None and g.z < -k_se)
    # as each recording's own diagnosis decides it (Refit.maybe_off: its calibrated test at CHANCE_EXCLUDED, else
    # the interval rule, CHANCE_EXCLUDED per parameter)
    per = [1 if refits[i].off_test is not None else
           max(len([e for e in refits[i].estimates if e.effect in ("", effect)]), 1) for i in idx]
    chance = min(1.0, CHANCE_EXCLUDED * max(per))
    on = SwitchedOn(on=tuple(effect not in refits[i].maybe_off for i in idx), chance=chance, alpha=chance)
    adequacy = CombinedTest(p_values=tuple(r.test.p_value for r in refits),
                            resolutions=tuple(r.test.resolution for r in refits), alpha=alpha)
    return JointCandidate(effect=effect, refits=tuple(refits), gain=gain, adequacy=adequacy, on=on,
                          informs=informs, worse_on=worse)


def informed_by_recording(effect: str, recording: Diagnosis, refit: Refit) -> bool:
    """Whether a recording's motion informs ``effect``: one criterion, a 90% interval narrower than half the prior's
    for some parameter of the effect, read where it is measured: on a trained task (an amortised refit, or one
    refined from it), from the task's held-out simulations (its report: the recording's
    :attr:`~softsbi.core.results.Diagnosis.uninformed`); otherwise from this recording's refit
    (:attr:`~softsbi.core.results.Estimate.informed`; unknown counts as informed)."""
    trained = refit.amortised or (refit.refined_from is not None and refit.refined_from.amortised)
    if trained or effect in recording.uninformed:
        return effect not in recording.uninformed
    own = [e.informed for e in refit.estimates if e.effect in ("", effect)]
    return not own or any(x is not False for x in own)


def paired_between(a: JointCandidate, b: JointCandidate) -> Gain | None:
    """How much lower ``b``'s summed score is than ``a``'s, paired over recordings (a rig's: summed over every
    recording with the Monte-Carlo standard errors; None: a score is missing)."""
    if a.score is None or b.score is None:
        return None
    ds = [x.score.value - y.score.value for x, y in zip(a.refits, b.refits)]  # type: ignore[union-attr]
    mc = math.sqrt(sum(x.score.se ** 2 + y.score.se ** 2 for x, y in zip(a.refits, b.refits)))  # type: ignore
    return Gain.summed(sum(ds), mc) if a.rig else Gain.paired(ds, mc)


def ranked(candidates: Sequence[JointCandidate]) -> tuple[JointCandidate, ...]:
    """The candidates by summed score, lowest first (unscored last), each with its difference to the best
    (:attr:`~softsbi.core.results.joint.JointCandidate.to_best`)."""
    order = sorted(candidates, key=lambda c: (c.score is None, c.score if c.score is not None else 0.0, c.effect))
    best = order[0] if order and order[0].score is not None else None
    return tuple(replace(c, to_best=None if best is None or c is best else paired_between(c, best)) for c in order)


def decide_joint(test: CombinedTest, candidates: Sequence[JointCandidate], k_se: float, rig: bool = False) -> Decision:
    """The verdict for the set (module docstring).

    Args:
        test: Fisher's method over the nominal fits' checks (:func:`nominal_test`).
        candidates: the candidates refitted on every recording (:func:`joint_candidate`).
        k_se: the standard-error margin of every score comparison (paired over recordings).
        rig: the recordings are a rig's several motions (its candidates from :func:`rig_candidate`).

    Raises:
        SoftsbiError: fewer than :data:`MIN_RECORDINGS` recordings (:data:`MIN_RIG_RECORDINGS` of a rig).
    """
    check_recordings(len(test.p_values), rig)
    if not test.rejects:
        return Decision(verdict="nothing-missing")
    gains = tuple(RefitGain(effects=(c.effect,), gain=c.gain) for c in candidates if c.gain is not None)
    scored = [c for c in candidates if c.score is not None]
    good = sorted((c for c in scored if not c.fails(k_se)), key=lambda c: c.score)  # type: ignore[arg-type]
    if good:
        best = good[0]
        ties = tuple((c.effect,) for c in good[1:] if not ((g := paired_between(c, best)) and g.exceeds(k_se)))
        return Decision(verdict="missing-effect", named=(best.effect,), alternatives=ties, gain=best.gain,
                        gains=gains)
    part = sorted((c for c in scored if c.improves(k_se) and c.on.switched_on), key=lambda c: c.score)  # type: ignore
    if part:
        return Decision(verdict="misspecified-unexplained", partial=(part[0].effect,), gain=part[0].gain, gains=gains)
    return Decision(verdict="misspecified-unexplained", gains=gains)

