"""Every sentence ``check``, ``diagnose`` and ``compare`` print, rendered from their typed results
(:mod:`softsbi.core.results`). Pure functions: tested against fixed result objects."""
from __future__ import annotations

import math
from typing import Mapping, Sequence

from scipy.stats import binom

from softsbi.core.metrics import describe_change, offset_axes
from softsbi.core.results.comparison import CompareResult, Metric
from softsbi.core.results import (Candidate, CheckResult, Diagnosis, Estimate, Gain, JointTest, MCPValue, OffTest,
                                  Refit, ResidualShape, Role, Score)
from softsbi.core.results.design import undecided_candidates
from softsbi.core.results.joint import CHANCE_EXCLUDED
from softsbi.core.types import unit_suffix
from softsbi.inference.contraction import INFORMED_MAX_RATIO

#: the names of softsbi's two energy scores (Gneiting & Raftery 2007, eq. 22), one per space, used in every sentence,
#: table and figure: ``check`` and ``compare`` score the posterior predictive's clouds with the Chamfer distance (cm,
#: :class:`~softsbi.core.results.EnergyScore`); ``diagnose`` decides on the score of ``check``'s summary statistics,
#: Euclidean in the nominal fit's scale (dimensionless, :class:`~softsbi.core.results.Score`)
CHAMFER_ENERGY = "Chamfer energy score"
SUMMARY_ENERGY = "summary energy score"
#: the unit of the summary energy score: each summary in standard deviations of the nominal fit's posterior
#: predictive (the scale every model is scored in, :class:`~softsbi.core.results.Score`)
SCORE_UNIT = "sd"


def cm(x: float | None, digits: int = 2) -> str:
    """A length in metres as centimetres: ``"1.23 cm"`` (``"n/a"`` for None)."""
    return "n/a" if x is None else f"{x * 100:.{digits}f} cm"


def pct(x: float | None) -> str:
    """A fraction as a percentage: ``"37%"``."""
    return "n/a" if x is None else f"{x * 100:.0f}%"


def rollouts(n: int | None) -> str:
    """How many posterior-predictive rollouts a Chamfer figure averages: ``" (n=30 rollouts)"`` (``""`` unknown)."""
    return f" (n={n} rollouts)" if n else ""


def region_value(name: str, value: str) -> str:
    """A region's name with the number that ranks it: ``"R9 (farthest from the grasp; 8.56 cm)"``, ``"R8 (8.1 cm)"``."""
    return f"{name[:-1]}; {value})" if name.endswith(")") else f"{name} ({value})"


def ranges(idx: Sequence[int]) -> str:
    """``[10, 11, 12, 20]`` -> ``"10-12, 20"``."""
    out, start = [], None
    s = sorted(int(i) for i in idx)
    for k, i in enumerate(s):
        start = i if start is None else start
        if k == len(s) - 1 or s[k + 1] != i + 1:
            out.append(f"{start}-{i}" if i > start else f"{i}")
            start = None
    return ", ".join(out)


def p_short(p: MCPValue | JointTest) -> str:
    """A p-value in a table cell, floored at its resolution: ``p <= 1/31`` or ``p = 0.13`` (a Monte-Carlo p-value,
    or a joint test's), ``p <= 2/201`` (a joint test Bonferroni-combined, as results written before the min-p
    combination are)."""
    if isinstance(p, JointTest):
        k = 1 if p.combined is not None else p.tests
        return f"p <= {k}/{p.n_null + 1}" if p.p_value <= p.resolution else f"p = {p.p_value:.2g}"
    return f"p <= 1/{p.n + 1}" if p.at_floor else f"p = {p.value:.2g}"


def p_words(p: MCPValue | JointTest, of: str = "null simulations") -> str:
    """A p-value for people, with its resolution: ``p <= 1/31 (beyond all 30 null simulations)`` or ``p = 0.13 (3 of
    30 null simulations as extreme)``; a joint test of two says how they were combined (min-p; Bonferroni in results
    written before it) and names the deciding test's own p-value, and a calibrated test (:attr:`JointTest.calibrated`)
    counts replicate recordings instead (``of``)."""
    if isinstance(p, MCPValue):
        if p.at_floor:
            return f"p <= 1/{p.n + 1} (beyond all {p.n} {of})"
        return f"p = {p.value:.2g} ({p.exceed} of {p.n} {of} as extreme)"
    if p.combined is not None:  # the two tests' min-p combination against one null
        of = REPLICATES if p.calibrated else of
        c = p.combined
        own = f"the {p.deciding} test's own {p_short(p.best)}"
        if c.at_floor:
            return f"p <= 1/{c.n + 1} (two tests, min-p combined; beyond all {c.n} {of}; {own})"
        return f"p = {c.value:.2g} (two tests, min-p combined: {c.exceed} of {c.n} {of} as extreme; {own})"
    of = REPLICATES if p.calibrated and p.deciding == "omnibus" else of
    if p.tests == 1:
        return p_words(p.omnibus, of)
    n = p.best.n
    if p.best.at_floor:
        return f"p <= 2/{n + 1} (two tests, Bonferroni; the {p.deciding} test beyond all {n} {of})"
    return (f"p = {p.p_value:.2g} (two tests, Bonferroni: 2 x the {p.deciding} test's {p_short(p.best)}; "
            f"{n} {of})")


