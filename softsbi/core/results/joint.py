"""The typed result of a task's diagnosis across its recordings (``softsbi diagnose RUN RUN ... --out DIR``,
:mod:`softsbi.workflows.criticism.joint`): :class:`JointDiagnosis`, with one :class:`JointCandidate` per candidate
effect refitted on every recording, and the two tests it combines the recordings with (:class:`CombinedTest`,
:class:`SwitchedOn`).

Its JSON form (``joint-diagnosis.json``) is written and read like every result of :mod:`softsbi.core.results`. Scores
are summary energy scores (dimensionless, :class:`~softsbi.core.results.Score`), each recording's in its own nominal
fit's scale.
"""
from __future__ import annotations

import math
import statistics
from dataclasses import dataclass, field
from pathlib import PurePath
from typing import Any, Mapping, Sequence

from softsbi.core.results import Decision, Diagnosis, Estimate, Gain, Refit

#: the chance that a calibrated 90% interval excludes a parameter's true value (5% on each side): the rate at which
#: a recording's refit shows an effect that is off as switched on, per parameter of the effect; for an off value at
#: a prior bound, the Bayes factor against it that excludes it (whose chance rate is at most this)
CHANCE_EXCLUDED = 0.10
#: a candidate's criteria for the set (:meth:`JointCandidate.fails`); the last is a rig's only (several motions)
CRITERIA = ("improves", "adequate", "switched on", "not contradicted")


