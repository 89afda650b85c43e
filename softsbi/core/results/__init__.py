"""Typed results of the model-error workflow: ``check``, ``diagnose`` and ``compare``.

Every result is a frozen dataclass. Workflows return them, :mod:`softsbi.report` renders sentences and
figures from them, and their JSON form (``check.json``, ``diagnosis.json``, ``compare.json``) carries a
schema version (:data:`SCHEMA`). :func:`to_json` / :func:`from_json` (:mod:`softsbi.core.jsonfile`) convert any of
them, nested ones included, from their type hints alone.

The package's modules hold the other typed results: a fit's ``report.json``, ``calibration.json`` and a task's
training report (:mod:`softsbi.core.results.fitreport`), the diagnosis across a task's recordings
(:mod:`softsbi.core.results.joint`) and ``compare``'s result (:mod:`softsbi.core.results.comparison`).

Units: distances in metres, like every stored number of softsbi.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, Mapping, Sequence

from softsbi.core.defaults import INFORMED_MAX_RATIO
# the JSON form and the result files' writer and reader (softsbi.core.jsonfile), importable from here too
from softsbi.core.jsonfile import (RENAMED, SCHEMA, UPGRADED, ResultDamaged, ResultUnwritable, check_result_path,  # noqa: F401
                                   from_json, read_json, read_result, to_json, write_json_atomic, write_result)



#: the verdicts of a diagnosis, in the order they are tested
VERDICTS = ("nothing-missing", "missing-effect", "misspecified-unexplained")


@dataclass(frozen=True, kw_only=True)
class MCPValue:
    """A Monte-Carlo p-value ``(exceed + 1) / (n + 1)`` (Davison & Hinkley 1997, eq. 4.11).

    Attributes:
        exceed: null simulations whose statistic is at least the observed one.
        n: null simulations.
    """

    exceed: int
    n: int

    @property
    def value(self) -> float:
        """``(exceed + 1) / (n + 1)``, never below :attr:`floor`."""
        return (self.exceed + 1) / (self.n + 1)

    @property
    def p_value(self) -> float:
        """The same as :attr:`value` (the name :attr:`JointTest.p_value` has): the probability, under the null of
        posterior-predictive simulations, of a statistic at least as extreme as the observed one."""
        return self.value

    @property
    def floor(self) -> float:
        """The resolution ``1 / (n + 1)``: the smallest p-value ``n`` simulations can give."""
        return 1.0 / (self.n + 1)

    @property
    def at_floor(self) -> bool:
        """True when the observation lies beyond every null simulation."""
        return self.exceed == 0


@dataclass(frozen=True, kw_only=True)
class JointTest:
    """``check``'s misspecification test: is the measurement inside the posterior predictive distribution?

    Two Monte-Carlo tests on one null: the *omnibus* test (mean squared standardised deviation of the summary
    statistics, a departure in any direction) and the *directional* test (the largest Westfall-Young max-T statistic
    over the candidate family: a departure along an effect's sensitivity), combined by the null's own distribution
    of the smaller of their p-values (:attr:`combined`, Westfall & Young's min-P:
    :func:`~softsbi.workflows.criticism.statistics.min_p_combined`). The null is the run's posterior-predictive
    rollouts, or for a fit of a trained task the task's replicate recordings, each refitted and checked the same
    way (:attr:`calibrated`). Results written before the combination (no :attr:`combined`) keep their Bonferroni
    p-value ``min(1, k min(p_omnibus, p_directional))``.

    Attributes:
        omnibus: the omnibus test's p-value.
        directional: the directional test's max-T adjusted p-value; None without a family (or when the
            simulation at the posterior median failed).
        directional_effect: the effect the directional test points along.
        family: the candidate effects of the directional test.
        alpha: the level the test decides at.
        max_null: the cap of the adaptive null.
        statistic: the omnibus statistic of the measurement (dimensionless).
        calibrated: the omnibus p-value is calibrated against replicate recordings of the run's trained task
            refitted and checked the same way (:mod:`~softsbi.workflows.criticism.check_null`), its ``n`` their number;
            else it is the posterior predictive p-value against the run's own rollouts (conservative).
        directional_skipped: why the directional test did not run (no candidate effects, or none could be
            screened, and why); None when it ran. The p-value is then the omnibus test's alone.
        combined: the two tests' min-P combined p-value against the null (its ``n``: null rollouts, or replicate
            recordings when :attr:`calibrated`); None with one test.
        directional_statistic: the directional test's statistic of the measurement (the screening's max-T maximum,
            dimensionless); None without it.
    """

    omnibus: MCPValue
    directional: MCPValue | None
    directional_effect: str | None
    family: tuple[str, ...]
    alpha: float
    max_null: int
    statistic: float = float("nan")
    calibrated: bool = False
    directional_skipped: str | None = None
    combined: MCPValue | None = None
    directional_statistic: float | None = None

    @property
    def tests(self) -> int:
        """Number of combined tests ``k`` (1 or 2)."""
        return 1 if self.directional is None else 2

    @property
    def n_null(self) -> int:
        """The null the joint p-value is computed against (the combination's, else the larger of the two tests'):
        it sets the joint p-value's floor :attr:`resolution`."""
        if self.combined is not None:
            return self.combined.n
        return max(self.omnibus.n, 0 if self.directional is None else self.directional.n)

    @property
    def deciding(self) -> str:
        """``"omnibus"`` or ``"directional"``: the test with the smaller p-value."""
        if self.directional is not None and self.directional.value < self.omnibus.value:
            return "directional"
        return "omnibus"

    @property
    def best(self) -> MCPValue:
        """The :attr:`deciding` test's own p-value."""
        return self.directional if self.deciding == "directional" and self.directional else self.omnibus

    @property
    def p_value(self) -> float:
        """The joint p-value: :attr:`combined`'s, else (one test, or a result written before the combination) the
        Bonferroni one; never below :attr:`resolution`."""
        if self.combined is not None:
            return self.combined.value
        return min(1.0, self.tests * self.best.value)

    @property
    def resolution(self) -> float:
        """The smallest joint p-value the null can give: ``1 / (n + 1)`` of the combination, ``k / (n + 1)``
        with Bonferroni (``n``: :attr:`n_null`)."""
        return (1 if self.combined is not None else self.tests) / (self.n_null + 1)

    @property
    def misspecified(self) -> bool:
        """True when the test rejects at :attr:`alpha` (``p <= alpha``)."""
        return self.p_value <= self.alpha