#: what a calibrated omnibus p-value counts (:mod:`~softsbi.workflows.criticism.check_null`)
REPLICATES = "replicate recordings of the task, refitted and checked the same way"


def joint_test_line(t: JointTest) -> str:
    """``check``'s line on the two tests of its joint test: the omnibus p-value, then the directional one with its
    family and strongest effect."""
    return (f"misspecification test: omnibus{' (calibrated)' if t.calibrated else ''} "
            f"{p_words(t.omnibus, REPLICATES if t.calibrated else 'null simulations')}"
            + (f"; directional (max-T over {len(t.family)} candidate effects, strongest {t.directional_effect}) "
               f"{p_words(t.directional)}" if t.directional else ""))


def skipped_words(t: JointTest) -> str:
    """``"; the directional test did not run (why): the p-value is the omnibus test's alone"`` when one of the two
    tests did not run (:attr:`JointTest.directional_skipped`), else ``""``."""
    if t.directional is not None or not t.directional_skipped:
        return ""
    return f"; the directional test did not run ({t.directional_skipped}): the p-value is the omnibus test's alone"


def test_verdict(test: JointTest) -> str:
    """``check``'s verdict in words, with its p-value and level."""
    alone = skipped_words(test)
    if test.misspecified:
        return f"the measurement is NOT explained by the model ({p_words(test)} <= {test.alpha:g}){alone}"
    return f"no evidence of misspecification ({p_words(test)} > {test.alpha:g}){alone}"


def sensor_words(c: CheckResult) -> str:
    """The metric's sensor model in words (``""`` when it sees everything)."""
    parts = []
    if c.metric_sensor == "camera":
        parts.append("simulated clouds made by the recording's virtual depth sensor")
    elif c.metric_min_z_m is not None:
        parts.append(f"points within {(c.metric_min_z_m - c.table_z_m) * 100:.1f} cm of the table unseen")
    if c.metric_frames is not None and len(c.metric_frames) < len(c.times_s):
        parts.append(f"frames {ranges(c.metric_frames)}")
    return f" under the fit's sensor model: {', '.join(parts)}" if parts else ""


def bound_words(e: dict) -> str:
    """A fit's posterior pressing a prior bound (a ``posterior_at_bounds`` entry), with the advice."""
    bound = f"{e['bound']:.4g}{unit_suffix(e.get('unit'))}"
    head = (f"{e['param']}'s posterior presses its {e['side']} prior bound {bound} "
            f"({pct(e['mass'])} of its mass near it)")
    wide = e.get("suggested_bounds")
    if wide:
        return (head + f": widen the prior (--bounds {e['param']}={wide[0]:.4g}:{wide[1]:.4g}) if such values are "
                       f"physical, or suspect an effect the model lacks")
    return head + ": the bound is a physical limit, so suspect an effect the model lacks"


def regions_from(c: CheckResult) -> str:
    """Whose grasp a check's regions are numbered from: ``"the grasp"``, or ``"the grasp of handle 'left'"`` when the
    scenario has several handles."""
    return "the grasp" if c.grasp_handle is None else f"the grasp of handle '{c.grasp_handle}'"


def phases_from(c: CheckResult) -> str:
    """How a check's phases were cut: ``"the scenario's keyframes"`` or ``"equal thirds of the motion"``."""
    return "the scenario's keyframes" if c.phases_at_keyframes else "equal thirds of the motion"


def check_summary(c: CheckResult) -> str:
    """``check``'s paragraph: the error, where it is worst, the verdict, and prior bounds the posterior presses."""
    one = f"; measured -> simulated {cm(c.chamfer_one_sided_mean_m)}" if c.chamfer_one_sided_mean_m is not None else ""
    s = (f"Posterior rollouts miss the measurement by {cm(c.chamfer_mean_m)} on average over {c.n_rollouts} rollouts "
         f"(Chamfer{sensor_words(c)}{one})")
    fitted = [p for p in c.phases if p.in_fit]
    if fitted:
        w = max(fitted, key=lambda p: p.chamfer_m)
        s += f"; worst in the {w.phase} phase (t {w.t_s[0]:.2f}-{w.t_s[1]:.2f} s, {cm(w.chamfer_m)})"
    if c.worst_regions:
        r = c.worst_regions[0]
        s += f" and in region {region_value(r, cm(c.region_mean_m[r])) if r in c.region_mean_m else r}"
        if c.grasp_handle is not None:  # several handles: say whose grasp the regions are numbered from
            s += f" (regions numbered from {regions_from(c)})"
    s += f"; {test_verdict(c.test)}."
    if c.energy:
        s += f" {CHAMFER_ENERGY} {cm(c.energy.energy_m)}."
    for e in c.posterior_at_bounds:
        s += f" The fit's posterior: {bound_words(dict(e))}."
    return s