def chi2_sf_even(x: float, df: int) -> float:
    """``P(X >= x)`` for ``X ~ chi^2`` with an even number ``df`` of degrees of freedom (closed form:
    ``exp(-x/2) sum_{k < df/2} (x/2)^k / k!``)."""
    if x <= 0:
        return 1.0
    h, term, total = x / 2.0, 1.0, 1.0
    for k in range(1, df // 2):
        term *= h / k
        total += term
    return min(1.0, math.exp(-h) * total)


def binomial_tail(k: int, n: int, q: float) -> float:
    """``P(X >= k)`` for ``X ~ Binomial(n, q)``."""
    if k <= 0:
        return 1.0
    return min(1.0, sum(math.comb(n, j) * q ** j * (1 - q) ** (n - j) for j in range(k, n + 1)))


@dataclass(frozen=True, kw_only=True)
class CombinedTest:
    """Fisher's method over the recordings' ``check`` tests: ``X = -2 sum_r ln p_r ~ chi^2_{2R}`` when every
    recording's model is right and the recordings are independent. Each ``p_r`` is a Monte-Carlo p-value no lower than
    its resolution (:attr:`~softsbi.core.results.JointTest.p_value`), hence no smaller in distribution than a uniform
    one, so the combined test is valid at its level (conservative), as each check is.

    Attributes:
        p_values: each recording's joint test p-value, in the runs' order.
        resolutions: the smallest p-value each recording's nulls can give (:attr:`~softsbi.core.results.JointTest.resolution`).
        alpha: the level it decides at.
    """

    p_values: tuple[float, ...]
    resolutions: tuple[float, ...]
    alpha: float

    @property
    def statistic(self) -> float:
        """``-2 sum_r ln p_r``."""
        return -2.0 * sum(math.log(p) for p in self.p_values)

    @property
    def df(self) -> int:
        """``2R``."""
        return 2 * len(self.p_values)

    @property
    def p_value(self) -> float:
        """The combined p-value ``P(chi^2_{2R} >= statistic)``."""
        return chi2_sf_even(self.statistic, self.df)

    @property
    def resolution(self) -> float:
        """The smallest combined p-value the recordings' nulls can give (every ``p_r`` at its resolution)."""
        return chi2_sf_even(-2.0 * sum(math.log(p) for p in self.resolutions), self.df)

    @property
    def rejects(self) -> bool:
        """True when the combined p-value is at most :attr:`alpha`."""
        return self.p_value <= self.alpha


@dataclass(frozen=True, kw_only=True)
class SwitchedOn:
    """Is an effect switched on across the recordings? A one-sided binomial test of the number of recordings whose
    refit excludes the effect's off value (at least one of its parameters excludes it at the level
    :data:`CHANCE_EXCLUDED`, :attr:`~softsbi.core.results.Estimate.may_be_off` False) against :attr:`chance`, the
    rate at which that happens when the effect is off: :data:`CHANCE_EXCLUDED` per parameter (Bonferroni over the
    effect's parameters, at most 1).

    Attributes:
        on: per recording, in the runs' order: its refit excludes the off value.
        chance: the chance rate per recording when the effect is off.
        alpha: the level it decides at.
    """

    on: tuple[bool, ...]
    chance: float
    alpha: float

    @property
    def count(self) -> int:
        """Recordings whose refit switches the effect on."""
        return sum(self.on)

    @property
    def p_value(self) -> float:
        """``P(X >= count)`` for ``X ~ Binomial(R, chance)``."""
        return binomial_tail(self.count, len(self.on), self.chance)

    @property
    def switched_on(self) -> bool:
        """True when :attr:`p_value` is at most :attr:`alpha`: more recordings switch it on than chance allows."""
        return self.p_value <= self.alpha


@dataclass(frozen=True, kw_only=True)
class JointCandidate:
    """One candidate effect refitted on every recording of the set.

    Attributes:
        effect: the effect's name.
        refits: its refit on each recording (the nominal model with the effect added), in the runs' order.
        gain: how much lower its summary energy score is than the nominal model's, summed over the recordings, with the
            standard error paired over them (:meth:`~softsbi.core.results.Gain.paired`); None when a recording has no
            score.
        adequacy: Fisher's method over its refits' check p-values (it is adequate on the set when this does not
            reject).
        on: whether the data switch its effect on across the set (:class:`SwitchedOn`).
        to_best: how much lower the best candidate's summed score is than this one's (paired, as ``gain``); None for
            the best one, or when a recording has no score.
        informs: a rig's (recordings of several motions) only: per recording, in the runs' order, whether its
            motion informs the effect (:func:`~softsbi.workflows.criticism.joint_decide.informed_by_recording`);
            its ``gain`` and ``on`` are then over the recordings that inform it
            (every recording when none does), the gain's standard error from the recordings' own Monte-Carlo
            standard errors (:func:`~softsbi.workflows.criticism.joint_decide.rig_candidate`). Empty: one task's
            recordings (the paired rule).
        worse_on: a rig's only: the recordings whose refit scores worse than their nominal fit by more than ``k_se``
            of their own standard errors (the effect contradicted there).
        combined: a rig's only: each effect parameter's posterior combined over the recordings that inform it (the
            product of their marginal posteriors: :func:`~softsbi.workflows.criticism.joint.combined_estimates`).
    """

    effect: str
    refits: tuple[Refit, ...]
    gain: Gain | None
    adequacy: CombinedTest
    on: SwitchedOn
    to_best: Gain | None = None
    informs: tuple[bool, ...] = ()
    worse_on: tuple[int, ...] = ()
    combined: tuple[Estimate, ...] = ()

    @property
    def rig(self) -> bool:
        """Decided by the rig's rule (recordings of several motions), not the task's."""
        return bool(self.informs)

    @property
    def informed_by(self) -> tuple[int, ...]:
        """A rig's recordings (indices) whose evidence decides it: those that inform it, every one when none does."""
        idx = tuple(i for i, x in enumerate(self.informs) if x)
        return idx or tuple(range(len(self.refits)))

    @property
    def score(self) -> float | None:
        """Its summary energy score summed over the recordings (None when a refit has none)."""
        if any(r.score is None for r in self.refits):
            return None
        return float(sum(r.score.value for r in self.refits))  # type: ignore[union-attr]

    @property
    def adequate(self) -> bool:
        """Adequate on the set: Fisher's method over its refits' checks does not reject."""
        return not self.adequacy.rejects

    @property
    def adequate_on(self) -> tuple[int, ...]:
        """The recordings (indices in the runs' order) where its own refit's check does not reject."""
        return tuple(i for i, r in enumerate(self.refits) if r.adequate)

    @property
    def parameters(self) -> tuple[str, ...]:
        """Its parameters' names, as the refits estimate them."""
        names: list[str] = []
        for r in self.refits:
            names += [e.name for e in r.estimates if e.effect in ("", self.effect) and e.name not in names]
        return tuple(names)

    def improves(self, k_se: float) -> bool:
        """Its summed gain over the nominal model exceeds ``k_se`` standard errors paired over recordings."""
        return self.gain is not None and self.gain.exceeds(k_se)

    def fails(self, k_se: float) -> tuple[str, ...]:
        """The criteria for the set it fails, in the rule's order (:data:`CRITERIA`; empty: it qualifies)."""
        return tuple(name for name, ok in zip(CRITERIA, (self.improves(k_se), self.adequate, self.on.switched_on,
                                                         not self.worse_on)) if not ok)

    def estimates(self, name: str) -> tuple[float | None, ...]:
        """Parameter ``name``'s posterior mean on each recording (None where the refit lacks it)."""
        return tuple(next((e.mean for e in r.estimates if e.name == name), None) for r in self.refits)

    def spread(self, name: str) -> tuple[float, float, float] | None:
        """Parameter ``name``'s estimates across the recordings: ``(median, min, max)``; None when none."""
        v = [x for x in self.estimates(name) if x is not None]
        return (float(statistics.median(v)), min(v), max(v)) if v else None


@dataclass(frozen=True, kw_only=True)
class JointDiagnosis:
    """The result of a task's diagnosis across its recordings (:func:`softsbi.workflows.criticism.joint.diagnose_runs`).

    Attributes:
        runs: the nominal fits' run directories, one per recording.
        recordings: each recording's own diagnosis (its own verdict, cloth parameters and refits), in the runs' order.
        candidates: the candidates refitted on every recording, best summed score first.
        test: Fisher's method over the nominal fits' checks (detect, on the set).
        decision: the verdict for the set (its ``named``, ``alternatives``, ``partial`` and ``gain`` as a single
            diagnosis' :class:`~softsbi.core.results.Decision`, the gains summed and paired over recordings).
        alpha, k_se, confirm: the level of every test, the standard-error margin and the refit budget.
        simulations: simulations spent by the per-recording diagnoses and the scales of the set's refits (refits'
            fits excluded).
        scenarios: each recording's scenario (motion), in the runs' order; more than one: a rig's diagnosis.
        key: what determines the result, so that a stored result is reused only for it.
        seconds: wall time.
    """

    runs: tuple[str, ...]
    recordings: tuple[Diagnosis, ...]
    candidates: tuple[JointCandidate, ...]
    test: CombinedTest
    decision: Decision
    alpha: float
    k_se: float
    confirm: int
    simulations: int = 0
    key: Mapping[str, Any] = field(default_factory=dict)
    seconds: float = 0.0
    scenarios: tuple[str, ...] = ()

    @property
    def rig(self) -> bool:
        """Recordings of several motions (scenarios) of one rig, decided by the rig's rule."""
        return len(set(self.scenarios)) > 1

    @property
    def verdict(self) -> str:
        """The set's verdict."""
        return self.decision.verdict

    @property
    def nominal(self) -> float | None:
        """The nominal model's summary energy score summed over the recordings (None when one has none)."""
        if any(d.nominal is None for d in self.recordings):
            return None
        return float(sum(d.nominal.value for d in self.recordings))  # type: ignore[union-attr]

    @property
    def family(self) -> tuple[str, ...]:
        """The candidates its recordings' diagnoses ranked, generic force terms aside (every recording ranks the same
        family): the effects a verdict may leave undecided."""
        return self.recordings[0].family if self.recordings else ()

    @property
    def uninformed(self) -> dict[str, float]:
        """The trained candidates no recording's task informs (each recording's
        :attr:`~softsbi.core.results.Diagnosis.uninformed`), by effect: the smallest width ratio over the recordings.
        A candidate one recording's task informs, or that one recording has no trained task of, is left out."""
        maps = [d.uninformed for d in self.recordings]
        if not maps:
            return {}
        return {e: min(m[e] for m in maps) for e in maps[0] if all(e in m for m in maps[1:])}

    def candidate(self, effect: str) -> JointCandidate | None:
        """The row of ``effect``, or None."""
        return next((c for c in self.candidates if c.effect == effect), None)

    def named_by(self, effect: str) -> tuple[int, ...]:
        """The recordings (indices) whose own diagnosis names ``effect`` (alone)."""
        return tuple(i for i, d in enumerate(self.recordings) if d.decision.named == (effect,))


def short_names(runs: Sequence[str]) -> tuple[str, ...]:
    """Each run's folder name, or its last two parts where two runs share a name."""
    paths = [PurePath(r) for r in runs]
    names = [p.name for p in paths]
    return tuple(f"{p.parent.name}/{n}" if names.count(n) > 1 else n for p, n in zip(paths, names))