@dataclass(frozen=True, kw_only=True)
class Candidate:
    """One candidate effect: its linearised screening and, on a task trained with its model, its amortised evidence.

    Attributes:
        effect: the effect's name.
        kind: ``"physics"`` or ``"sensor"``.
        generic: a generic force term (describes a residual, names no cause).
        description: the effect's one line.
        explained: fraction of the residual sum of squares it explains (None when its screening failed).
        adjusted: its max-T adjusted Monte-Carlo p-value over the family (None when its screening failed).
        estimate: the linearised estimate of its parameters (physical units).
        error: why its screening failed, else None.
        amortised: the summary energy score of its trained model's amortised posterior predictive, in the nominal
            fit's scale (:func:`softsbi.workflows.criticism.evidence.amortised_scores`; ``diagnose`` only), else None.
    """

    effect: str
    kind: str = "physics"
    generic: bool = False
    description: str = ""
    explained: float | None = None
    adjusted: MCPValue | None = None
    estimate: Mapping[str, float] = field(default_factory=dict)
    error: str | None = None
    amortised: Score | None = None

    @property
    def screened(self) -> bool:
        """True when its screening statistic was computed."""
        return self.adjusted is not None


@dataclass(frozen=True, kw_only=True)
class EnergyScore:
    """The Chamfer energy score (``check``, ``compare``): the energy score of a posterior predictive distribution
    against the measured clouds (Gneiting & Raftery 2007, eq. 22), with the fit's Chamfer distance as the distance:
    ``ES = chamfer - spread / 2`` (m).

    Attributes:
        energy_m: the score (lower is better).
        se_m: its Monte-Carlo standard error (jackknife over rollouts).
        chamfer_m: mean Chamfer between a rollout and the measurement (the posterior-predictive Chamfer).
        spread_m: mean Chamfer between two rollouts.
        n: rollouts scored.
    """

    energy_m: float
    se_m: float
    chamfer_m: float
    spread_m: float
    n: int