#: the level at which a fit's 90% intervals miss more hidden values than chance allows: the hint to run ``check``
#: shows when ``P(X >= misses) <= TRUTH_MISS_LEVEL`` for ``X ~ Binomial(n values, 1 - 0.9)`` (each interval covering
#: its value with probability 0.9); with 5 values: 3 misses or more (2 misses happen by chance 8% of the time)
TRUTH_MISS_LEVEL = 0.05


def truth_miss_hint(inside: Mapping[str, bool | None], run: str, level: float = TRUTH_MISS_LEVEL,
                    coverage: float = 0.9) -> str | None:
    """The fit report's hint that the model may lack something: its ``coverage`` intervals miss more of the hidden
    values of a simulated recording (``inside``: report.json's ``truth_in_90pct_interval``, None = no hidden value)
    than chance allows at ``level`` (:data:`TRUTH_MISS_LEVEL`); None when they do not."""
    judged = [bool(v) for v in inside.values() if v is not None]
    n, k = len(judged), sum(not v for v in judged)
    if k == 0:
        return None
    p = float(binom.sf(k - 1, n, 1 - coverage))
    if p > level:
        return None
    return (f"Note: the {coverage:.0%} intervals miss {k} of {n} hidden values, more than chance allows "
            f"(p = {p:.2g} <= {level:g}): the model may lack an effect; `softsbi check {run}` shows where and when "
            f"it misses the measurement.")


#: magnitudes below this print as 0: a switched-off effect's estimate at its off value (8.7e-22 is rounding)
ZERO_PRINTED = 1e-12


def num(v: float) -> str:
    """A parameter value for people: three significant digits, ``"0"`` below :data:`ZERO_PRINTED`."""
    return "0" if abs(v) < ZERO_PRINTED else f"{v:.3g}"


def estimate_words(e: Estimate, on: bool | None = None) -> str:
    """``"wind_y = 0.81 m/s (90% interval 0.62 to 0.97 m/s)"``. A wide interval (:attr:`Estimate.informed` False)
    is "not informed by the data", unless the effect is switched on (``on``: the refit's calibrated test,
    :attr:`~softsbi.core.results.Refit.off_test`; None: the estimate's own rule, :attr:`Estimate.may_be_off`
    False): then the data do inform it, on two counts: the effect is on, and its size is known to within half the
    interval's width. Where a test decides, the Savage-Dickey ratio is printed without a verdict of its own."""
    u = unit_suffix(e.unit)
    s = f"{e.name} = {num(e.mean)}{u}"
    shown_on = (e.may_be_off is False) if on is None else on
    if e.q05 is not None and e.q95 is not None:
        s += f" (90% interval {num(e.q05)} to {num(e.q95)}{u}"
        if e.off_ratio is not None:  # an off value at a prior bound: the ratio decides, not the interval
            s += f"; {off_ratio_words(e.off_ratio, decides=on is None)}"
        if e.informed is False and shown_on:
            s += f": the data show the effect is on, its size known to within ±{num((e.q95 - e.q05) / 2)}{u})"
        else:
            s += ", not informed by the data)" if e.informed is False else ")"
    return s


def off_ratio_words(ratio: float, decides: bool = True) -> str:
    """``"its posterior next to the off value is 1.2 times the prior's (possibly off: on at most 0.1)"``: the
    Savage-Dickey ratio that decides "switched on" for an off value at a prior bound (:data:`SWITCHED_ON_RULE`);
    without its verdict where a calibrated test decides instead (``decides`` False)."""
    s = f"its posterior next to the off value is {ratio:.2g} times the prior's"
    if not decides:
        return s
    on = ratio <= CHANCE_EXCLUDED
    return s + f" ({'switched on' if on else 'possibly off'}: on at most {CHANCE_EXCLUDED:g})"


#: the "switched on" criterion in words, as :func:`~softsbi.workflows.criticism.diagnose.may_be_off` applies it
SWITCHED_ON_RULE = (f"a parameter's 90% interval excludes the effect's off value or, for an off value at a prior "
                    f"bound (which no interval reaches), the posterior's mass next to that bound is at most "
                    f"{CHANCE_EXCLUDED:g} of the prior's (a Savage-Dickey ratio)")
#: the calibrated "switched on" test of a trained task's amortised refit in words
#: (:mod:`~softsbi.workflows.criticism.switched_on`)
SWITCHED_ON_TEST = (f"its posterior lies farther from the effect's off value, in posterior standard deviations, than "
                    f"its model's posteriors of simulations without the effect do, at p <= {CHANCE_EXCLUDED:g}")


