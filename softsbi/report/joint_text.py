"""Every sentence and table row of a task's diagnosis across its recordings (``softsbi diagnose RUN RUN ... --out
DIR``), rendered from its typed result (:class:`~softsbi.core.results.joint.JointDiagnosis`). Pure functions: tested
against fixed result objects. The words of a single diagnosis are :mod:`softsbi.report.text`'s."""
from __future__ import annotations

from softsbi.core.results.joint import JointCandidate, JointDiagnosis, short_names
from softsbi.core.results import Diagnosis, Gain
from softsbi.core.types import unit_suffix
from softsbi.core.results.design import undecided_candidates
from softsbi.report.text import (SCORE_UNIT, SUMMARY_ENERGY, SWITCHED_ON_RULE, design_hint, num, p_short,
                                 uninformed_words)

#: the columns of :func:`joint_rows`
JOINT_COLUMNS = ["candidate", f"summed score [{SCORE_UNIT}]", f"gain over nominal [{SCORE_UNIT}]",
                 f"to the best [{SCORE_UNIT}]", "adequate on", "combined check p", "switched on",
                 "estimates: median (range)", "named alone by", "for the task"]
#: the columns of :func:`recording_rows`
RECORDING_COLUMNS = ["#", "recording", "check p", "own verdict", "named alone"]
#: the ``for the task`` column's words for each criterion a candidate fails
#: (:data:`~softsbi.core.results.joint.CRITERIA`)
FAILED = {"improves": "gain within --k-se", "adequate": "misfit on the set", "switched on": "not switched on",
          "not contradicted": "worse on a recording"}


#: what a rig's combined estimate is, in words
COMBINED = ("; combined: the product of the informing recordings' marginal posteriors, assuming the recordings "
            "independent given one value of the parameter for the rig")


def standard_errors(c: JointCandidate) -> str:
    """What a candidate's summed gain's standard errors are: paired over recordings (one task), or the recordings'
    own (a rig)."""
    return "standard errors of the recordings' own scores" if c.rig else "standard errors paired over recordings"


def informing(c: JointCandidate) -> str:
    """A rig's candidate's recordings its gain is summed over, in words: ``"over the 2 recordings whose motion
    informs it"`` (``""`` for one task's)."""
    if not c.rig:
        return ""
    n = len(c.informed_by)
    return (f" over the {n} recording{'s' if n > 1 else ''} whose motion informs it" if any(c.informs) else
            " over every recording (none informs it)")


def combined_words(c: JointCandidate) -> str:
    """A rig's candidate's parameters combined over the recordings that inform it: ``"wind_y 0.8 (90% 0.5 to 1.1)
    m/s"`` (``""`` for one task's)."""
    return "; ".join(f"{e.name} {num(e.mean)} (90% {num(e.q05)} to {num(e.q95)}){unit_suffix(e.unit)}"
                     for e in c.combined)


def p_value(p: float) -> str:
    """A combined p-value in a cell or a sentence: ``"p = 0.031"``."""
    return f"p = {p:.2g}"


def gain_cell(g: Gain | None) -> str:
    """``"8.1 ± 2.3 (z 3.5)"``: a summed gain with its standard error paired over recordings (``"-"``: none)."""
    return "-" if g is None else f"{g.difference:.3g} ± {g.se:.2g} (z {g.z:.1f})"


def recordings_cell(idx: tuple[int, ...], n: int) -> str:
    """``"3 of 5 (#1, #2, #4)"``: which of ``n`` recordings (numbered from 1)."""
    return f"{len(idx)} of {n}" + (f" ({', '.join(f'#{i + 1}' for i in idx)})" if idx and len(idx) < n else "")


def spread_words(c: JointCandidate) -> str:
    """Each parameter's estimates across the recordings: ``"wind 0.38 (0.31 to 0.45) m"`` (median and range)."""
    parts = []
    for name in c.parameters:
        s = c.spread(name)
        unit = next((e.unit for r in c.refits for e in r.estimates if e.name == name), "")
        if s is not None:
            parts.append(f"{name} {num(s[0])} ({num(s[1])} to {num(s[2])}){unit_suffix(unit)}")
    words = "; ".join(parts) or "-"
    return words + (f"; combined: {combined_words(c)}" if c.combined else "")


def task_role(j: JointDiagnosis, c: JointCandidate) -> str:
    """The ``for the task`` column: what the set's decision says of candidate ``c``, else the criteria it fails."""
    dec = j.decision
    if (c.effect,) == dec.named:
        return "named"
    if (c.effect,) in dec.alternatives:
        return "indistinguishable"
    if (c.effect,) == dec.partial:
        return "explains a part"
    if dec.verdict == "nothing-missing":
        return "not named: nothing missing"
    fails = c.fails(j.k_se)
    if not fails and dec.named:  # it meets the criteria, but the named one's summed score is lower by k_se
        return f"not named: {dec.named[0]} scores lower"
    return "not named: " + ", ".join(FAILED[f] for f in fails)