@dataclass(frozen=True, kw_only=True)
class Score:
    """The summary energy score (``diagnose``): the energy score of a posterior predictive distribution of ``check``'s
    summary statistics against the measurement's (Gneiting & Raftery 2007, eq. 22, Euclidean distance):
    ``mean_i |z_i - z| - mean_ij |z_i - z_j| / 2`` with ``z`` the summaries divided by one fixed scale per summary for
    every model compared (the nominal fit's posterior-predictive standard deviation, floored: the scale of ``check``'s
    omnibus test). A strictly proper score: in expectation no forecast scores lower than the distribution the
    measurement comes from.

    Attributes:
        value: the score (dimensionless; lower is better).
        se: its Monte-Carlo standard error (jackknife over rollouts).
        n: rollouts scored.
    """

    value: float
    se: float
    n: int


@dataclass(frozen=True, kw_only=True)
class Estimate:
    """A refit's posterior of one parameter of an added effect.

    Attributes:
        name, unit: the parameter and its unit.
        mean, q05, q95: posterior mean and 90% interval (physical units).
        width_ratio: the 90% interval's width over the prior's (in the parameter's own scale); None if unknown.
        pressed: ``"lower"`` or ``"upper"`` when the posterior presses that prior bound, else None.
        suggested_bounds: the wider prior to try when it presses a bound that is not a physical limit.
        effect: the effect the parameter belongs to (``""`` in files written before it was kept).
        may_be_off: whether the data leave the posterior at the value that switches the effect off
            (:meth:`~softsbi.core.interfaces.Effect.nominal`): the 90% interval contains it, or, for an off value at
            a prior bound, the Savage-Dickey density ratio there is above 0.10
            (:func:`~softsbi.workflows.criticism.diagnose.may_be_off`); None when unknown.
        off_ratio: for an off value at a prior bound, that Savage-Dickey ratio (the posterior's mass next to the
            bound over the prior's, :func:`~softsbi.workflows.criticism.diagnose.off_ratio`); None otherwise.
    """

    name: str
    unit: str
    mean: float
    q05: float | None = None
    q95: float | None = None
    width_ratio: float | None = None
    pressed: str | None = None
    suggested_bounds: tuple[float, float] | None = None
    effect: str = ""
    may_be_off: bool | None = None
    off_ratio: float | None = None

    @property
    def informed(self) -> bool | None:
        """Whether the data narrowed it (90% interval narrower than half the prior's)."""
        return None if self.width_ratio is None else self.width_ratio <= INFORMED_MAX_RATIO


@dataclass(frozen=True, kw_only=True)
class OffTest:
    """The calibrated test of "the added effect is off" of an amortised refit
    (:mod:`~softsbi.workflows.criticism.switched_on`): its posterior's distance from the effect's off value
    (:func:`~softsbi.workflows.criticism.statistics.off_distance`) against the same model's posteriors of
    ``p_value.n`` prior simulations without the effect (the nominal model's held-out simulations).

    Attributes:
        statistic: the refit's distance (posterior standard deviations, unit coordinates).
        p_value: its Monte-Carlo p-value, ``(1 + #null >= statistic) / (n + 1)``.
        level: the effect is switched on when ``p_value <= level`` (the rate at which an effect that is off is
            called on: :data:`~softsbi.core.results.joint.CHANCE_EXCLUDED`).
    """

    statistic: float
    p_value: MCPValue
    level: float

    @property
    def on(self) -> bool:
        """The data switch the effect on: ``p_value <= level``."""
        return self.p_value.value <= self.level + 1e-12