def off_test_words(t: OffTest) -> str:
    """``"its posterior lies 3.1 posterior standard deviations from the off value, farther than on 195 of 200
    simulations without the effect (p = 0.03: switched on at p <= 0.1)"``."""
    far = t.p_value.n - t.p_value.exceed
    return (f"its posterior lies {t.statistic:.2g} posterior standard deviations from the off value, farther than on "
            f"{far} of {t.p_value.n} of its model's posteriors of simulations without the effect ({p_short(t.p_value)}"
            f": {'switched on' if t.on else 'possibly off'} at p <= {t.level:g})")


def score_change(base: Score | None, new: Score | None, g: Gain | None, joiner: str = " -> ") -> str:
    """``"28.5 -> 14.3 sd (50% lower, 6.1 standard errors)"`` (:data:`SCORE_UNIT`) (``joiner`` between the two scores; the standard errors
    are the decision's, ``g``: :attr:`~softsbi.core.results.Decision.gains`)."""
    if base is None or new is None:
        return "n/a"
    z = f", {g.z:.1f} standard errors" if g is not None and math.isfinite(g.z) else ""
    return f"{base.value:.3g}{joiner}{new.value:.3g} {SCORE_UNIT} ({describe_change(base.value, new.value)}{z})"


def extended(d: Diagnosis, r: Refit) -> Score | None:
    """The score of the model refit ``r`` extends: the nominal fit's for a single effect, the first effect's refit
    for a pair."""
    if len(r.effects) == 1:
        return d.nominal
    first = d.refit(r.effects[:1])
    return first.score if first else None


def refit_words(r: Refit, base: Score | None, nominal_chamfer_m: float | None = None, nominal_n: int = 0,
                g: Gain | None = None, aside: str | None = None) -> str:
    """One refit: is it adequate, does it improve (``g``: its gain over ``base``, the model it extends, as the
    decision computed it), what it estimates, which prior bounds it presses, and, when the decision sets an adequate
    refit aside, why (``aside``: :func:`set_aside_words`, the reason the table gives). An adequate refit whose
    posterior-predictive Chamfer is higher than the nominal fit's (``nominal_chamfer_m``) is said to pass check, not
    to put the measurement "inside" (which reads like a win); its Chamfer is a fact beside the decision, never its
    reason."""
    worse = (r.adequate and r.chamfer_m is not None and nominal_chamfer_m is not None
             and r.chamfer_m > nominal_chamfer_m)
    chamfer = f"posterior-predictive Chamfer {cm(r.chamfer_m)}{rollouts(r.chamfer_n)}"
    if worse:
        s = (f"With {' + '.join(r.effects)}: check does not reject the refit ({p_words(r.test)}), {SUMMARY_ENERGY} "
             f"{score_change(base, r.score, g)}; its {chamfer} is higher than the nominal fit's "
             f"{cm(nominal_chamfer_m)}{rollouts(nominal_n)}.")
    else:
        ok = "inside" if r.adequate else "still outside"
        s = (f"With {' + '.join(r.effects)}: the measurement is {ok} the refit's posterior predictive distribution "
             f"({p_words(r.test)}), {SUMMARY_ENERGY} {score_change(base, r.score, g)}"
             + (f", {chamfer}." if r.chamfer_m is not None else "."))
    if r.refined_from is not None:
        s += f" {refined_words(r)}"
    if aside is not None:
        s += f" Set aside: {aside}."
    if r.estimates:
        on = None if r.off_test is None else r.off_test.on
        s += " The refit estimates " + "; ".join(estimate_words(e, on) for e in r.estimates) + "."
    if r.off_test is not None:
        words = off_test_words(r.off_test)
        s += f" Is its effect off? {words[0].upper()}{words[1:]}."
    for e in r.estimates:  # a bound that is a physical limit (or the effect's switched-off side) gets no advice
        if e.pressed and e.suggested_bounds:
            s += (f" Its {e.name} presses the {e.pressed} prior bound: refit with --bounds "
                  f"{e.name}={e.suggested_bounds[0]:.4g}:{e.suggested_bounds[1]:.4g} if such values are physical.")
    return s


def refined_words(r: Refit) -> str:
    """Why and how refit ``r`` was refined (:func:`~softsbi.workflows.criticism.decide.to_refine`): its amortised
    refit was adequate and improving but left the effect possibly off, so it was fitted again in sequential rounds
    after that posterior; its adequacy needs the amortised refit's calibrated check too."""
    a = r.refined_from
    assert a is not None
    why = off_test_words(a.off_test) if a.off_test is not None else "no parameter's posterior excluded its off value"
    score = f" to {a.score.value:.3g}" if a.score is not None else ""
    return (f"Refined: its amortised refit passed check ({p_words(a.test)}) and lowered the {SUMMARY_ENERGY}{score} "
            f"but left {' + '.join(r.effects)} possibly off ({why}), so it was fitted again in "
            f"{max(r.rounds - 1, 0)} sequential round{'s' if r.rounds - 1 != 1 else ''} of {r.sims_per_round} "
            f"simulations after that posterior; the numbers here are the refinement's.")