def joint_rows(j: JointDiagnosis) -> list[list[str]]:
    """The task's table (:data:`JOINT_COLUMNS`), one row per candidate refitted on every recording, best summed
    score first: its summed summary energy score, its summed gain over the nominal model and its difference to the
    best (each with the standard error paired over recordings), the recordings where its own refit is adequate,
    Fisher's combined p of its refits' checks, the recordings that switch it on (with the binomial p), its parameters'
    estimates across the recordings (median and range), the recordings whose own diagnosis names it, and the set's
    verdict on it (:func:`task_role`)."""
    n = len(j.recordings)
    return [[c.effect, "-" if c.score is None else f"{c.score:.3g}", gain_cell(c.gain),
             "best" if c is j.candidates[0] and c.score is not None else gain_cell(c.to_best),
             recordings_cell(c.adequate_on, n), p_value(c.adequacy.p_value),
             f"{c.on.count} of {len(c.on.on)} ({p_value(c.on.p_value)})", spread_words(c),
             recordings_cell(j.named_by(c.effect), n) if j.named_by(c.effect) else "-", task_role(j, c)]
            for c in j.candidates]


def no_candidate_words(j: JointDiagnosis) -> str:
    """The sentence that stands for an empty candidates' table (:func:`joint_rows`): why no candidate was refitted
    on every recording."""
    if not j.test.rejects:
        return (f"No candidate was refitted on every recording: the recordings' combined check does not reject "
                f"(Fisher's method, p = {j.test.p_value:.2g} > {j.alpha:g}), so nothing is missing for the task.")
    return ("No candidate was refitted on every recording: no recording's own diagnosis refitted one (--confirm "
            f"{j.confirm}), and none was named with --candidate.")


def own_verdict(d: Diagnosis) -> str:
    """A recording's own verdict with what it names: ``"missing-effect: toy-wind"``, ``"misspecified-unexplained
    (toy-wind explains a part)"``."""
    dec = d.decision
    if dec.named:
        return " + ".join(dec.named)
    return f"({' + '.join(dec.partial)} explains a part)" if dec.partial else "-"


def recording_rows(j: JointDiagnosis) -> list[list[str]]:
    """Each recording's own diagnosis beside the task's (:data:`RECORDING_COLUMNS`): its number, its run, its
    nominal fit's check p, its own verdict and what it names."""
    return [[f"#{i + 1}", name, p_short(d.test), d.verdict, own_verdict(d)]
            for i, (name, d) in enumerate(zip(short_names(j.runs), j.recordings))]


def _not_named(j: JointDiagnosis, c: JointCandidate) -> str:
    """Why candidate ``c`` is not named for the task, criterion by criterion."""
    n, why = len(j.recordings), []
    for f in c.fails(j.k_se):
        if f == "improves":
            why.append("its refits are not scored on every recording" if c.gain is None else
                       f"its summed gain{informing(c)} {c.gain.difference:.3g} {SCORE_UNIT} is {c.gain.z:.1f} "
                       f"{standard_errors(c)} (not more than {j.k_se:g})")
        elif f == "adequate":
            why.append(f"Fisher's combined test of its refits' checks rejects ({p_value(c.adequacy.p_value)} <= "
                       f"{j.alpha:g})")
        elif f == "switched on":
            why.append(f"the data switch it on on {c.on.count} of {len(c.on.on)} recordings"
                       f"{' that inform it' if c.rig and any(c.informs) else ''}, no more than chance allows "
                       f"(binomial {p_value(c.on.p_value)} > {c.on.alpha:g})")
        else:
            why.append(f"its refit scores worse than the nominal fit by more than {j.k_se:g} standard errors on "
                       f"{recordings_cell(c.worse_on, n)}")
    return f"{c.effect}: " + "; ".join(why)


