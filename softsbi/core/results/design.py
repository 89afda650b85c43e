"""The typed result of ``softsbi design RUN`` (:mod:`softsbi.workflows.criticism.design`): which motion to record next
so that the candidates a diagnosis left undecided can be decided. One :class:`MotionEffect` per motion and undecided
effect, and the motions ranked (:class:`Design`).

Its JSON form (``design.json``) is written and read like every result of :mod:`softsbi.core.results`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

from softsbi.core.defaults import INFORMED_MAX_RATIO
from softsbi.core.results import Diagnosis
from softsbi.core.results.joint import JointDiagnosis

#: the sources of a cell's width ratio
TRAINED, LINEAR = "trained task", "linear estimate"


@dataclass(frozen=True, kw_only=True)
class MotionEffect:
    """How well one recording of ``motion`` would inform ``effect``.

    Attributes:
        motion: the motion (scenario) name.
        effect: the candidate effect.
        width_ratio: the effect's best-informed parameter's 90% interval width over its prior's (the smallest over
            the effect's parameters, in the unit cube): on a trained task of the motion, the median over its
            held-out simulations (``source`` :data:`TRAINED`); otherwise the linearised Gaussian (Laplace)
            approximation at the fit's cloth (:data:`LINEAR`, :func:`~softsbi.workflows.criticism.design.linear_widths`);
            None when it could not be estimated (``error`` says why).
        source: :data:`TRAINED` or :data:`LINEAR`.
        bound: the linear estimate's width ratio itself, where it was computed (a :data:`LINEAR` cell's
            ``width_ratio`` is it scaled by the design's ``efficiency``); None otherwise.
        error: why no width ratio (a simulation failed), else None.
    """

    motion: str
    effect: str
    width_ratio: float | None
    source: str
    bound: float | None = None
    error: str | None = None

    @property
    def informs(self) -> bool:
        """The motion informs the effect: some parameter's 90% interval at most :data:`INFORMED_MAX_RATIO` of the
        prior's."""
        return self.width_ratio is not None and self.width_ratio <= INFORMED_MAX_RATIO


@dataclass(frozen=True, kw_only=True)
class Design:
    """Which motion to record next (:func:`~softsbi.workflows.criticism.design.design_run`).

    Attributes:
        run: the fit whose diagnosis left the candidates undecided, or the folder of a diagnosis across several
            recordings (``joint-diagnosis.json``).
        motion: that fit's motion (scenario); a joint diagnosis's: its first recording's.
        undecided: the candidates to decide, each with why it is undecided (``"not informed by this task"``,
            ``"indistinguishable"``, ``"unexplained"``, or ``"no diagnosis yet"``).
        cells: one per motion and undecided candidate.
        motions: the motions, best first: most undecided candidates informed, then the smallest summed width ratio.
        simulations: simulations of the linear estimates (0: every cell from trained tasks).
        efficiency: the trained estimator's widths over the bound's on the fit's own motion (the median ratio,
            :func:`~softsbi.workflows.criticism.design.efficiency_factor`), by which the other motions' bounds are
            scaled; None when no trained task of the fit's motion measures it (the bounds stand unscaled).
        key: what determines the result, so that a stored result is reused only for it.
        seconds: wall time.
        recorded: the motions already recorded, in order (a rig's several; empty: ``motion`` alone).
    """

    run: str
    motion: str
    undecided: Mapping[str, str]
    cells: tuple[MotionEffect, ...]
    motions: tuple[str, ...]
    simulations: int = 0
    efficiency: float | None = None
    key: Mapping[str, Any] = field(default_factory=dict)
    seconds: float = 0.0
    recorded: tuple[str, ...] = ()

    @property
    def recorded_motions(self) -> tuple[str, ...]:
        """The motions already recorded: :attr:`recorded`, or the fit's own alone."""
        return self.recorded or (self.motion,)

    @property
    def informed_already(self) -> tuple[str, ...]:
        """The undecided candidates some recorded motion informs, in :attr:`undecided`'s order."""
        done = {e for m in self.recorded_motions for e in self.informed(m)}
        return tuple(e for e in self.undecided if e in done)

    def cell(self, motion: str, effect: str) -> MotionEffect | None:
        """The cell of ``motion`` and ``effect``, or None."""
        return next((c for c in self.cells if c.motion == motion and c.effect == effect), None)

    def informed(self, motion: str) -> tuple[str, ...]:
        """The undecided candidates ``motion`` informs, in :attr:`undecided`'s order."""
        return tuple(e for e in self.undecided if (c := self.cell(motion, e)) is not None and c.informs)

    @property
    def best(self) -> str | None:
        """The motion to record next: the best-ranked not yet recorded that informs an undecided candidate no
        recorded motion does; None when none does."""
        own = set(self.informed_already)
        return next((m for m in self.motions if m not in self.recorded_motions and set(self.informed(m)) - own), None)


def undecided_candidates(d: Diagnosis | JointDiagnosis | None, family: Sequence[str]) -> dict[str, str]:
    """The candidates a diagnosis ``d`` leaves undecided, each with why, in ``family``'s order then the rest: those its
    task does not inform (when the check rejects), the named one and those indistinguishable from it, and, when the
    verdict is ``misspecified-unexplained``, every candidate of ``family``. A check that does not reject, or one named
    effect with nothing beside it, leaves only the uninformed ones. Without a diagnosis (None): the whole family.
    A diagnosis across several recordings (:class:`~softsbi.core.results.joint.JointDiagnosis`) by the same rule on
    the set: its combined check, its verdict, and the candidates no recording's task informs."""
    if d is None:
        return {e: "no diagnosis yet" for e in family}
    if not (d.test.rejects if isinstance(d, JointDiagnosis) else d.test.misspecified):
        return {}
    out: dict[str, str] = {}
    if d.verdict == "misspecified-unexplained":
        out.update({e: "unexplained" for e in family})
    if d.decision.alternatives:
        out.update({e: "indistinguishable" for x in (d.decision.named, *d.decision.alternatives) for e in x})
    out.update({e: "not informed by this task" if isinstance(d, Diagnosis) else "not informed by these tasks"
                for e in d.uninformed})
    return out