#: the reasons :func:`set_aside` gives (the table's verdict column, after ``"refit: "``)
MISFIT_REMAINS = "misfit remains"
POSSIBLY_OFF = "the data leave it possibly off"
NO_LOWER = "no lower score"


def set_aside(d: Diagnosis, r: Refit) -> str | None:
    """Why the decision did not name refit ``r`` (None: it names it, lists it as indistinguishable or as explaining
    a part), in the order of the decision's criteria (:mod:`softsbi.workflows.criticism.decide`): the misfit remains
    (check rejects it), the data leave its effect possibly off, its score is lower than the nominal's but above the
    named refit's, or no lower. The table's verdict column and the refit's paragraph both give this reason."""
    dec = d.decision
    if dec.role(r.effects) is not Role.NOT_NAMED:
        return None
    if not r.adequate:
        return MISFIT_REMAINS
    if r.maybe_off:
        return POSSIBLY_OFF
    g = dec.gain_of(r.effects)
    if g is not None and g.exceeds(d.k_se) and dec.named:  # adequate and improving, but the named refit scores lower
        return f"a lower score than the nominal's, above {' + '.join(dec.named)}'s"
    return NO_LOWER


def set_aside_words(d: Diagnosis, r: Refit) -> str | None:
    """:func:`set_aside`'s reason with what it means, for the refit's paragraph; None where the paragraph's first
    sentence says it already (the misfit remains: the measurement is still outside) or the refit is not set aside."""
    why = set_aside(d, r)
    if why is None or why == MISFIT_REMAINS:
        return None
    if why == POSSIBLY_OFF and r.off_test is not None:
        return (f"{why} ({off_test_words(r.off_test)}): the refit explains the misfit by widening its predictions, "
                f"not by identifying a cause")
    if why == POSSIBLY_OFF:
        return (f"{why} (its effect is switched on when {SWITCHED_ON_RULE}, and no parameter of it does so): the "
                f"refit explains the misfit by widening its predictions, not by identifying a cause")
    return f"{why} (by more than {d.k_se:g} standard errors)" if why != NO_LOWER else (
        f"{why} (its {SUMMARY_ENERGY} is not {d.k_se:g} standard errors below the model it extends)")


def rule_words(d: Diagnosis) -> str:
    """The decision rule as applied, in three sentences."""
    s = (f"Detect: check's joint test of the nominal fit, {p_words(d.test)} "
         f"{'<=' if d.test.misspecified else '>'} {d.alpha:g}{skipped_words(d.test)}.")
    if not d.test.misspecified:
        return s
    singles = [r.label for r in d.refits if len(r.effects) == 1]
    refined = [r.label for r in d.refits if r.refined_from is not None]
    n_trained = sum(c.amortised is not None for c in d.ranking)
    s += (f" Propose: the screening ranked {len(d.candidates)} candidates"
          + (f" and the amortised posterior of each of the {n_trained} the task trained scored its refit"
             if n_trained else "") + "; refitted "
          + (", ".join(singles) if singles else "none")
          + (" (the trained ones whose amortised refit scores lower, then the top named ones the screening ranks)"
             if n_trained else " (the top named ones by evidence)")
          + (f", then the pair {d.refits[-1].label}" if d.refits and len(d.refits[-1].effects) == 2 else "")
          + (f"; refined {', '.join(refined)} (an amortised refit that passed and improved but left its effect "
             f"possibly off, fitted again in sequential rounds after its amortised posterior)" if refined else "")
          + ".")
    s += (f" Decide: a refit explains the misfit when check's test of it gives p > {d.alpha:g} and its "
          f"{SUMMARY_ENERGY} (the energy score of its posterior predictive of check's summaries, a proper score, in "
          f"{SCORE_UNIT}: standard deviations of the nominal fit's posterior predictive) falls by more than {d.k_se:g} standard errors below the model it extends, and the "
          f"data switch its effect on ({switched_on_rules(d.refits)}).")
    return s


def switched_on_rules(refits: Sequence[Refit]) -> str:
    """The "switched on" rule(s) the refits were judged by: the calibrated test for amortised refits that have one
    (:data:`SWITCHED_ON_TEST`), the estimates' rule for the others (:data:`SWITCHED_ON_RULE`)."""
    tested = [r for r in refits if r.off_test is not None]
    if not tested:
        return SWITCHED_ON_RULE
    if len(tested) == len(refits):
        return SWITCHED_ON_TEST
    return (f"for {', '.join(r.label for r in tested)}, {SWITCHED_ON_TEST}; for the others, "
            f"{SWITCHED_ON_RULE}")