@dataclass(frozen=True, kw_only=True)
class Refit:
    """The nominal model with added effects, fitted to the same measurement and checked.

    Attributes:
        effects: the added effects.
        run: its run directory.
        test: ``check``'s test of the refit (same level and family as the diagnosis, less its own effects).
        score: its summary energy score (of its posterior predictive of the summaries, in the nominal fit's scale;
            None when too few rollouts succeeded).
        chamfer_m: its posterior-predictive Chamfer (m), from its check (as the nominal's :attr:`Diagnosis.chamfer_m`).
        chamfer_n: the posterior-predictive rollouts that Chamfer averages (0: unknown).
        estimates: its posterior of the added effects' parameters.
        ranking: its own screening of the remaining candidates (what it leaves unexplained).
        rounds, sims_per_round: its simulation budget (an amortised refit: 1 round of 0 simulations of its own).
        amortised: its posterior is its model's trained task's, conditioned on the recording (no rounds simulated;
            its check calibrated against the model's replicates when the task has them); False: sequential rounds.
        off_test: for an amortised single refit whose task stores its "off" null, the calibrated test that decides
            whether the data switch its effect on (:class:`OffTest`); None: the estimates decide
            (:attr:`Estimate.may_be_off`).
        refined_from: the amortised refit this one refines (adequate and improving, its effect possibly off:
            :func:`~softsbi.workflows.criticism.decide.to_refine`), fitted again in sequential rounds after it; None:
            not a refinement.
    """

    effects: tuple[str, ...]
    run: str
    test: JointTest
    score: Score | None
    chamfer_m: float | None = None
    estimates: tuple[Estimate, ...] = ()
    ranking: tuple[Candidate, ...] = ()
    rounds: int = 0
    sims_per_round: int = 0
    chamfer_n: int = 0
    amortised: bool = False
    off_test: OffTest | None = None
    refined_from: Refit | None = None

    @property
    def label(self) -> str:
        """``"wind"`` or ``"wind+point-noise"``."""
        return "+".join(self.effects)

    @property
    def adequate(self) -> bool:
        """The measurement lies inside the refit's posterior predictive distribution (its test does not reject);
        a refinement also needs the refit it refines to be adequate (whose check, calibrated against the model's
        replicates, its own uncalibrated one does not replace)."""
        return not self.test.misspecified and (self.refined_from is None or self.refined_from.adequate)

    @property
    def maybe_off(self) -> tuple[str, ...]:
        """The added effects the data do not switch on: with an :attr:`off_test`, its effect unless the test says
        on; else those every one of whose parameters' posterior reaches the effect's off value
        (:attr:`Estimate.may_be_off`)."""
        if self.off_test is not None:
            return () if self.off_test.on else self.effects
        return tuple(e for e in self.effects if (own := [x for x in self.estimates if x.effect == e])
                     and all(x.may_be_off for x in own))


@dataclass(frozen=True, kw_only=True)
class Gain:
    """How much lower model B's score is than model A's: ``difference = A - B``, its standard error ``se`` and
    ``z = difference / se`` (all dimensionless, as the :class:`Score` they compare)."""

    difference: float
    se: float
    z: float

    @classmethod
    def of(cls, a: "Score | None", b: "Score | None") -> "Gain | None":
        """The gain of ``b`` over ``a``: the difference ``a - b``, its standard error ``sqrt(se_a^2 + se_b^2)`` (two
        independent Monte-Carlo samples scored against the same measurement) and ``z``; None when either is
        missing."""
        if a is None or b is None:
            return None
        return cls.summed(a.value - b.value, math.hypot(a.se, b.se))

    @classmethod
    def summed(cls, difference: float, se: float) -> "Gain":
        """A gain ``difference`` with its standard error ``se``: ``z = difference / se`` (at ``se`` 0, infinite in the
        gain's sign, 0 for no gain)."""
        d, se = float(difference), float(se)
        z = d / se if se > 0 else (math.inf if d > 0 else -math.inf if d < 0 else 0.0)
        return cls(difference=d, se=se, z=z)

    @classmethod
    def paired(cls, differences: Sequence[float], mc_se: float = 0.0) -> "Gain | None":
        """The gain summed over recordings, paired over them: ``difference = sum_r d_r`` of the per-recording gains
        ``d_r``, its standard error from their spread across recordings, ``sd(d_r) * sqrt(R)`` (sample standard
        deviation; a one-sample statistic, so one recording's large gain does not make the sum significant), never
        below ``mc_se`` (the Monte-Carlo standard error of the sum); None for fewer than two recordings."""
        d = [float(x) for x in differences]
        if len(d) < 2:
            return None
        mean = sum(d) / len(d)
        sd = math.sqrt(sum((x - mean) ** 2 for x in d) / (len(d) - 1))
        return cls.summed(sum(d), max(sd * math.sqrt(len(d)), float(mc_se)))

    def exceeds(self, k_se: float) -> bool:
        """True when the gain is more than ``k_se`` standard errors (``z > k_se``): the diagnosis' margin for an
        improvement (:func:`softsbi.workflows.criticism.decide.improves`)."""
        return self.z > k_se


