"""The diagnosis suite's protocol: what a stored row counts as, which rows pool, and the acceptance figures.

Pure functions of the rows that :mod:`benchmarks.diagnosis` writes (no simulation, no softsbi import):

* **Scoring** (:func:`outcome`) is strict: a control is right with ``nothing-missing``, the other engine with
  ``misspecified-unexplained``, a hidden effect only when the verdict names it alone (``decision.named`` is the hidden
  effect). A hidden effect the verdict lists as indistinguishable from the named one is counted apart
  (``indistinguishable``), never as right. Every row is scored here from its stored verdict, so rows stored under an
  earlier, lenient rule count the same way.
* **Errors**: a case's latest row counts (:func:`latest`; the runner reruns a case whose latest row is an error). A
  case whose latest row is an error stays in every rate's denominator as wrong (a control's error counts as a false
  alarm), and the summary states how many there are.
* **Pooling** (:func:`pooling_problem`): a split's rows are summarised together only when they record the same
  settings (the fit's, the estimator's options with its recalibration, the diagnosis's, the cases' with the threshold
  table). Rows stored before rows recorded their settings count as settings unknown, pooled only with unknown rows of
  one commit; otherwise the summary is one line saying why it refuses.
* **Thresholds** (:data:`THRESHOLDS`, ``--thresholds FILE``): a hidden effect's magnitude starts at its measured
  detection threshold; an effect without one starts at :data:`DEFAULT_THRESHOLD`, an unmeasured placeholder, and the
  summary marks it so.
* **Acceptance** (:data:`TARGETS`): the false-alarm rate of the controls with its 95% Clopper-Pearson interval, a KS
  test of the controls' p-values against uniform, the strict named-right rate overall and per effect, the other
  engine's share of ``misspecified-unexplained``, each against its target; the old rule against the new on the cases
  both diagnosed (the same nominal fit).
* **Split size** (:data:`MINIMUMS`): the counts a test split must reach; :func:`cases_for_minimums` is the smallest
  number of cases (whole cycles of :data:`CYCLE`) that reaches them.
"""
from __future__ import annotations

import json
import math
from collections import Counter
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
from scipy import stats

from benchmarks import runner

#: the shipped effects, each hidden in one case per cycle
EFFECTS = ["wind", "air-drag", "extra-damping", "grip-compliance", "table-slope", "sticky-patch", "heavy-hem",
           "calibration-offset", "time-offset", "point-noise", "table-unseen"]
#: one cycle of case labels: 6 controls, one case per shipped effect, one of the other engine
CYCLE = ["control"] * 6 + EFFECTS + ["other-engine"]
LABELS = ["control", *EFFECTS, "other-engine"]
#: magnitude at which the earlier benchmark's development cases detected the effect in 90% of cases (a logistic fit
#: of detection on magnitude, 38-89 cases per effect); None: not measured (no magnitude within the prior detected the
#: effect that reliably), the case's magnitude starts at :data:`DEFAULT_THRESHOLD`
THRESHOLDS: dict[str, float | None] = {e: None for e in EFFECTS} | {
    "calibration-offset": 0.26, "point-noise": 0.37, "wind": 0.36, "time-offset": 0.54, "grip-compliance": 0.82}
#: the lower end of an unmeasured effect's magnitude: a placeholder, not a measured threshold (the summary says so)
DEFAULT_THRESHOLD = 0.5
#: the acceptance targets: false-alarm rate and the upper end of its 95% interval, the KS p-value of the controls'
#: p-values against uniform (above), the strict named-right rate of the hidden effects and the other engine's share
#: of ``misspecified-unexplained`` (at least)
TARGETS = {"false_alarm_rate": 0.05, "false_alarm_upper": 0.10, "ks_p": 0.05, "named_right": 0.80,
           "other_engine": 0.90}
#: what a test split must hold: controls, cases per shipped effect, cases of the other engine
MINIMUMS = {"control": 60, "effect": 10, "other-engine": 10}