def residual_words(res: ResidualShape) -> str:
    """Where, when and in which direction the nominal fit misses the measurement. Each phase or region it names comes
    with the number that ranks it: the flagged frames' share of each phase they fall in (:func:`flagged_shares`), the
    phase's posterior-predictive Chamfer (the number of ``check``'s phase table), a region's error beyond the model's
    own spread; the centroid's displacement with its dominant axis, or the axes that tie
    (:func:`~softsbi.core.metrics.offset_axes`)."""
    judged = [p for p in res.phases if p.get("fraction_flagged") is not None]
    if res.frame_spans:
        sp = ", ".join(f"frames {a}-{b} (t {t0:.2f}-{t1:.2f} s)" if b != a else f"frame {a} (t {t0:.2f} s)"
                       for a, b, t0, t1 in res.frame_spans[:3])
        shares = flagged_shares(judged)
        s = f"The summaries leave the rollouts' 95% range in {sp}" + (f" ({shares})" if shares else "")
    else:
        s = "No single frame is outside the rollouts' 95% range; the residual is spread over the motion"
    with_chamfer = [p for p in judged if p.get("chamfer_m") is not None]
    if with_chamfer:
        w = max(with_chamfer, key=lambda p: p["chamfer_m"])
        s += f"; the Chamfer is largest in the {w['phase']} phase ({cm(w['chamfer_m'])}, as in check's table)"
    o = res.centroid_offset_cm
    axes = offset_axes(o)
    way = ("" if not axes else f", mostly {axes[0]}" if len(axes) == 1
           else f", {', '.join(axes[:-1])} and {axes[-1]} alike")
    exc = res.region_excess_cm
    regions = ", ".join(region_value(r, f"{exc[r]:+.2f} cm") if exc.get(r) is not None else r
                        for r in res.worst_regions)
    return (s + f"; the measured centroid is displaced by ({o[0]:+.1f}, {o[1]:+.1f}, {o[2]:+.1f}) cm{way}; the most "
                f"deviant summary is {res.worst_summary}; regions with the most error beyond the model's own spread: "
                f"{regions}.")


def flagged_shares(phases: Sequence[Mapping]) -> str:
    """The flagged frames' share of each phase they fall in, largest first: ``"78% of the middle phase's frames and
    75% of the late phase's"``; ``"every fitted frame"`` when every phase is flagged throughout (``""``: none)."""
    hit = sorted((p for p in phases if p["fraction_flagged"] > 0), key=lambda p: -p["fraction_flagged"])
    if not hit:
        return ""
    if len(hit) == len(phases) and all(p["fraction_flagged"] >= 1 for p in hit):
        return "every fitted frame"
    parts = [f"{pct(p['fraction_flagged'])} of the {p['phase']} phase's" for p in hit]
    parts[0] += " frames"
    return parts[0] if len(parts) == 1 else f"{', '.join(parts[:-1])} and {parts[-1]}"


def _kind(d: Diagnosis, effects: Sequence[str]) -> str:
    kinds = {c.effect: c.kind for c in d.ranking}
    ks = {kinds.get(e, "physics") for e in effects}
    return ks.pop() if len(ks) == 1 else "physics and sensor"


def diagnosis_summary(d: Diagnosis) -> str:
    """The verdict in one or two sentences."""
    dec = d.decision
    if dec.verdict == "nothing-missing":
        return (f"Nothing missing: the measurement lies inside the nominal model's posterior predictive distribution "
                f"({p_words(d.test)} > {d.alpha:g}).")
    if dec.verdict == "missing-effect":
        r = d.refit(dec.named)
        names = " + ".join(dec.named)
        desc = {c.effect: c.description for c in d.ranking}
        s = (f"Missing {_kind(d, dec.named)} effect{'s' if len(dec.named) > 1 else ''}: {names}"
             + (f" ({desc[dec.named[0]]})" if len(dec.named) == 1 and desc.get(dec.named[0]) else "") + ". ")
        if len(dec.named) == 2:
            s += ("Neither refit alone explains the misfit; with both, the refit puts the measurement inside its "
                  "posterior predictive distribution ")
        else:
            s += "Its refit puts the measurement inside its posterior predictive distribution "
        s += (f"({p_words(r.test)}) and lowers the {SUMMARY_ENERGY} from "
              f"{score_change(extended(d, r), r.score, dec.gain, ' to ')}.")
        if dec.alternatives:
            alts = " or ".join(" + ".join(a) for a in dec.alternatives)
            s += (f" The data cannot tell it from {alts}: that refit explains the misfit too, with a {SUMMARY_ENERGY} "
                  f"within {d.k_se:g} standard errors; evidence these recordings lack (an independent measurement of "
                  f"the effect, or a motion in which the two differ) would decide.")
        return s
    s = (f"Misspecified, unexplained: the measurement lies outside the nominal model's posterior predictive "
         f"distribution ({p_words(d.test)} <= {d.alpha:g})")
    if not d.refits:
        return s + ", and no candidate was refitted."
    s += f", and no refit of {', '.join(r.label for r in d.refits)} explains it."
    if dec.partial:
        r = d.refit(dec.partial)
        s += (f" {' + '.join(dec.partial)} explains a part: of the single refits, it lowers the {SUMMARY_ENERGY} "
              f"most, from {score_change(d.nominal, r.score, dec.gain, ' to ')}, "
              f"but the measurement stays outside its posterior predictive distribution ({p_words(r.test)}).")
    else:
        s += " " + unexplained_reasons(d)
    return s