@dataclass(frozen=True, kw_only=True)
class RefitGain:
    """A refit's score against the model it extends (the nominal fit's for one effect, its first effect's refit for a
    pair): ``effects`` the refit's added effects, ``gain`` the :class:`Gain`."""

    effects: tuple[str, ...]
    gain: Gain


class Role(str, Enum):
    """What a diagnosis' decision says of one refit (:meth:`Decision.role`)."""

    NAMED = "named"
    INDISTINGUISHABLE = "indistinguishable"
    PARTIAL = "explains a part"
    NOT_NAMED = "not named"


@dataclass(frozen=True, kw_only=True)
class Decision:
    """What a diagnosis concludes (:func:`softsbi.workflows.criticism.decide.decide`).

    Attributes:
        verdict: one of :data:`VERDICTS`.
        named: the effects the verdict names (one, or two for a pair); empty unless ``missing-effect``.
        alternatives: refits the data cannot tell from the named one (each a tuple of effects).
        partial: for ``misspecified-unexplained``: the single refit that lowers the score most while the measurement
            stays outside its posterior predictive distribution (it explains a part), else empty.
        gain: the named (or partial) refit's score against the model it extends.
        gains: every scored refit's score against the model it extends, as the decision compared them (empty in
            files written before they were kept).
    """

    verdict: str
    named: tuple[str, ...] = ()
    alternatives: tuple[tuple[str, ...], ...] = ()
    partial: tuple[str, ...] = ()
    gain: Gain | None = None
    gains: tuple[RefitGain, ...] = ()

    def role(self, effects: Sequence[str]) -> Role:
        """What the decision says of the refit adding ``effects`` (in any order)."""
        s = set(effects)
        if s == set(self.named):
            return Role.NAMED
        if any(s == set(a) for a in self.alternatives):
            return Role.INDISTINGUISHABLE
        if s == set(self.partial):
            return Role.PARTIAL
        return Role.NOT_NAMED

    def gain_of(self, effects: Sequence[str]) -> Gain | None:
        """The refit adding ``effects``' score against the model it extends (None: not scored, or not kept)."""
        return next((g.gain for g in self.gains if set(g.effects) == set(effects)), None)


@dataclass(frozen=True, kw_only=True)
class ResidualShape:
    """When, where and in which direction the nominal fit misses the measurement.

    Attributes:
        frames_flagged: frames whose summaries lie beyond the posterior predictive's 95% quantile.
        frame_spans: runs of consecutive flagged frames ``(first, last, t_first_s, t_last_s)``.
        phases: per phase of the motion ``{"phase", "frames": [a, b], "fraction_flagged", "chamfer_m"}``
            (``fraction_flagged`` None: no fitted frame; ``chamfer_m``: the phase's posterior-predictive Chamfer, m,
            the number ``check``'s phase table shows; absent in older files).
        centroid_offset_cm: measured minus simulated centroid over the flagged frames ``(x, y, z)`` (cm).
        direction: its dominant axis in words (``"+y"``, ``"-z (down)"``, ``"+x and +y"`` for a tie,
            :func:`~softsbi.core.metrics.offset_direction`).
        worst_summary: the summary statistic that departs most.
        region_excess_cm: per region of the cloth, the error the model's own spread does not produce (cm).
        worst_regions: the two regions with the largest excess.
    """

    frames_flagged: tuple[int, ...]
    frame_spans: tuple[tuple[int, int, float, float], ...]
    phases: tuple[Mapping[str, Any], ...]
    centroid_offset_cm: tuple[float, float, float]
    direction: str
    worst_summary: str
    region_excess_cm: Mapping[str, float | None]
    worst_regions: tuple[str, ...]