def cases_for_minimums() -> int:
    """The fewest cases, in whole cycles of :data:`CYCLE`, that hold :data:`MINIMUMS` (10 cycles: 180)."""
    need = {"control": MINIMUMS["control"], "other-engine": MINIMUMS["other-engine"],
            **{e: MINIMUMS["effect"] for e in EFFECTS}}
    return len(CYCLE) * max(math.ceil(n / CYCLE.count(label)) for label, n in need.items())


def threshold(thresholds: Mapping[str, float | None], label: str) -> float:
    """The lower end of a hidden effect's magnitude: its measured threshold, else :data:`DEFAULT_THRESHOLD`."""
    value = thresholds.get(label)
    return DEFAULT_THRESHOLD if value is None else float(value)


def load_thresholds(path: Path) -> dict[str, float | None]:
    """The threshold table of ``--thresholds FILE``: a JSON object naming every shipped effect, each with its measured
    detection threshold (a magnitude in [0, 1)) or null (not measured).

    Raises:
        SystemExit: one line naming the file and what is wrong (unreadable, not an object, an effect missing or
            unknown, a value out of range).
    """
    try:
        table = json.loads(Path(path).read_text())
    except (OSError, ValueError) as e:
        raise SystemExit(f"--thresholds {path}: cannot read a JSON object ({e})") from None
    if not isinstance(table, dict):
        raise SystemExit(f"--thresholds {path}: expected a JSON object {{effect: threshold or null}}")
    missing, unknown = [e for e in EFFECTS if e not in table], sorted(set(table) - set(EFFECTS))
    if missing or unknown:
        raise SystemExit(f"--thresholds {path}: name every shipped effect once (null where not measured); "
                         f"missing {missing}, unknown {unknown}")
    bad = {e: v for e, v in table.items() if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))
                                                                 or not 0 <= v < 1)}
    if bad:
        raise SystemExit(f"--thresholds {path}: a threshold is a magnitude in [0, 1) or null; got {bad}")
    return {e: (None if table[e] is None else float(table[e])) for e in EFFECTS}


def _names(x: Any) -> list[str]:
    return [] if not x else [x] if isinstance(x, str) else list(x)


def outcome(label: str, verdict: str, named: Any, alternatives: Any = ()) -> str:
    """A verdict's score: ``right``, ``indistinguishable`` (a hidden effect listed alone as indistinguishable from the
    named one, counted apart) or ``wrong``. ``named``: the decision's named effects (a list; a name alone from older
    rows); ``alternatives``: its lists of indistinguishable effects."""
    if label == "control":
        return "right" if verdict == "nothing-missing" else "wrong"
    if label == "other-engine":
        return "right" if verdict == "misspecified-unexplained" else "wrong"
    if verdict != "missing-effect":
        return "wrong"
    if _names(named) == [label]:
        return "right"
    return "indistinguishable" if [label] in [_names(a) for a in alternatives or ()] else "wrong"


def is_error(row: Mapping[str, Any]) -> bool:
    """Whether a row records a failed case (``status`` error, or no verdict)."""
    return row.get("status") == "error" or "error" in row or "verdict" not in row


def row_outcome(row: Mapping[str, Any]) -> str:
    """:func:`outcome` of a row, ``error`` for a failed case."""
    if is_error(row):
        return "error"
    return outcome(row["label"], row["verdict"], row.get("named"), row.get("alternatives"))


def old_outcome(row: Mapping[str, Any]) -> str | None:
    """The old rule's :func:`outcome` of a row: None where the old rule did not diagnose it, ``error`` where it
    failed."""
    old = row.get("old")
    if not isinstance(old, dict):
        return None
    if "verdict" not in old or "error" in old:
        return "error"
    return outcome(row["label"], old["verdict"], old.get("named") if old["verdict"] == "missing-effect" else [],
                   old.get("alternatives"))


def read_rows(path: Path) -> list[dict[str, Any]]:
    """The rows of a JSON-lines file, in order ([] for a missing file)."""
    return [json.loads(x) for x in path.read_text().splitlines() if x.strip()] if path.exists() else []