def unexplained_reasons(d: Diagnosis) -> str:
    """Why no refit explains the misfit, as the decision found it: ``"No refit lowers the summary energy score by more
    than 2 standard errors."`` when no refit's gain clears ``k_se``, else each refit with the reason that set it aside
    (:func:`set_aside`)."""
    gains = [d.decision.gain_of(r.effects) for r in d.refits]
    if not any(g is not None and g.exceeds(d.k_se) for g in gains):
        return f"No refit lowers the {SUMMARY_ENERGY} by more than {d.k_se:g} standard errors."
    return "Set aside: " + "; ".join(f"{r.label}: {set_aside(d, r) or 'not set aside'}" for r in d.refits) + "."


def diagnosis_text(d: Diagnosis) -> list[str]:
    """Everything ``diagnose`` says, one paragraph per item: the verdict, the rule as applied, each refit,
    the residual's shape and the best generic force term."""
    out = [diagnosis_summary(d), rule_words(d)]
    out += [refit_words(r, extended(d, r), d.chamfer_m, d.chamfer_n, d.decision.gain_of(r.effects),
                        set_aside_words(d, r))
            for r in d.refits]
    if d.decision.verdict == "misspecified-unexplained" and d.residual:
        out.append(residual_words(d.residual))
    if d.decision.verdict == "misspecified-unexplained" and d.generic:
        g = d.generic
        out.append(f"Best generic force term: {g.effect} explains {pct(g.explained)} of the residual in the "
                   f"linearised screening (max-T adjusted {p_words(g.adjusted) if g.adjusted else 'n/a'}).")
    if d.test.misspecified and d.uninformed:
        out.append(uninformed_words(d.uninformed))
    left = undecided_candidates(d, d.family)
    if left:
        out.append(design_hint(d.run, left))
    return out


def design_hint(where: str, undecided: Mapping[str, str]) -> str:
    """The last line of a diagnosis that leaves candidates undecided: how many, why, and the command that ranks the
    motions to record next (:func:`~softsbi.core.results.design.undecided_candidates`); ``where``: the fit's run
    directory, or the folder of a diagnosis across several recordings."""
    why: dict[str, list[str]] = {}
    for e, reason in undecided.items():
        why.setdefault(reason, []).append(e)
    parts = "; ".join(f"{len(v)} {k}" for k, v in why.items())
    return (f"Undecided: {len(undecided)} candidate{'s' if len(undecided) > 1 else ''} ({parts}). `softsbi design "
            f"{where}` ranks the motions the object supports by how well one more recording of each would inform "
            f"them (seconds from trained tasks, a few minutes of simulation otherwise).")


def uninformed_words(uninformed: Mapping[str, float]) -> str:
    """The trained candidates the task does not inform (:attr:`~softsbi.core.results.Diagnosis.uninformed`), in
    one sentence: the data of this motion mostly leave their parameters near the prior, so a missing effect among
    them is seldom named here."""
    names = ", ".join(f"{e} ({w:.2f})" for e, w in sorted(uninformed.items(), key=lambda kv: kv[1]))
    return (f"Not informed by this task: {names}. Over the task's held-out prior simulations, the median 90% "
            f"interval of every one of their own parameters spans more than {INFORMED_MAX_RATIO:g} of the prior's "
            f"width (the narrowest in brackets): the data of this motion seldom switch these effects on, so a "
            f"missing effect among them is seldom named here; a motion that excites them, trained as another task, "
            f"can tell.")


def candidate_role(d: Diagnosis, c: Candidate) -> str:
    """The ``verdict`` column of ``diagnose``'s table: what the decision says of the candidate (never more)."""
    dec = d.decision
    if c.effect in dec.named:
        return "named" if len(dec.named) == 1 else "named (pair)"
    if any(c.effect in a for a in dec.alternatives):
        return "indistinguishable"
    if c.effect in dec.partial:
        return "explains a part"
    r = d.refit((c.effect,))
    if r is None:
        return not_refitted(d, c)
    return f"refit: {set_aside(d, r)}"


def not_refitted(d: Diagnosis, c: Candidate) -> str:
    """Why ``diagnose`` did not refit candidate ``c`` (its verdict column): nothing is missing, a generic term
    (describes the residual, names no cause), its trained model's amortised posterior predictive does not lower the
    nominal fit's score, its screening failed, or the refit budget ``--confirm`` ended above it
    (:func:`softsbi.workflows.criticism.decide.refit_order`)."""
    if not d.test.misspecified:
        return "not refitted: nothing missing"
    if c.generic:
        return "not refitted: generic term"
    g = Gain.of(d.nominal, c.amortised)
    if c.amortised is not None and not (g is not None and g.exceeds(d.k_se)):  # decide.refit_order's test
        return "not refitted: its amortised refit scores no lower"
    if c.amortised is None and not c.screened:
        return "not refitted: screening failed"
    if d.confirm is None:
        return "not refitted: beyond the refit budget"
    return f"not refitted: beyond --confirm {d.confirm}"