@dataclass(frozen=True, kw_only=True)
class Diagnosis:
    """The result of ``diagnose``: detect, propose, decide (:mod:`softsbi.workflows.criticism.diagnose`).

    Attributes:
        run: the nominal fit's run directory.
        candidates: the candidate family (used in every step).
        alpha, k_se: the level of every test and the standard-error margin of every score comparison.
        test: ``check``'s test of the nominal fit (detect).
        ranking: the screening's candidates by evidence (propose).
        nominal: the nominal fit's summary energy score (:class:`Score`).
        refits: the refits made, in order.
        decision: the verdict (decide).
        residual: the nominal fit's residual shape (None for ``nothing-missing``).
        generic: the generic force term that explains most of the residual, or None.
        simulations: simulations spent (refits' fits excluded).
        chamfer_m, chamfer_n: the nominal fit's posterior-predictive Chamfer (m, from its check) and the rollouts it
            averages (0: unknown), which each refit's is compared with.
        confirm: the refit budget (``--confirm``: the top named candidates refitted; None: unknown).
        uninformed: the trained candidates their task does not inform, by effect: the smallest median held-out 90%
            width over the prior's among the effect's own parameters, each above
            :data:`~softsbi.inference.contraction.INFORMED_MAX_RATIO`
            (:func:`~softsbi.workflows.criticism.evidence.uninformed_candidates`).
        key: what determines the result (the fit, the settings), so that a stored result is reused only for them.
        seconds: wall time.
    """

    run: str
    candidates: tuple[str, ...]
    alpha: float
    k_se: float
    test: JointTest
    ranking: tuple[Candidate, ...]
    nominal: Score | None
    refits: tuple[Refit, ...]
    decision: Decision
    residual: ResidualShape | None = None
    generic: Candidate | None = None
    simulations: int = 0
    key: Mapping[str, Any] = field(default_factory=dict)
    seconds: float = 0.0
    chamfer_m: float | None = None
    chamfer_n: int = 0
    confirm: int | None = None
    uninformed: Mapping[str, float] = field(default_factory=dict)

    @property
    def family(self) -> tuple[str, ...]:
        """The candidates it ranked, generic force terms aside: the effects a verdict may leave undecided."""
        return tuple(c.effect for c in self.ranking if not c.generic)

    @property
    def verdict(self) -> str:
        """The decision's verdict."""
        return self.decision.verdict

    def refit(self, effects: tuple[str, ...] | list[str]) -> Refit | None:
        """The refit that added ``effects`` (any order), or None."""
        want = set(effects)
        return next((r for r in self.refits if set(r.effects) == want), None)


@dataclass(frozen=True, kw_only=True)
class Phase:
    """One phase of the motion: ``phase`` name, ``frames`` ``(first, last)``, ``t_s`` ``(start, end)``, the mean
    Chamfer (m) of the posterior rollouts over it (and the one-sided one), whether the fit's frames include it
    and its worst region."""

    phase: str
    frames: tuple[int, int]
    t_s: tuple[float, float]
    chamfer_m: float
    chamfer_one_sided_m: float | None
    in_fit: bool
    worst_region: str


@dataclass(frozen=True, kw_only=True)
class Band:
    """A per-frame curve with its 5-95% band over posterior rollouts: ``mean``, ``q05``, ``q95`` ``(T,)`` (m)."""

    mean: tuple[float, ...]
    q05: tuple[float, ...]
    q95: tuple[float, ...]