def latest(rows: Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The last row of each case id, in the order the ids first appear (a rerun replaces an error row)."""
    out: dict[str, dict[str, Any]] = {}
    for i, r in enumerate(rows):
        out[str(r.get("id", f"#{i}"))] = dict(r)
    return list(out.values())


def done_ids(rows: Iterable[Mapping[str, Any]]) -> set[str]:
    """The ids whose latest row is not an error: the cases a run skips."""
    return {r["id"] for r in latest(rows) if "id" in r and not is_error(r)}


def _pool_key(row: Mapping[str, Any]) -> str:
    s = row.get("settings")
    return json.dumps(s, sort_keys=True) if s is not None else f"unknown settings (commit {row.get('commit', '?')})"


def _differing(settings: Sequence[Any], prefix: str = "") -> list[str]:
    """The dotted keys in which ``settings`` (dicts) differ."""
    if not all(isinstance(s, dict) for s in settings):
        return [prefix or "settings"]
    out = []
    for k in sorted({k for s in settings for k in s}):
        vals = [s.get(k, "<absent>") for s in settings]
        if any(json.dumps(v, sort_keys=True) != json.dumps(vals[0], sort_keys=True) for v in vals):
            out += _differing(vals, f"{prefix}{k}.") if all(isinstance(v, dict) for v in vals) else [prefix + k]
    return out


def pooling_problem(rows: Sequence[Mapping[str, Any]], split: str) -> str | None:
    """One line saying why ``rows`` of ``split`` cannot be pooled (their settings differ, or some are unknown), or
    None when they can."""
    keys = Counter(_pool_key(r) for r in rows)
    if len(keys) <= 1:
        return None
    known = [r["settings"] for r in rows if r.get("settings") is not None]
    unknown = sorted({k for k in keys if k.startswith("unknown")})
    what = ", ".join(_differing(known)[:8]) if len({_pool_key(r) for r in rows if r.get("settings")}) > 1 else ""
    why = "; ".join(x for x in [f"settings differ in {what}" if what else "", ", ".join(unknown)] if x)
    return (f"The {split} split's {len(rows)} rows are not summarised: they cannot be pooled ({why}); keep one "
            f"setting per rows file (--results FILE) and rerun the others there.")


def settings_conflict(rows: Sequence[Mapping[str, Any]], settings: Mapping[str, Any],
                      path: Path | str) -> str | None:
    """One line when the stored ``rows`` of ``path`` were run under settings other than ``settings`` (or unknown
    ones), so that new rows could not be pooled with them; None when they can (or there are none)."""
    old = latest(rows)
    if not old or all(r.get("settings") == settings for r in old):
        return None
    recorded = [r["settings"] for r in old if r.get("settings") is not None]
    what = _differing([*recorded, dict(settings)])[:8] if recorded else []
    unknown = sum(r.get("settings") is None for r in old)
    why = "; ".join(([f"differ in {', '.join(what)}"] if what else []) + ([f"{unknown} rows record none"] if unknown
                                                                          else []))
    return (f"--results {path}: its stored rows were run under other settings ({why}); give another --results file "
            f"for these settings (or move the stored rows away), so that no split pools rows of two settings.")


def interval(k: int, n: int) -> list[float]:
    """The 95% Clopper-Pearson interval of ``k`` successes in ``n`` ([0, 1] for n = 0)."""
    if n == 0:
        return [0.0, 1.0]
    ci = stats.binomtest(k, n).proportion_ci(0.95, method="exact")
    return [float(ci.low), float(ci.high)]


def _rate(k: int, n: int) -> dict[str, Any]:
    return {"k": k, "n": n, "rate": k / n if n else None, "ci95": interval(k, n)}


def summary(rows: Sequence[Mapping[str, Any]], split: str) -> dict[str, Any]:
    """The figures of a split's stored rows (every stored row; a case's latest one counts).

    Returns ``{"refused": line, ...}`` when the rows cannot be pooled (:func:`pooling_problem`); otherwise the counts
    (``cases``, ``errors``, ``reruns``), ``by_label`` (per truth: cases, errors, detected, right, indistinguishable,
    the right rate's interval, what was called, the old rule's right on the same fit), ``false_alarms``, ``ks``,
    ``named_right``, ``other_engine`` (each ``k``, ``n``, ``rate``, ``ci95``), ``acceptance`` (:func:`acceptance`),
    ``minimums`` (:func:`minimums`), ``thresholds`` (per effect: the value, ``unmeasured`` or ``unknown``), ``old``
    (the comparison on the cases both rules diagnosed) and the detection by magnitude.
    """
    stored = len(rows)
    rows = latest(rows)
    out: dict[str, Any] = {"split": split, "cases": len(rows), "errors": sum(map(is_error, rows)),
                           "reruns": stored - len(rows), "commits": dict(Counter(r.get("commit", "unknown")
                                                                                  for r in rows))}
    if problem := pooling_problem(rows, split):
        return {**out, "refused": problem}
    settings = rows[0].get("settings") if rows else None
    out["settings"] = "recorded" if settings is not None else "unknown"
    table = (settings or {}).get("cases", {}).get("thresholds")
    out["thresholds"] = {e: ("unknown" if table is None else "unmeasured" if table.get(e) is None else table[e])
                         for e in EFFECTS}
    scored = [(r, row_outcome(r), old_outcome(r)) for r in rows]
    out["by_label"], out["confusion"] = {}, {}
    for label in LABELS:
        rs = [(r, o, oo) for r, o, oo in scored if r.get("label") == label]
        if not rs:
            continue
        k = sum(o == "right" for _, o, _ in rs)
        entry = {"n": len(rs), "errors": sum(o == "error" for _, o, _ in rs), "right": k,
                 "right_ci95": interval(k, len(rs)),
                 "indistinguishable": sum(o == "indistinguishable" for _, o, _ in rs),
                 "detected": sum(o != "error" and r["verdict"] != "nothing-missing" for r, o, _ in rs)}
        olds = [oo for r, o, oo in rs if o != "error" and oo not in (None, "error")]
        if olds:
            entry.update(old_n=len(olds), old_right=olds.count("right"), old_right_ci95=interval(olds.count("right"),
                                                                                                len(olds)))
        out["by_label"][label] = entry
        out["confusion"][label] = dict(Counter("error" if o == "error" else "+".join(_names(r.get("named")))
                                               or r["verdict"] for r, o, _ in rs))
    ctl = [(r, o) for r, o, _ in scored if r.get("label") == "control"]
    out["false_alarms"] = _rate(sum(o != "right" for _, o in ctl), len(ctl))
    pv = [float(r["p_value"]) for r, o in ctl if o != "error" and r.get("p_value") is not None]
    ks = stats.kstest(pv, "uniform") if pv else None
    out["ks"] = {"n": len(pv), "statistic": float(ks.statistic) if ks else None,
                 "p_value": float(ks.pvalue) if ks else None}
    eff = [o for r, o, _ in scored if r.get("label") in EFFECTS]
    out["named_right"] = {**_rate(eff.count("right"), len(eff)), "indistinguishable": eff.count("indistinguishable")}
    oe = [o for r, o, _ in scored if r.get("label") == "other-engine"]
    out["other_engine"] = _rate(oe.count("right"), len(oe))
    out["acceptance"] = acceptance(out)
    out["minimums"] = minimums(out)
    out["old"] = old_comparison(rows)
    with_m = [(r, o) for r, o, _ in scored if r.get("magnitude") is not None]
    out["detection_by_magnitude"] = {f"{a:.2f}-{min(b, 1):.2f}": [sum(o != "error" and r["verdict"] != "nothing-missing"
                                                                      for r, o in with_m if a <= r["magnitude"] < b),
                                                                  sum(a <= r["magnitude"] < b for r, _ in with_m)]
                                     for a, b in [(0.25, 0.5), (0.5, 0.75), (0.75, 1.0001)]}
    drops = [1 - r["score_named"] / r["score_nominal"] for r, o, _ in scored
             if o == "right" and r.get("score_named") and r.get("score_nominal")]
    out["score_drop_median"] = float(np.median(drops)) if drops else None
    return out


def acceptance(s: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """Each criterion of :data:`TARGETS` with its value and ``pass`` (True, False, or None with no case to judge)."""
    fa, ks, nr, oe, t = s["false_alarms"], s["ks"], s["named_right"], s["other_engine"], TARGETS
    return {
        "false_alarms": {"value": fa["rate"], "upper": fa["ci95"][1],
                         "target": f"rate <= {t['false_alarm_rate']:g}, 95% upper bound <= {t['false_alarm_upper']:g}",
                         "pass": None if not fa["n"] else fa["rate"] <= t["false_alarm_rate"]
                         and fa["ci95"][1] <= t["false_alarm_upper"]},
        "control_p_uniform": {"value": ks["p_value"], "target": f"KS p > {t['ks_p']:g}",
                              "pass": None if ks["p_value"] is None else ks["p_value"] > t["ks_p"]},
        "named_right": {"value": nr["rate"], "target": f">= {t['named_right']:g}",
                        "pass": None if not nr["n"] else nr["rate"] >= t["named_right"]},
        "other_engine": {"value": oe["rate"], "target": f">= {t['other_engine']:g}",
                         "pass": None if not oe["n"] else oe["rate"] >= t["other_engine"]}}


def minimums(s: Mapping[str, Any]) -> dict[str, Any]:
    """The split's cases (errors included) per truth against :data:`MINIMUMS`: ``short`` (label: [have, need]) and
    ``met``."""
    have = {label: s["by_label"].get(label, {}).get("n", 0) for label in LABELS}
    need = {label: MINIMUMS["effect" if label in EFFECTS else label] for label in LABELS}
    short = {label: [have[label], need[label]] for label in LABELS if have[label] < need[label]}
    return {"short": short, "met": not short}


def old_comparison(rows: Sequence[Mapping[str, Any]]) -> dict[str, Any] | None:
    """The old rule against the new on the cases both diagnosed without error (the same nominal fit): ``n``,
    ``agree`` (same verdict and named effects), ``new_right``, ``old_right`` (strict, with intervals), ``not_shared``
    (either rule failed)
    and the old checkouts' ``commits``; ``refused`` when the old verdicts come from more than one checkout commit.
    None when no row has an old verdict."""
    olds = [r for r in rows if isinstance(r.get("old"), dict)]
    if not olds:
        return None
    commits = dict(Counter(r["old"].get("commit", "unknown") for r in olds))
    if len(commits) > 1:
        return {"commits": commits, "refused": f"The old rule's verdicts come from {len(commits)} checkouts "
                                               f"({', '.join(commits)}): not compared; rerun them with one --old."}
    shared = [r for r in olds if not is_error(r) and old_outcome(r) != "error"]
    new = sum(row_outcome(r) == "right" for r in shared)
    old = sum(old_outcome(r) == "right" for r in shared)
    agree = sum(r["verdict"] == r["old"]["verdict"] and sorted(_names(r.get("named"))) == sorted(_names(
        r["old"].get("named") if r["old"]["verdict"] == "missing-effect" else [])) for r in shared)
    return {"n": len(shared), "agree": agree, "new_right": _rate(new, len(shared)),
            "old_right": _rate(old, len(shared)), "not_shared": len(olds) - len(shared), "commits": commits}


def _ci(c: Sequence[float]) -> str:
    return f"{c[0]:.2f}-{c[1]:.2f}"


def _verdict(p: bool | None) -> str:
    return "not judged (no case)" if p is None else "pass" if p else "FAIL"


def _frac(r: Mapping[str, Any], what: str = "") -> str:
    return f"{r['k']} of {r['n']}{what and ' ' + what}" + (f" ({r['rate']:.2f}, 95% interval {_ci(r['ci95'])})"
                                                           if r["n"] else "")


def report(s: Mapping[str, Any], split: str) -> dict[str, Any]:
    """The summary (:func:`summary`) as the suite's table and notes: one line when the rows were not pooled."""
    if "refused" in s:
        return {"tables": [], "notes": [s["refused"]]}
    if not s["cases"]:
        return {"tables": [], "notes": [f"No case of the {split} split is stored yet."]}
    rows = []
    for label, e in s["by_label"].items():
        th = s["thresholds"].get(label)
        th = None if th is None else f"{th:.2f}" if isinstance(th, float) else (
            f"unmeasured ({DEFAULT_THRESHOLD:g} placeholder)" if th == "unmeasured" else th)
        old = [f"{e['old_right']} of {e['old_n']}", _ci(e["old_right_ci95"])] if "old_n" in e else [None, None]
        rows.append([label, th, e["n"], e["errors"], e["detected"], e["right"], _ci(e["right_ci95"]),
                     e["indistinguishable"], *old])
    acc = s["acceptance"]
    reruns = f", {s['reruns']} earlier rows replaced by reruns" if s["reruns"] else ""
    notes = [f"{s['cases']} cases, {s['errors']} of them errors (counted as wrong; a control's as a false alarm)"
             f"{reruns}; settings "
             + ("recorded and equal in every row." if s["settings"] == "recorded" else
                "unknown (rows stored before rows recorded them: one commit, thresholds unknown).")
             + " Commits: " + ", ".join(f"`{c}` ({n})" for c, n in s["commits"].items()) + ".",
             f"False alarms: {_frac(s['false_alarms'], 'controls')}: {_verdict(acc['false_alarms']['pass'])} (target "
             f"{acc['false_alarms']['target']}).",
             "Control p-values against uniform: KS p = "
             + (f"{s['ks']['p_value']:.3f}" if s["ks"]["p_value"] is not None else "-")
             + f" (n = {s['ks']['n']}): {_verdict(acc['control_p_uniform']['pass'])} (target "
             f"{acc['control_p_uniform']['target']}).",
             "Named right (the verdict names the hidden effect alone): "
             f"{_frac(s['named_right'], 'hidden-effect cases')} ({s['named_right']['indistinguishable']} more listed "
             "as indistinguishable, not counted right): "
             f"{_verdict(acc['named_right']['pass'])} (target {acc['named_right']['target']}).",
             f"Other engine called misspecified-unexplained: {_frac(s['other_engine'])}: "
             f"{_verdict(acc['other_engine']['pass'])} (target {acc['other_engine']['target']}).",
             "Split size: " + ("meets" if s["minimums"]["met"] else "falls short of")
             + f" the test split's minimums ({MINIMUMS['control']} controls, {MINIMUMS['effect']} cases per shipped "
             f"effect, {MINIMUMS['other-engine']} of the other engine; {cases_for_minimums()} cases)"
             + ("." if s["minimums"]["met"] else ": " + ", ".join(f"{k} {h} of {n}" for k, (h, n)
                                                                  in s["minimums"]["short"].items()) + ".")]
    unmeasured = [e for e, v in s["thresholds"].items() if v == "unmeasured"]
    if unmeasured:
        notes.append(f"No measured detection threshold (magnitudes from the unmeasured placeholder "
                     f"{DEFAULT_THRESHOLD:g}): {', '.join(unmeasured)}.")
    if (o := s["old"]) is not None:
        notes.append(o["refused"] if "refused" in o else
                     f"Old rule (checkout `{next(iter(o['commits']))}`) on the same nominal fits: {o['n']} cases "
                     f"shared ({o['not_shared']} not: either rule failed); verdicts agree in {o['agree']}; named "
                     f"right: this rule {_frac(o['new_right'])}, the old rule {_frac(o['old_right'])}.")
    notes += ["What was called, per truth: " + "; ".join(f"{k}: " + ", ".join(f"{c} {n}" for c, n in v.items())
                                                        for k, v in s["confusion"].items()) + ".",
              "Detected against magnitude: " + ", ".join(f"{k}: {d} of {n}" for k, (d, n)
                                                         in s["detection_by_magnitude"].items()) + "."]
    if s.get("score_drop_median") is not None:
        notes.append(f"Median fall of the energy score of the summaries from the nominal fit to the named refit, right "
                     f"cases: {s['score_drop_median'] * 100:.0f}%.")
    return {"tables": [runner.table(f"Diagnosis, {split} split: verdicts per truth",
                                    ["truth", "threshold", "cases", "errors", "detected", "right (this rule)",
                                     "95% interval", "listed indistinguishable", "right (old rule, same fit)",
                                     "95% interval"], rows)], "notes": notes}