def diagnosis_rows(d: Diagnosis) -> list[list[str]]:
    """``diagnose``'s table (:func:`diagnosis_columns`), one row per candidate in the screening's order: effect, kind,
    share of the residual explained in the screening, max-T adjusted p, the amortised refit's summary energy score
    (when the task trained candidates), the refit's check p and summary energy score, and the verdict column
    (:func:`candidate_role`)."""
    amortised = _has_amortised(d)
    rows = []
    for c in d.ranking:
        r = d.refit((c.effect,))
        rows.append([c.effect, c.kind + (" (generic)" if c.generic else ""),
                     pct(None if c.explained is None else max(c.explained, 0.0)),
                     p_short(c.adjusted) if c.adjusted else (c.error or "-")]
                    + ([f"{c.amortised.value:.3g}" if c.amortised else "-"] if amortised else [])
                    + [p_short(r.test) if r else "-", f"{r.score.value:.3g}" if r and r.score else "-",
                       candidate_role(d, c)])
    return rows


def _has_amortised(d: Diagnosis) -> bool:
    return any(c.amortised is not None for c in d.ranking)


def diagnosis_columns(d: Diagnosis) -> list[str]:
    """The column names of :func:`diagnosis_rows`: the amortised score's only when some candidate has one."""
    return [c for c in DIAGNOSIS_COLUMNS if c != AMORTISED_COLUMN or _has_amortised(d)]


#: the column of a trained candidate's amortised refit's summary energy score
AMORTISED_COLUMN = f"amortised score [{SCORE_UNIT}]"
DIAGNOSIS_COLUMNS = ["candidate", "kind", "explains", "max-T p", AMORTISED_COLUMN, "refit check p",
                     f"refit {SUMMARY_ENERGY} [{SCORE_UNIT}]", "verdict"]


def row_label(metric: Metric, a: CheckResult, b: CheckResult, part: str = "") -> str:
    """A ``compare`` row's label in words, for checks ``a`` and ``b`` (``part``: the phase or region of a ``PHASE`` or
    ``REGION`` row)."""
    if metric is Metric.CHAMFER:
        n = f"n={a.n_rollouts}" + ("" if b.n_rollouts == a.n_rollouts else f" and {b.n_rollouts}")
        return f"posterior-predictive Chamfer, mean over the fit's frames ({n} rollouts)"
    if metric is Metric.PHASE:
        t = next(p.t_s for p in a.phases if p.phase == part)
        return f"{part} phase ({t[0]:.2f}-{t[1]:.2f} s)"
    if metric is Metric.REGION:
        return f"region {part}"
    return ROW_NAMES[metric] + ROW_NOTES[metric]


#: the short name of each single-row metric of ``compare`` (its label, less :data:`ROW_NOTES`; the summary's words)
ROW_NAMES = {Metric.CHAMFER: "posterior-predictive Chamfer", Metric.CHAMFER_ONE_SIDED: "one-sided Chamfer",
             Metric.ENERGY_CHAMFER: CHAMFER_ENERGY, Metric.POSTERIOR_MEAN: "posterior-mean rollout"}
#: what the label of each single-row metric adds to its name
ROW_NOTES = {Metric.CHAMFER: "", Metric.CHAMFER_ONE_SIDED: " (measured -> simulated)",
             Metric.ENERGY_CHAMFER: " (a proper score: Chamfer less half the mean Chamfer between two rollouts)",
             Metric.POSTERIOR_MEAN: " Chamfer (the fitted point estimate)"}


def compare_summary(c: CompareResult) -> str:
    """``compare``'s sentence: the error before -> after, the Chamfer energy score, the point estimate, the tests; the
    two fits named in the order of their numbers (``a -> b``)."""
    first = c.row(Metric.CHAMFER)
    s = (f"{c.label_a} -> {c.label_b}: posterior-predictive Chamfer {cm(first.a)}{rollouts(c.check_a.n_rollouts)} -> "
         f"{cm(first.b)}{rollouts(c.check_b.n_rollouts)} ({describe_change(first.a, first.b)})")
    for metric in (Metric.ENERGY_CHAMFER, Metric.POSTERIOR_MEAN):
        row = c.row(metric)
        if row is not None:
            s += f", {ROW_NAMES[metric]} {cm(row.a)} -> {cm(row.b)} ({describe_change(row.a, row.b)})"
    s += f"; misspecification {p_words(c.check_a.test)} -> {p_words(c.check_b.test)}."
    if not c.same_sensor:
        s += (" The two fits use different sensor models (--sensor / --min-height / --frames), so their Chamfer values "
              "measure different things.")
    return s