@dataclass(frozen=True, kw_only=True)
class CheckResult:
    """The result of ``check``: where a fit misses the measurement, and whether it can produce it.

    Attributes:
        run: the run directory.
        n_rollouts, failed_rollouts: posterior-predictive rollouts that succeeded / failed.
        times_s: frame times (s).
        chamfer: Chamfer per frame with its band (m); ``chamfer_one_sided``: measured -> simulated.
        chamfer_mean_m: mean over the fit's frames (the report's posterior-predictive Chamfer).
        chamfer_one_sided_mean_m: the same for the one-sided Chamfer (None if unavailable).
        metric_min_z_m, metric_frames, metric_sensor: the fit's sensor model (``"camera"``, ``"height"``,
            ``"none"``); table_z_m: the table's height (m).
        regions, region_error_m ``(T, R)``, region_compared ``(T, R)``, region_mean_m: error per region of
            the cloth (regions counted from the first handle's grasp).
        phases: per phase of the motion; worst_frames, worst_regions: where it misses most.
        test: the misspecification test; ranking: its screening of the candidate effects (the directional test's
            family, by evidence); energy: the posterior predictive's Chamfer energy score (:class:`EnergyScore`).
        posterior_mean: the posterior-mean rollout's Chamfer ``{"chamfer_m", "chamfer_se_m", "n"}`` (m), the error
            of the fitted point estimate; None for a fit without one.
        residual: where, when and in which direction the fit misses the measurement (when the test rejects).
        posterior_at_bounds: the fit's parameters whose posterior presses a prior bound (report.json's).
        key: what determines the result (run, settings), so that a stored result is reused only for them.
        seconds: wall time.
        grasp_handle: with several handles, the moving handle whose grasp the regions are ranked from (``"left"``);
            None: the scenario's one grasp.
        phases_at_keyframes: the phases are the moves between the scenario's keyframes (False: equal thirds of the
            motion).
    """

    run: str
    n_rollouts: int
    failed_rollouts: int
    times_s: tuple[float, ...]
    chamfer: Band
    chamfer_one_sided: Band
    chamfer_mean_m: float
    chamfer_one_sided_mean_m: float | None
    metric_min_z_m: float | None
    metric_frames: tuple[int, ...] | None
    metric_sensor: str
    table_z_m: float
    regions: tuple[str, ...]
    region_error_m: tuple[tuple[float, ...], ...]
    region_compared: tuple[tuple[bool, ...], ...]
    region_mean_m: Mapping[str, float]
    phases: tuple[Phase, ...]
    worst_frames: tuple[int, ...]
    worst_regions: tuple[str, ...]
    test: JointTest
    ranking: tuple[Candidate, ...]
    energy: EnergyScore | None
    posterior_mean: Mapping[str, float] | None = None
    residual: ResidualShape | None = None
    posterior_at_bounds: tuple[Mapping[str, Any], ...] = ()
    key: Mapping[str, Any] = field(default_factory=dict)
    seconds: float = 0.0
    grasp_handle: str | None = None
    phases_at_keyframes: bool = False


#: how ``check.json`` files of schema <= 3 said whose grasp the regions count from (``regions_from``, in words)
LEGACY_GRASP = "the grasp of handle '"


def _legacy_check(data: dict[str, Any]) -> dict[str, Any]:
    """A ``check.json`` of schema <= 3 (``regions_from`` and ``phases_from`` in words) with typed fields instead."""
    data = dict(data)
    regions, phases = data.pop("regions_from", None), data.pop("phases_from", None)
    if isinstance(regions, str) and regions.startswith(LEGACY_GRASP) and "grasp_handle" not in data:
        data["grasp_handle"] = regions[len(LEGACY_GRASP):].rstrip("'")
    if phases is not None and "phases_at_keyframes" not in data:
        data["phases_at_keyframes"] = phases == "the scenario's keyframes"
    return data


UPGRADED["CheckResult"] = _legacy_check