def joint_summary(j: JointDiagnosis) -> str:
    """The set's verdict in a few sentences: what it names (or why nothing), with the three criteria's numbers, and
    the recordings whose own verdict differs."""
    n, dec, t = len(j.recordings), j.decision, j.test
    names = short_names(j.runs)
    whole = "the rig" if j.rig else "the task"
    combined = f"Fisher's combined test of the {n} nominal fits' checks gives {p_value(t.p_value)}"
    if dec.verdict == "nothing-missing":
        s = f"Nothing missing for {whole}: {combined} > {j.alpha:g}."
        own = [(names[i], d) for i, d in enumerate(j.recordings) if d.verdict != "nothing-missing"]
        if own:
            s += (" On its own, " + "; ".join(f"{name}'s diagnosis says {d.verdict}"
                                              + (f" ({own_verdict(d)})" if own_verdict(d) != "-" else "")
                                              for name, d in own)
                  + f": a misfit of {'that recording' if len(own) == 1 else 'those recordings'}, which the set does "
                    f"not share.")
        return s
    if dec.verdict == "missing-effect":
        c = j.candidate(dec.named[0])
        g = c.gain
        desc = next((x.description for d in j.recordings for x in d.ranking if x.effect == c.effect and x.description),
                    "")
        s = (f"Missing effect for {whole}: {c.effect}" + (f" ({desc})" if desc else "") + ". "
             f"Summed{informing(c) if c.rig else f' over the {n} recordings'}, its refits lower the "
             f"{SUMMARY_ENERGY} by {g.difference:.3g} {SCORE_UNIT}, {g.z:.1f} {standard_errors(c)} (more than "
             f"{j.k_se:g}){'; no recording scores worse with it' if c.rig else ''}; Fisher's combined test of its "
             f"refits' checks gives {p_value(c.adequacy.p_value)} > {j.alpha:g} (adequate alone on "
             f"{recordings_cell(c.adequate_on, n)}); the data switch it on on {c.on.count} of {len(c.on.on)} "
             f"recordings (binomial {p_value(c.on.p_value)} <= {c.on.alpha:g} against {c.on.chance:.0%} by chance). "
             f"Its parameters across the recordings: {spread_words(c)} (median and range"
             f"{COMBINED if c.combined else ''}).")
        if dec.alternatives:
            alts = " or ".join(a[0] for a in dec.alternatives)
            s += (f" The recordings cannot tell it from {alts}: it meets the {'four' if j.rig else 'three'} criteria "
                  f"too, with a summed score "
                  f"within {j.k_se:g} {'standard errors' if j.rig else 'paired standard errors'}.")
        return s
    s = f"Misspecified, unexplained for {whole}: {combined} <= {j.alpha:g}"
    if not j.candidates:
        return s + ", and no recording's diagnosis refitted a candidate."
    s += (f", and no candidate of {', '.join(c.effect for c in j.candidates)} meets the "
          f"{'four' if j.rig else 'three'} criteria.")
    if dec.partial:
        c = j.candidate(dec.partial[0])
        s += (f" {c.effect} explains a part: it lowers the summed {SUMMARY_ENERGY} most, by {c.gain.difference:.3g} ± "
              f"{c.gain.se:.2g} {SCORE_UNIT} (z {c.gain.z:.1f}), and the data switch it on, but Fisher's combined "
              f"test of its refits' checks rejects ({p_value(c.adequacy.p_value)} <= {j.alpha:g}).")
    rest = [_not_named(j, c) + "." for c in j.candidates if (c.effect,) != dec.partial]
    return " ".join([s, *rest])


def joint_rule(j: JointDiagnosis) -> str:
    """The rule as applied, in words (a rig's or one task's)."""
    if j.rig:
        return (f"Rule for a rig's {len(set(j.scenarios))} motions ({', '.join(dict.fromkeys(j.scenarios))}): the "
                f"{len(j.recordings)} recordings are diagnosed one by one; the candidates their diagnoses refitted most "
                f"often (at most --confirm {j.confirm}) are refitted on every recording. A candidate is named for the "
                f"rig when its {SUMMARY_ENERGY}, summed over the recordings whose motion informs it (some parameter's "
                f"90% interval narrower than half the prior's, on the trained task's held-out simulations, else on "
                f"the recording's refit; every recording when none does), is lower than the nominal model's by more than "
                f"{j.k_se:g} standard errors of the recordings' own scores, no recording scores worse with it by more "
                f"than {j.k_se:g} of its own, Fisher's combined test of its refits' checks on every recording does not "
                f"reject at {j.alpha:g}, and the informing recordings switch its effect on (each as its own diagnosis "
                f"decides) more often than chance allows, at the chance rate itself (one informing recording decides "
                f"it as its own diagnosis would). Motions differ in what they show, so a gain seen in one motion "
                f"among null ones counts with its own standard error, not the spread across motions.")
    return (f"Rule: the {len(j.recordings)} recordings are diagnosed one by one; the candidates their diagnoses "
            f"refitted most often (at most --confirm {j.confirm}) are refitted on every recording. A candidate is named "
            f"for the task when its {SUMMARY_ENERGY}, summed over the recordings, is lower than the nominal model's by "
            f"more than {j.k_se:g} standard errors paired over recordings (from the spread of the per-recording gains, "
            f"so that one recording's gain does not name an effect for all), Fisher's combined test of its refits' "
            f"checks does not reject at {j.alpha:g}, and more recordings switch its effect on ({SWITCHED_ON_RULE}) "
            f"than chance allows (one-sided binomial test at {j.alpha:g}).")


def joint_text(j: JointDiagnosis, where: str = "DIR") -> list[str]:
    """Everything a task's or a rig's diagnosis says, one paragraph per item: the verdict, the rule, when the set's
    test rejects the trained candidates no recording's task informs, and, when it leaves candidates undecided, the
    command that ranks the motions to record next (``where``: the diagnosis's ``--out`` folder)."""
    blind = j.uninformed
    out = [joint_summary(j), joint_rule(j)] + ([uninformed_words(blind)] if j.test.rejects and blind else [])
    left = undecided_candidates(j, j.family)
    return out + ([design_hint(where, left)] if left else [])
