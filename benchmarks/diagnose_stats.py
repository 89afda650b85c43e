"""Statistical benchmark of ``diagnose``'s verdicts: false alarms, confusion matrix, power.

Cases are deterministic from ``--seed`` and their index: case ``i`` is a control (the nominal model
is true) when ``i % (1 + E) == 0``, else a measurement with the ``(i % (1 + E))``-th candidate effect
hidden (``E`` candidate effects). Truths are random (nominal parameters uniform in the middle 60%
of their prior box; scenario drawn from the suite's); a hidden effect's magnitude ``m`` is uniform
in ``[0.1, 1]``: each effect parameter moves from its nominal (switched-off) value a fraction ``m``
of the way to an edge of its range (random edge for two-sided parameters such as wind).

Each case fits the nominal model with a small budget, diagnoses it (screening verdict; refits only
with ``--confirm``) and appends one JSON line to ``--results`` (resumable: cases already there are
skipped, so the benchmark grows over several sessions). ``summary`` computes the false-alarm rate
with its binomial standard error (and a Clopper-Pearson 95% interval), the confusion matrix (truth x
verdict/named effect) and detection vs magnitude.

Usage:
    python benchmarks/diagnose_stats.py run --suite mujoco --cases 0:20 --results benchmarks/results/diagnose_stats.jsonl
    python benchmarks/diagnose_stats.py run --suite mujoco --cases 45:110 --only control   # controls only
    python benchmarks/diagnose_stats.py run --suite cross-engine --cases 0:8 --confirm 2   # with refits
    python benchmarks/diagnose_stats.py pm-rollout --out RUNS...   # posterior-mean rollout drops of stored refits
    python benchmarks/diagnose_stats.py summary --results benchmarks/results/diagnose_stats.jsonl [--confirm 2]
Rows with refits carry the id suffix ``-refit<N>`` and are summarised apart (``summary --confirm N``).
Rows diagnosed with check's joint test (the omnibus and the directional test, Bonferroni-combined:
``softsbi.workflows.screening.misspecification_verdict``) carry ``"test": "joint"`` and the id suffix ``-joint``;
rows stored before it have the omnibus test alone (``summary --test omnibus``, the default ``joint``).
Suites: ``mujoco`` (mujoco-flex; lift, wipe, fling, wind; effects wind, air-drag, extra-damping,
grip-compliance), ``cross-engine`` (measurements by pybullet-massspring fitted with mujoco-flex; the
right verdict is misspecified-unexplained) and ``toy`` (the test plugin's toy-gauss and toy-wind; needs tests/plugins/softsbi_toy).
"""
from __future__ import annotations

import argparse
import json
import time
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
from scipy import stats

from softsbi.plugins import registry
from softsbi.workflows.diagnose import diagnose_run
from softsbi.workflows.fit import FitConfig, run_fit
from softsbi.workflows.measurement import simulate_recording
from softsbi.workflows.stats import ALPHA, FEATURE_NAMES

#: the misspecification test the verdicts below are decided with (stored with every new row)
TEST = "joint"
#: summaries per frame of check's and diagnose's tests (stored with every new row as ``n_summaries``; rows stored
#: without the field had 13: no local thickness, before the twenty-sixth session)
N_SUMMARIES = len(FEATURE_NAMES)

#: the ten named candidates installed with softsbi before table-unseen (screened by the newer suites)
NAMED_CANDIDATES = ["wind", "air-drag", "extra-damping", "grip-compliance", "table-slope", "sticky-patch",
                    "heavy-hem", "calibration-offset", "time-offset", "point-noise"]

SUITES: dict[str, dict[str, Any]] = {
    "mujoco": {"backend": "mujoco-flex", "scenarios": ["lift", "wipe", "fling", "wind"],
               "effects": ["wind", "air-drag", "extra-damping", "grip-compliance"],
               "backend_options": {"grid": 7}, "n_points": 64, "n_dense": 300, "estimator_options": {}},
    # data from the other engine (pybullet-massspring at random truths), fitted with mujoco-flex: the
    # right verdict is misspecified-unexplained (no installed effect turns one engine into the other)
    "cross-engine": {"backend": "mujoco-flex", "data_backend": "pybullet-massspring",
                     "data_backend_options": {"grid": 7}, "scenarios": ["lift", "wipe", "fling"],
                     "effects": ["wind", "air-drag", "extra-damping", "grip-compliance"],
                     "backend_options": {"grid": 7}, "n_points": 64, "n_dense": 300, "estimator_options": {}},
    # the candidates added with the effect door (issue 19 item 1): physics (table-slope, sticky-patch,
    # heavy-hem) and sensor (calibration-offset, time-offset, point-noise) effects hidden, and all ten named
    # candidates screened
    "mujoco-more": {"backend": "mujoco-flex", "scenarios": ["lift", "wipe", "fling", "wind"],
                    "effects": ["table-slope", "sticky-patch", "heavy-hem", "calibration-offset", "time-offset",
                                "point-noise"],
                    "candidates": NAMED_CANDIDATES,
                    "backend_options": {"grid": 7}, "n_points": 64, "n_dense": 300, "estimator_options": {}},
    # the sensor candidate added last (points near the table unseen), hidden alone; all eleven named screened
    "table-unseen": {"backend": "mujoco-flex", "scenarios": ["lift", "wipe", "fling", "wind"],
                     "effects": ["table-unseen"],
                     "candidates": NAMED_CANDIDATES + ["table-unseen"],
                     "backend_options": {"grid": 7}, "n_points": 64, "n_dense": 300, "estimator_options": {}},
    # pairs of hidden effects (issue 19 item 5): both switched on at magnitudes in [0.4, 1]; right = the
    # verdict names both (the selected effect and the forward selection's second), nothing else
    "pairs": {"backend": "mujoco-flex", "scenarios": ["lift", "wipe", "fling", "wind"],
              "pairs": [["wind", "extra-damping"], ["wind", "calibration-offset"],
                        ["extra-damping", "calibration-offset"]], "magnitude_range": [0.4, 1.0],
              "effects": ["wind", "extra-damping", "calibration-offset"],
              "candidates": NAMED_CANDIDATES,
              "backend_options": {"grid": 7}, "n_points": 64, "n_dense": 300, "estimator_options": {}},
    # one named effect hidden beyond its declared prior (magnitude 1-1.5: the parameter goes past the prior's edge
    # by up to half the distance from its switched-off value), the case confirm_effect's widening is for: a user's
    # effect larger than its prior's guess. Stored apart (magnitudes above 1 are outside the power curves' range)
    "beyond-prior": {"backend": "mujoco-flex", "scenarios": ["lift", "wipe", "fling", "wind"],
                     "effects": NAMED_CANDIDATES, "candidates": NAMED_CANDIDATES, "magnitude_range": [1.0, 1.5],
                     "backend_options": {"grid": 7}, "n_points": 64, "n_dense": 300, "estimator_options": {}},
    "toy": {"backend": "toy-gauss", "scenarios": ["toy"], "effects": ["toy-wind"], "backend_options": {},
            "n_points": 16, "n_dense": 64, "estimator_options": {"max_epochs": 80, "hidden": [64, 64]}},
}


def _scenario(name: str):
    if name == "toy":
        from softsbi_toy.plugin import toy_scenario
        return toy_scenario(4)
    from softsbi.scenarios.builtin import lift_scenario, make_scenario
    return lift_scenario(None) if name == "lift" else make_scenario(name)


def hidden_effects(case: dict[str, Any]) -> list[str]:
    """The effects hidden in a case's measurement (none for controls and other-engine data)."""
    return [] if case["truth_label"] in ("control", "other-engine") else case["truth_label"].split("+")


#: the right verdict of cases without a named hidden effect
CORRECT_VERDICT = {"control": "nothing-missing", "other-engine": "misspecified-unexplained"}


def make_case(suite: str, seed: int, i: int) -> dict[str, Any]:
    """Case ``i`` of ``suite`` (deterministic from ``seed`` and ``i``): ``id``, ``truth_label``
    (``control``, ``other-engine``, the hidden effect, or for the ``pairs`` suite two effects joined by
    ``+``), ``scenario``, ``truth`` (physical units), ``magnitude`` (the smallest of a pair's)."""
    cfg = SUITES[suite]
    rng = np.random.default_rng([seed, i, 41])
    effects = cfg["effects"]
    k = i % (1 + len(effects))
    if "pairs" in cfg:
        label = "+".join(cfg["pairs"][i % len(cfg["pairs"])])
    else:
        label = "other-engine" if "data_backend" in cfg else "control" if k == 0 else effects[k - 1]
    scen = cfg["scenarios"][int(rng.integers(len(cfg["scenarios"])))]
    sc = _scenario(scen)
    reg = registry()
    data_backend = cfg.get("data_backend", cfg["backend"])
    space = reg.simulator(data_backend)(**cfg.get("data_backend_options", cfg["backend_options"])).param_space(sc)
    truth = space.as_dict(space.from_unit(rng.uniform(0.2, 0.8, space.dim)))
    magnitude = None
    for name in ([] if label in ("control", "other-engine") else label.split("+")):
        m = float(rng.uniform(*cfg.get("magnitude_range", (0.1, 1.0))))
        magnitude = m if magnitude is None else min(m, magnitude)
        eff = reg.effect(name)()
        es, nom = eff.param_space(), eff.nominal()
        for p in es:
            ps1 = es.subset([p.name])
            u0 = float(ps1.to_unit(np.array([nom[p.name]]))[0])
            edge = (1.0 if rng.random() < 0.5 else 0.0) if 0.05 < u0 < 0.95 else (1.0 if u0 <= 0.05 else 0.0)
            truth[p.name] = float(ps1.from_unit(np.array([u0 + m * (edge - u0)]))[0])
    return {"id": f"{suite}-s{seed}-{i}", "suite": suite, "index": i, "truth_label": label, "scenario": scen,
            "truth": truth, "magnitude": magnitude}


def run_case(case: dict[str, Any], out: Path, rounds: int, sims: int, n_null: int, max_null: int,
             confirm: int, workers: int | None, confirm_budget: dict[str, int] | None = None,
             proposal: str = "corrected", alpha: float = ALPHA,
             candidates: Sequence[str] | None = None) -> dict[str, Any]:
    """Fit the nominal model to the case's measurement and diagnose it; the JSON line's fields.

    ``confirm_budget``: ``{"rounds", "sims_per_round"}`` of the confirmation refits (default: the
    nominal fit's); ``candidates`` are screened (default the suite's: :func:`suite_candidates`) and stored with
    the row. ``proposal``: the nominal fit's (rows stored before the field existed were fitted with
    ``"corrected"``)."""
    t0 = time.perf_counter()
    cfg = SUITES[case["suite"]]
    hidden = hidden_effects(case)
    meas = simulate_recording(cfg.get("data_backend", cfg["backend"]), _scenario(case["scenario"]), case["truth"],
                              backend_options=cfg.get("data_backend_options", cfg["backend_options"]), effects=hidden,
                              n_points=cfg["n_points"],
                              n_dense=cfg["n_dense"], seed=1000 + case["index"])
    fc = FitConfig(backend=cfg["backend"], backend_options=cfg["backend_options"], estimator="rkhs",
                   rounds=rounds, sims_per_round=sims, workers=workers, n_points=cfg["n_points"], n_eval=n_null,
                   n_dense=cfg["n_dense"], seed=case["index"], estimator_options=cfg["estimator_options"],
                   proposal=proposal)
    run_dir = out / case["id"]
    run_fit(run_dir, meas, fc)
    screened = list(candidates or suite_candidates(case["suite"]))
    d = diagnose_run(run_dir, effects=screened, n_null=n_null, max_null=max_null,
                     workers=workers, confirm=confirm, confirm_budget=confirm_budget, alpha=alpha)
    return {**row_fields(case, d), "proposal": proposal, "candidates": screened,
            "budget": {"rounds": rounds, "sims_per_round": sims, "n_null": n_null, "max_null": max_null,
                       "confirm": confirm, "confirm_budget": confirm_budget, "alpha": alpha},
            "simulations": d["simulations"], "wall_s": time.perf_counter() - t0}


def called_and_correct(case: dict[str, Any], verdict: str, named: str | None,
                       named_all: Sequence[str]) -> tuple[str, bool]:
    """The scoring rule: what a verdict ``called`` (the named effects joined by ``+`` when more than one, else the
    named effect or the verdict) and whether it is ``correct``: exactly the case's hidden effects named, no more (a
    single hidden wind named "wind + extra damping" is not; until the twenty-second session such a row counted as
    right when the first named was), or for a case without a hidden effect the verdict :data:`CORRECT_VERDICT`
    gives its label."""
    hidden = hidden_effects(case)
    called = "+".join(sorted(named_all)) if len(named_all) > 1 else named or verdict
    return called, (sorted(named_all) == sorted(hidden) if hidden else verdict == CORRECT_VERDICT[case["truth_label"]])


def row_fields(case: dict[str, Any], d: dict[str, Any]) -> dict[str, Any]:
    """The JSON line's fields that come from the case and its diagnosis ``d`` (``diagnosis.json``)."""
    named = d["selected"] if d["verdict"] == "missing-effect" else None
    # the effects the verdict names: after refits the diagnosis says (named_effects), else the screening's
    named_all = (list(d["named_effects"]) if d.get("named_effects") is not None else
                 [named] + [e for e in d["significant"] if e != named]) if named else []
    called, correct = called_and_correct(case, d["verdict"], named, named_all)
    return {**case, "verdict": d["verdict"], "named": named, "called": called, "named_all": named_all,
            "correct": correct,
            "second": d["significant"][1:],
            # refits that explain the misfit as well as the named one (diagnose: the data cannot tell them apart)
            "alternatives": [t["effect"] for t in d.get("indistinguishable") or []],
            "remaining": {k: d["remaining"][k] for k in ("fraction", "p_value")} if d.get("remaining") else None, "misspecification_p": d["misspecification"]["p_value"],
            "misspecification_p_text": d["misspecification"]["p_text"], "n_null": d["n_null"], "test": TEST,
            "n_summaries": N_SUMMARIES,
            "omnibus_p": d["misspecification"]["omnibus"]["p_value"],
            "directional_p": (d["misspecification"].get("directional") or {}).get("p_value"),
            "ranking": [[r["effect"], round(r["explained_fraction"], 3), r["adjusted_p_value"]]
                        for r in d["ranking"] if "statistic" in r],
            # per refit: effect, error drop, check's test of the refit (p, still misspecified), and the fraction of
            # the nominal's summary bias it removes with its z (None for refits made before it was kept), and the
            # drop of the posterior predictive's energy score (None for refits made before it was computed), and
            # the drop of the posterior-mean rollout's Chamfer (None before it was computed; `pm-rollout` adds it),
            # and for an effect seen in the local thickness (point noise) its thickness bias's fall with its z
            "refits": [[c["effect"], c.get("drop"), (c.get("misspecification_after") or {}).get("p_value"),
                        (c.get("misspecification_after") or {}).get("misspecified"), c.get("bias_fall"),
                        c.get("bias_fall_z"), c.get("energy_drop"), c.get("pm_drop"), c.get("thickness_bias_fall"),
                        c.get("thickness_bias_fall_z")] for c in d["confirmed"]],
            "screening_verdict": d.get("screening_verdict", d["verdict"]),
            # the candidate below rule 2's share that a refit decided on (diagnose.refit_decides), or None
            "refit_decides": d.get("refit_decides")}


#: the fields of a stored row that define its case (:func:`make_case`); the rest come from its diagnosis
CASE_KEYS = ("id", "suite", "index", "truth_label", "scenario", "truth", "magnitude")


def scored(r: dict[str, Any]) -> dict[str, Any]:
    """Row ``r`` with ``called`` and ``correct`` from its stored verdict and named effects under the current
    scoring rule (:func:`row_fields`: the hidden effects named, no more), so that rows stored under an older rule
    are counted the same way. Rows without ``named_all`` (failed cases, or tests' hand-made rows) are kept as
    they are."""
    if "verdict" not in r or "named_all" not in r or not hidden_effects(r):
        return r
    called, correct = called_and_correct(r, r["verdict"], r.get("named"), r["named_all"] if r.get("named") else [])
    return {**r, "called": called, "correct": correct}


def load_rows(results: Path) -> list[dict[str, Any]]:
    """The stored rows of ``results`` (one JSON object per line), scored under the current rule (:func:`scored`)."""
    return [scored(json.loads(x)) for x in results.read_text().splitlines() if x.strip()]


def save_rows(results: Path, rows: Sequence[dict[str, Any]]) -> None:
    """Write ``rows`` back to ``results``, one JSON object per line."""
    results.write_text("".join(json.dumps(x) + "\n" for x in rows))


#: the fields a stored row keeps when its case is run again (:func:`merge_rows`): they describe the case's data
#: (the hidden effect's size in it), not its diagnosis. The oracle floor is not kept: it is stored with the nominal
#: fit's Chamfer, which the new run replaces (``floor`` adds both again)
CASE_DATA_KEYS = ("effect_size",)


def merge_rows(results: Path, new_files: Sequence[Path], note: str | None = None) -> dict[str, int]:
    """Merge rows run apart (``run --results FILE``) into ``results``: a row whose id is already stored replaces it
    in place (the case run again on the current code, e.g. because its stored diagnosis was decided under an older
    rule), keeping the old row's :data:`CASE_DATA_KEYS` and recording ``rerun`` = ``note`` and the old verdict
    (``rerun_was``: ``called``, ``correct``); other rows are appended (one that diagnosed a stored measurement under
    another protocol's id gets ``rerun`` and ``rerun_was`` with that row's ``id``; the summary counts the newer,
    :func:`one_row_per_case`). Rows that ended in an error are skipped.
    Returns ``{"replaced", "appended", "skipped"}``."""
    rows = load_rows(results)
    where = {r["id"]: i for i, r in enumerate(rows)}
    k = {"replaced": 0, "appended": 0, "skipped": 0}
    for f in new_files:
        for new in load_rows(f):
            if new.get("error") or "verdict" not in new:
                k["skipped"] += 1
                continue
            i = where.get(new["id"])
            if i is None:
                # the same measurement stored under another protocol's id (e.g. refits at the nominal budget, now
                # 3 x 100): kept, and the summary counts the newest (select_rows); the new row says what it follows
                key = case_key(new)
                same = [r for r in rows if case_key(r) == key] if key[0] != "row" else []
                if same:
                    new["rerun"] = note
                    new["rerun_was"] = {"called": same[-1].get("called"), "correct": same[-1].get("correct"),
                                        "id": same[-1]["id"]}
                where[new["id"]] = len(rows)
                rows.append(new)
                k["appended"] += 1
                continue
            old = rows[i]
            new.update({key: old[key] for key in CASE_DATA_KEYS if key in old and key not in new})
            new["rerun"] = note
            new["rerun_was"] = {"called": old.get("called"), "correct": old.get("correct")}
            rows[i] = new
            k["replaced"] += 1
    save_rows(results, rows)
    return k


def find_run_dir(outs: Sequence[Path], case_id: str, marker: str = "diagnosis.json") -> Path | None:
    """The ``out / case_id`` among ``outs`` whose ``marker`` was written last (a case run again, e.g. an interrupted
    one finished in a later session's folder, or a point-noise case refitted apart, has several); None when none
    holds it."""
    found = [o / case_id for o in outs if (o / case_id / marker).exists()]
    return max(found, key=lambda d: (d / marker).stat().st_mtime) if found else None


def redecide_rows(results: Path, outs: Sequence[Path], workers: int | None = 1) -> list[str]:
    """Rule 3 applied again (:func:`softsbi.workflows.diagnose.redecide`) to the stored rows it can change: those
    with a refit that check accepted (``p > 0.2``, not misspecified) whose Chamfer did not fall, and those whose
    screening named an effect that no refit confirmed (the third verdict after refits), where refits below rule 2's
    share may follow (:func:`softsbi.workflows.diagnose.refits_below_share`; these simulate). Their run
    directories are looked up in ``outs``; each diagnosis.json is rewritten and the row's verdict fields replaced
    (marked ``"redecided"``). Running it again re-applies the rule without simulating (the bias and the refits are
    kept in diagnosis.json). Returns the ids changed in verdict or name."""
    from softsbi.workflows.diagnose import redecide
    rows = load_rows(results)
    changed = []
    for r in rows:
        acc_rise = [x for x in r.get("refits") or [] if x[2] is not None and x[3] is False and (x[1] or 0) <= 0]
        unconfirmed = r.get("refits") and r["verdict"] == "misspecified-unexplained" \
            and r.get("screening_verdict") == "missing-effect"
        run_dir = find_run_dir(outs, r["id"])
        if not (acc_rise or unconfirmed) or run_dir is None:
            continue
        d = json.loads((run_dir / "diagnosis.json").read_text())
        confirm = r.get("budget", {}).get("confirm") or int(r["id"].split("-refit")[1][0])
        d = redecide(run_dir, d, confirm, workers, budget=(r.get("budget") or {}).get("confirm_budget"))
        (run_dir / "diagnosis.json").write_text(json.dumps(d, indent=2))
        new = row_fields({k: r[k] for k in CASE_KEYS}, d)
        if (new["verdict"], new["named"]) != (r["verdict"], r["named"]):
            changed.append(r["id"])
        print(json.dumps({"id": r["id"], "truth": r["truth_label"], "before": [r["verdict"], r["named"]],
                          "after": [new["verdict"], new["named"]],
                          "refits": [[x[0], x[1], x[2], x[4], x[5]] for x in new["refits"]]}), flush=True)
        r.update(new, redecided=True)
        save_rows(results, rows)
    return changed


def keep_backfilled(old: Sequence[list[Any]], new: Sequence[list[Any]]) -> list[list[Any]]:
    """A row's refits after it was decided again (``new``), with the energy and posterior-mean drops
    (``refits[i][6:8]``) that backfills (``truth-energy``, ``pm-rollout``) stored in the row but not in
    diagnosis.json carried over from ``old`` for the same refit: the refit's runs are unchanged."""
    before = {x[0]: list(x) + [None] * (8 - len(x)) for x in old}
    out = []
    for x in new:
        x, b = list(x) + [None] * (8 - len(x)), before.get(x[0], [None] * 8)
        out.append(x[:6] + [b[i] if x[i] is None else x[i] for i in (6, 7)] + x[8:])
    return out


def unresolved_refit_checks(d: dict[str, Any]) -> list[dict[str, Any]]:
    """The refits of a stored diagnosis ``d`` whose check (``misspecification_after``) stopped at a first stage
    that does not resolve its decision (:func:`softsbi.workflows.screening.joint_resolved`) and did not grow."""
    from softsbi.workflows.screening import joint_resolved
    from softsbi.workflows.stats import MCPValue
    out = []
    for c in d.get("confirmed") or []:
        m = c.get("misspecification_after") or {}
        if not m or m.get("extended") or m.get("n_null", 0) >= m.get("max_null", 0):
            continue
        ps = [MCPValue(t["exceed"], t["n_null"]) for t in (m.get("omnibus"), m.get("directional")) if t]
        if ps and not joint_resolved(ps, m["alpha"] / len(ps)):
            out.append(c)
    return out


def stored_diagnoses(rows: list[dict[str, Any]], outs: Sequence[Path], ids: Sequence[str] | None, done: str,
                     select: Callable[[dict[str, Any]], list[dict[str, Any]]], keep_as: str | None = None):
    """The stored rows (or ``ids``) not yet marked ``done`` whose run directory (looked up in ``outs``) holds a
    diagnosis in which ``select`` finds refits: yields ``(row, run_dir, diagnosis, selected)``, after keeping the
    diagnosis as ``run_dir / keep_as`` (once; an interrupted call keeps the first)."""
    for r in rows:
        if (ids and r["id"] not in ids) or done in r:
            continue
        run_dir = find_run_dir(outs, r["id"])
        if run_dir is None:
            continue
        d = json.loads((run_dir / "diagnosis.json").read_text())
        todo = select(d)
        if not todo:
            continue
        if keep_as and not (run_dir / keep_as).exists():
            (run_dir / keep_as).write_text((run_dir / "diagnosis.json").read_text())
        yield r, run_dir, d, todo


def decide_stored_again(results: Path, outs: Sequence[Path], ids: Sequence[str] | None, mark: str,
                        select: Callable[[dict[str, Any]], list[dict[str, Any]]], keep_as: str,
                        redo: Callable[..., None], report: Callable[..., tuple[dict[str, Any], dict[str, Any]]],
                        workers: int | None = 1) -> list[str]:
    """The loop every ``REDO_STORED`` subcommand shares: for each stored row (or ``ids``) whose run directory (looked
    up in ``outs``) has refits ``select`` lists (:func:`stored_diagnoses`; the old diagnosis kept as ``keep_as``),
    ``redo(run_dir, diagnosis, selected, workers, budget)`` changes those refits in the diagnosis, then the rules are applied again
    (:func:`softsbi.workflows.diagnose.redecide`, at the row's refit budget, which also refits a pair where the rules
    ask for one) and diagnosis.json rewritten. The row's verdict fields are replaced (the energy and posterior-mean
    drops backfills stored kept, :func:`keep_backfilled`); the old verdict and name, with the mark fields of
    ``report(diagnosis, selected) -> (printed, kept)``, are kept under ``mark``. ``results`` is rewritten after each
    row, so an interrupted call continues where it stopped. Returns the ids whose verdict or name changed."""
    from softsbi.workflows.diagnose import redecide
    rows = load_rows(results)
    changed = []
    for r, run_dir, d, todo in stored_diagnoses(rows, outs, ids, mark, select, keep_as):
        t0 = time.perf_counter()
        b = r.get("budget") or {}
        redo(run_dir, d, todo, workers, b)
        confirm = b.get("confirm") or int(r["id"].split("-refit")[1][0])
        d = redecide(run_dir, d, confirm, workers, budget=b.get("confirm_budget"))
        (run_dir / "diagnosis.json").write_text(json.dumps(d, indent=2))
        new = row_fields({k: r[k] for k in CASE_KEYS}, d)
        new["refits"] = keep_backfilled(r.get("refits") or [], new["refits"])
        if (new["verdict"], new["named"]) != (r["verdict"], r["named"]):
            changed.append(r["id"])
        printed, kept = report(d, todo)
        print(json.dumps({"id": r["id"], "truth": r["truth_label"], "before": [r["verdict"], r["named"]],
                          "after": [new["verdict"], new["named"]], **printed,
                          "s": round(time.perf_counter() - t0)}), flush=True)
        r.update(new, **{mark: {"verdict": r["verdict"], "named": r["named"], **kept}})
        save_rows(results, rows)
    return changed


def check_refit_again(d: dict[str, Any], c: dict[str, Any], workers: int | None = 1):
    """Check's test of a stored refit ``c`` of diagnosis ``d``, computed again as ``misspecification_verdict`` now
    does, at the refit check's own level and cap: its posterior-predictive rollouts re-simulated with their seeds
    from the first stage confirm_effect requested (``n_null`` counts the successes among those requests). Returns
    ``misspecification_verdict``'s ``(test, screening, ranking)``."""
    from softsbi.workflows.screening import candidate_effects, misspecification_verdict
    from softsbi.workflows.stats import N_NULL, PosteriorPredictive
    m = c["misspecification_after"]
    pool = PosteriorPredictive(c["run"], workers).ensure(int(d.get("n_null_start", N_NULL)))
    return misspecification_verdict(pool, candidate_effects(pool.run), m["alpha"], int(m["max_null"]))


def recheck_rows(results: Path, outs: Sequence[Path], workers: int | None = 1,
                 ids: Sequence[str] | None = None) -> list[str]:
    """Rule 3 with resolved refit checks: for every stored row (or ``ids``) whose run directory (looked up in
    ``outs``) has a refit whose check the first stage did not resolve (:func:`unresolved_refit_checks`), that
    check is decided again as ``misspecification_verdict`` now does: the refit's posterior-predictive rollouts
    re-simulated with their seeds, the null grown to its cap. Then rule 3 is applied again
    (:func:`decide_stored_again`). The old diagnosis is kept as ``diagnosis.before-recheck.json``
    and each rechecked refit keeps its first-stage test in ``misspecification_first_stage``; the old verdict
    fields are kept in ``rechecked``. Returns the ids whose verdict or name changed."""
    def redo(run_dir, d, todo, workers, budget):
        for c in todo:
            test = check_refit_again(d, c, workers)[0]
            c["misspecification_first_stage"], c["misspecification_after"] = c["misspecification_after"], test

    def report(d, todo):
        return ({"checks": [[c["effect"], c["misspecification_first_stage"]["p_text"],
                             c["misspecification_after"]["p_text"]] for c in todo]},
                {"refits": [c["effect"] for c in todo]})
    return decide_stored_again(results, outs, ids, "rechecked", unresolved_refit_checks,
                               "diagnosis.before-recheck.json", redo, report, workers)


def refits_to_widen(d: dict[str, Any]) -> list[dict[str, Any]]:
    """A stored diagnosis' refits that :func:`softsbi.workflows.diagnose.confirm_effect` would now refit with a wider
    prior: check rejected them, an added effect's parameter presses a prior bound (``at_bounds``, stored since
    the field exists) and none was widened. Whether the bound can move (not the switched-off side) is
    ``confirm_effect``'s call."""
    return [c for c in d.get("confirmed") or [] if (c.get("misspecification_after") or {}).get("misspecified")
            and c.get("at_bounds") and "widened" not in c]

def rewiden_rows(results: Path, outs: Sequence[Path], workers: int | None = 1,
                 ids: Sequence[str] | None = None) -> list[str]:
    """Widen pressed priors in stored rows: for every row (or ``ids``) whose run directory (looked up in ``outs``)
    has a refit :func:`refits_to_widen` lists, ``confirm_effect`` is called again with the diagnosis' settings
    (the first refit is on disk and resumes as it was; where it may, the widened refit is fitted into
    ``refit-<effect>-widened``), the refit's entry replaced, and rule 3 applied again (:func:`decide_stored_again`).
    The old diagnosis is kept as ``diagnosis.before-widening.json``; the old verdict fields are kept in
    ``rewidened``. Returns the ids whose verdict or name changed."""
    from softsbi.workflows.diagnose import EXPLAIN_ALPHA, confirm_effect
    from softsbi.workflows.runs import load_run
    from softsbi.workflows.stats import MAX_NULL, N_NULL

    def redo(run_dir, d, todo, workers, budget):
        view = load_run(run_dir)
        for c in todo:
            new_c = confirm_effect(view, c["effect"].split("+"), budget.get("confirm_budget"), workers,
                                   alpha=max(d.get("alpha", 0.05), EXPLAIN_ALPHA),
                                   n_null=int(d.get("n_null_start", N_NULL)), max_null=int(d.get("max_null", MAX_NULL)),
                                   nominal_bias=d.get("summary_bias"), nominal_energy=d.get("energy"))
            d["confirmed"][d["confirmed"].index(c)] = new_c

    def report(d, todo):
        widened = [c for c in d["confirmed"] if c.get("widened")]
        return ({"widened": [[c["effect"], c["widened"]["bounds"],
                              c["widened"]["first_misspecification_after"]["p_text"],
                              c["misspecification_after"]["p_text"], c.get("drop")] for c in widened]},
                {"refits": [c["effect"] for c in todo], "widened": [c["effect"] for c in widened]})
    return decide_stored_again(results, outs, ids, "rewidened", refits_to_widen, "diagnosis.before-widening.json",
                               redo, report, workers)


def refits_without_lead(d: dict[str, Any]) -> list[dict[str, Any]]:
    """A stored diagnosis' first refit (the screening's first effect) when the pair rule
    (:func:`softsbi.workflows.diagnose.second_effect`) would read its check's screening and it was stored without
    one: the screening said missing-effect, every refitted single named effect was checked and rejected, and that
    refit has no ``ranking_after``."""
    if d.get("screening_verdict", d.get("verdict")) != "missing-effect" or not d.get("significant"):
        return []
    singles = [c for c in d.get("confirmed") or [] if "+" not in c["effect"]]
    if not singles or any(not (c.get("misspecification_after") or {}).get("misspecified", False) for c in singles):
        return []
    return [c for c in singles if c["effect"] == d["significant"][0] and "ranking_after" not in c]

def resecond_rows(results: Path, outs: Sequence[Path], workers: int | None = 1,
                  ids: Sequence[str] | None = None) -> list[str]:
    """The pair's second effect from the first refit's check: for every stored row (or ``ids``) whose run
    directory (looked up in ``outs``) has a refit :func:`refits_without_lead` lists, check's test of that refit is
    computed again (its posterior-predictive rollouts re-simulated with their seeds, the null grown as it was) to
    keep its screening (``ranking_after``), then the rules are applied again (:func:`decide_stored_again`, which
    refits the pair :func:`~softsbi.workflows.diagnose.second_effect` now chooses). The old diagnosis is kept as
    ``diagnosis.before-resecond.json``; the old verdict fields, the pairs refitted before and the second effect
    chosen now are kept in ``reseconded``. Returns the ids whose verdict or name changed."""
    from softsbi.workflows.diagnose import ranking_digest
    old_pairs: list[str] = []

    def redo(run_dir, d, todo, workers, budget):
        old_pairs[:] = [c["effect"] for c in d["confirmed"] if "+" in c["effect"]]
        for c in todo:
            again, _, ranking = check_refit_again(d, c, workers)
            c["ranking_after"] = ranking_digest(ranking)
            c["ranking_after_check"] = again["p_text"]  # the same test, simulated again: should read as stored

    def report(d, todo):
        return ({"old_pairs": list(old_pairs), "lead": d.get("pair_lead"),
                 "checks": [[c["effect"], c["misspecification_after"]["p_text"], c.get("ranking_after_check")]
                            for c in todo],
                 "pairs": [[c["effect"], c.get("drop"), c["misspecification_after"]["p_text"]]
                           for c in d["confirmed"] if "+" in c["effect"]]},
                {"old_pairs": list(old_pairs), "lead": (d.get("pair_lead") or {}).get("effect")})
    return decide_stored_again(results, outs, ids, "reseconded", refits_without_lead, "diagnosis.before-resecond.json",
                               redo, report, workers)


def took_pair_path(d: dict[str, Any]) -> bool:
    """Whether a stored diagnosis ``d`` went down the pair path: the screening said missing-effect (with a significant
    effect), and the stored verdict is the third or names a pair (no single refit explained the misfit)."""
    if d.get("screening_verdict", d.get("verdict")) != "missing-effect" or not d.get("significant"):
        return False
    return d.get("verdict") == "misspecified-unexplained" or any("+" in c["effect"] for c in d.get("confirmed") or [])


def refits_with_another_base(d: dict[str, Any]) -> list[dict[str, Any]]:
    """A stored diagnosis' single refit that a pair now builds on (:func:`softsbi.workflows.diagnose.pair_base`: the
    refit that lowered the error most) where that is not the screening's first effect and the pair path was taken
    (:func:`took_pair_path`)."""
    from softsbi.workflows.diagnose import pair_base
    if not took_pair_path(d):
        return []
    base = pair_base(d)
    return [base] if base is not None and base["effect"] != d["significant"][0] else []


def rebase_rows(results: Path, outs: Sequence[Path], workers: int | None = 1,
                ids: Sequence[str] | None = None) -> list[str]:
    """The pair built on the refit that lowered the error most: every stored row (or ``ids``) that
    :func:`refits_with_another_base` selects is decided again (:func:`decide_stored_again`: ``redecide`` refits the
    pair :func:`~softsbi.workflows.diagnose.second_effect` now chooses, from the base refit's stored check screening).
    The old diagnosis is kept as ``diagnosis.before-rebase.json``; the old verdict fields, the pairs refitted before
    and the base are kept in ``rebased``. Returns the ids whose verdict or name changed."""
    old_pairs: list[str] = []

    def redo(run_dir, d, todo, workers, budget):
        old_pairs[:] = [c["effect"] for c in d["confirmed"] if "+" in c["effect"]]

    def report(d, todo):
        return ({"old_pairs": list(old_pairs), "base": [c["effect"] for c in todo], "lead": d.get("pair_lead"),
                 "pairs": [[c["effect"], c.get("drop"), c["misspecification_after"]["p_text"]]
                           for c in d["confirmed"] if "+" in c["effect"]]},
                {"old_pairs": list(old_pairs), "base": [c["effect"] for c in todo],
                 "lead": (d.get("pair_lead") or {}).get("effect")})
    return decide_stored_again(results, outs, ids, "rebased", refits_with_another_base, "diagnosis.before-rebase.json",
                               redo, report, workers)


def refits_with_another_lead(d: dict[str, Any]) -> list[dict[str, Any]]:
    """A stored diagnosis' base refit (:func:`softsbi.workflows.diagnose.pair_base`) whose pair's second effect under
    the current rule (:func:`softsbi.workflows.diagnose.next_effect`: the first named candidate of check of the refit
    that passes rule 2, twenty-second session) differs from the stored ``pair_lead`` (the first ranked, when it
    passed), where the pair path was taken (:func:`took_pair_path`)."""
    from softsbi.workflows.diagnose import MIN_EXPLAINED, next_effect, pair_base
    if not took_pair_path(d):
        return []
    base = pair_base(d)
    if base is None or not base.get("ranking_after"):
        return []
    lead = next_effect(base, d.get("min_explained", MIN_EXPLAINED), d.get("candidates"))
    return [base] if (lead or {}).get("effect") != (d.get("pair_lead") or {}).get("effect") else []


def relead_rows(results: Path, outs: Sequence[Path], workers: int | None = 1,
                ids: Sequence[str] | None = None) -> list[str]:
    """The pair's second effect under the current rule 2 (:func:`refits_with_another_lead`): each selected row is
    decided again (:func:`decide_stored_again`; ``redecide`` refits the pair the current rule chooses). The old
    diagnosis is kept as ``diagnosis.before-relead.json``; the old verdict, the old lead and the new one in
    ``reled``. Returns the ids whose verdict or name changed."""
    old_lead: list[Any] = []

    def redo(run_dir, d, todo, workers, budget):
        old_lead[:] = [(d.get("pair_lead") or {}).get("effect")]

    def report(d, todo):
        kept = {"old_lead": old_lead[0] if old_lead else None, "lead": (d.get("pair_lead") or {}).get("effect")}
        return ({**kept, "pairs": [[c["effect"], c.get("drop"), c["misspecification_after"]["p_text"]]
                                   for c in d["confirmed"] if "+" in c["effect"]]}, kept)
    return decide_stored_again(results, outs, ids, "reled", refits_with_another_lead, "diagnosis.before-relead.json",
                               redo, report, workers)


#: the subcommands that decide stored rows again, refit by refit: the mark they leave in a row, the refits they
#: select in its diagnosis, what ``--list`` prints of one, the function that does it, and what it does
REDO_STORED: dict[str, tuple[str, Callable, Callable, Callable, str]] = {
    "recheck": ("rechecked", unresolved_refit_checks,
                lambda c: [c["effect"], c["misspecification_after"]["p_text"]], recheck_rows,
                "decide again, with the null grown, the refit checks of stored rows that the first stage did not "
                "resolve"),
    "rewiden": ("rewidened", refits_to_widen,
                lambda c: [c["effect"], c["misspecification_after"]["p_text"],
                           [(e["param"], e["side"]) for e in c["at_bounds"]]], rewiden_rows,
                "refit with a wider prior the stored refits that check rejected while an added effect's parameter "
                "pressed a prior bound"),
    "resecond": ("reseconded", refits_without_lead,
                 lambda c: [c["effect"], c["misspecification_after"]["p_text"]], resecond_rows,
                 "keep the screening of check of the first refit where no single refit explains the misfit, and refit "
                 "the pair it calls for"),
    "rebase": ("rebased", refits_with_another_base,
               lambda c: [c["effect"], c.get("drop"), c["misspecification_after"]["p_text"]], rebase_rows,
               "build the pair on the refit that lowered the error most where that is not the screening's first effect, "
               "and refit the pair it calls for"),
    "relead": ("reled", refits_with_another_lead,
               lambda c: [c["effect"], c.get("drop"), c["misspecification_after"]["p_text"]], relead_rows,
               "take as the pair's second effect the first named candidate of check of the base refit that passes "
               "rule 2 (not the first ranked), and refit the pair it calls for"),
}


def row_alpha(r: dict[str, Any]) -> float:
    """The level a stored row was decided at (rows stored before the field: 0.01, the default of the time)."""
    return float((r.get("budget") or {}).get("alpha", 0.01))


def can_change_at(r: dict[str, Any], alpha: float) -> bool:
    """Could a stored row's verdict change if it were decided at ``alpha`` instead of its own level? Only
    when some decision of the diagnosis compared a p-value lying between the two levels: the
    misspecification test's, a candidate's max-T adjusted p-value (which candidates are refitted, which is
    named), or the remaining residual's (a second effect); or when its null stopped short of the cap with
    a p-value the eager extension (p <= 0.1 per test) would now grow. The pool, screening and refits are
    otherwise the same simulations (same seeds), so every other row's verdict is the same at either level."""
    if "verdict" not in r or r.get("misspecification_p") is None:
        return False
    lo, hi = sorted((row_alpha(r), alpha))

    def between(p: Any) -> bool:
        return p is not None and lo < p <= hi

    p = r["misspecification_p"]
    if between(p) or (r.get("n_null", 200) < (r.get("budget") or {}).get("max_null", 200) and p <= 0.2):
        return True
    if p > hi:
        return False
    return any(between(x[2]) for x in r.get("ranking") or []) or between((r.get("remaining") or {}).get("p_value"))


def awaits_level(r: dict[str, Any], alpha: float, ids: Sequence[str] | None = None) -> bool:
    """Whether a stored row (among ``ids``, when given) has a verdict not yet decided at ``alpha``."""
    return "verdict" in r and row_alpha(r) != alpha and (not ids or r["id"] in ids)


def rediagnose_rows(results: Path, outs: Sequence[Path], alpha: float, workers: int | None = 1,
                    ids: Sequence[str] | None = None) -> list[str]:
    """Diagnose again, at level ``alpha``, the stored rows whose verdict could change at it
    (:func:`can_change_at`), from their stored nominal runs (looked up in ``outs``): same candidates, null
    sizes, refit budget and seeds; refits already on disk are reused (``run_fit`` resumes), new ones are
    fitted. The old ``diagnosis.json`` is kept as ``diagnosis.alpha<old>.json``; the row's verdict fields are
    replaced, ``budget.alpha`` set and the old verdict kept in ``rediagnosed``. Rows that cannot change get
    ``budget.alpha`` too (their verdict holds at both levels). ``results`` is rewritten after each rediagnosed
    row and at the end, so an interrupted call loses no diagnosis and the same call continues (marking the
    rows that cannot change costs nothing to repeat). Returns the ids whose verdict or name changed."""
    rows = load_rows(results)
    changed = []
    first = {i: k for k, i in enumerate(ids or [])}  # the order asked for, then the file's
    for r in sorted(rows, key=lambda x: first.get(x["id"], len(first))):
        if not awaits_level(r, alpha, ids):
            continue
        if not can_change_at(r, alpha):
            if r.get("test") == TEST and (r.get("budget") or {}).get("confirm"):
                r["budget"]["alpha"] = alpha  # the same verdict at either level
            continue
        run_dir = find_run_dir(outs, r["id"])
        if run_dir is None:
            continue
        b = r["budget"]
        old = run_dir / f"diagnosis.alpha{row_alpha(r):g}.json"
        if not old.exists():
            old.write_text((run_dir / "diagnosis.json").read_text())
        t0 = time.perf_counter()
        d = diagnose_run(run_dir, effects=row_candidates(r), n_null=b["n_null"],
                         max_null=b["max_null"], workers=workers, confirm=b["confirm"],
                         confirm_budget=b.get("confirm_budget"), alpha=alpha)
        new = row_fields({k: r[k] for k in CASE_KEYS}, d)
        if (new["verdict"], new["named"]) != (r["verdict"], r["named"]):
            changed.append(r["id"])
        print(json.dumps({"id": r["id"], "truth": r["truth_label"], "before": [r["verdict"], r["named"]],
                          "after": [new["verdict"], new["named"]], "p": new["misspecification_p_text"],
                          "s": round(time.perf_counter() - t0)}), flush=True)
        r.update(new, rediagnosed={"alpha": row_alpha(r), "verdict": r["verdict"], "named": r["named"]},
                 simulations=d["simulations"])
        r["budget"]["alpha"] = alpha
        save_rows(results, rows)
    save_rows(results, rows)
    return changed


def refit_case(run_dir: Path, effect: str, rounds: int, sims: int, proposal: str = "truncated", n_null: int = 30,
               max_null: int = 200, alpha: float = 0.01) -> dict[str, Any]:
    """Refit a stored case's nominal run (``run_dir``) with ``effect`` switched on at another budget and
    proposal (into ``run_dir/trefit-<effect>-<rounds>x<sims>``), then check's test of the refit: the
    posterior-predictive Chamfer before/after and the refit's misspecification p-value."""
    from dataclasses import replace

    from softsbi.workflows.diagnose import recording_from_run
    from softsbi.workflows.runs import load_run
    from softsbi.workflows.screening import candidate_effects, misspecification_verdict
    from softsbi.workflows.stats import PosteriorPredictive
    t0 = time.perf_counter()
    run = load_run(run_dir)
    cfg = replace(FitConfig.from_run_config(run.config), effects=list(run.effects) + [effect], rounds=rounds,
                  sims_per_round=sims, workers=1, proposal=proposal)
    out = run.path / f"trefit-{effect}-{rounds}x{sims}"
    res = run_fit(out, recording_from_run(run), cfg, make_plots=False)
    pool = PosteriorPredictive(out, 1).ensure(n_null)
    mis = misspecification_verdict(pool, candidate_effects(pool.run), alpha, max_null)[0]
    b, a = run.report["chamfer_posterior_m"], res.report["chamfer_posterior_m"]
    return {"case": run_dir.name, "effect": effect, "budget": f"{rounds}x{sims} {proposal}", "before_cm": b * 100,
            "after_cm": a * 100, "drop": 1 - a / b, "check_after": mis["p_text"], "s": time.perf_counter() - t0}


def _mean_chamfer_at(run: Any, theta: dict[str, float], effects: list[str], n: int) -> float:
    """Mean Chamfer (m, over the run's metric frames) between the measurement and ``n`` rollouts at
    ``theta`` with ``effects``, seeds ``5000 + k``, through the run's own job
    (:func:`~softsbi.workflows.stats.rollout_chamfers`); NaN when none succeeds."""
    from softsbi.workflows.stats import rollout_chamfers
    vals = rollout_chamfers(run, [(theta, 5000 + k, effects) for k in range(n)], 1)
    return float(np.mean(vals)) if len(vals) else float("nan")


def truth_floor(run_dir: Path, case: dict[str, Any], n: int = 5) -> float:
    """The oracle floor (m) of a case's posterior-predictive Chamfer: the mean Chamfer between the
    measurement and ``n`` rollouts at the case's truth with its hidden effects switched on (seeds
    ``5000 + k``), through the nominal run's own job and metric. A model that knew everything would
    score this; the point sampling of both clouds keeps it above zero."""
    from softsbi.workflows.runs import load_run
    run = load_run(run_dir)
    return _mean_chamfer_at(run, dict(case["truth"]), list(run.effects) + hidden_effects(case), n)


def truth_energy(run_dir: Path, case: dict[str, Any], n: int = 30) -> dict[str, Any] | None:
    """The energy score (:func:`softsbi.workflows.stats.energy_score`) of the oracle's predictive distribution:
    ``n`` rollouts at the case's truth with its hidden effects switched on (seeds ``5000 + k``, as
    :func:`truth_floor`), through the nominal run's own job and metric. Only the simulation seeds vary, so this is
    the distribution the measurement was drawn from; a proper score gives it the lowest expected score of all
    predictive distributions, which the benchmark checks against the nominal fits and the refits."""
    from types import SimpleNamespace

    from softsbi.workflows.jobs import run_jobs
    from softsbi.workflows.runs import load_run
    from softsbi.workflows.stats import energy_score
    run = load_run(run_dir)
    items = [(dict(case["truth"]), 5000 + k, list(run.effects) + hidden_effects(case)) for k in range(n)]
    res = run_jobs(run.sim_context(keep_rollout=True), items, 1)
    rollouts = [dict(r, sample=k) for k, r in enumerate(res) if r and r.get("vertices") is not None]
    return energy_score(SimpleNamespace(run=run, rollouts=rollouts, energy_scores={}), n)


def add_truth_energies(results: Path, outs: Sequence[Path]) -> int:
    """Add ``energy_m = {"nominal", "refit", "truth"}`` (m) to every stored correctly named row whose diagnosis
    kept energy scores (``diagnosis.json``: the nominal's ``energy`` and the named refit's ``energy_after_m``),
    with the truth's from :func:`truth_energy`; rewrites ``results``, returns the number of rows updated."""
    rows = load_rows(results)
    k = 0
    for r in rows:
        run_dir = find_run_dir(outs, r["id"])
        if "energy_m" in r or not (r.get("correct") and r.get("named")) or run_dir is None \
                or not (run_dir / "diagnosis.json").exists():
            continue
        d = json.loads((run_dir / "diagnosis.json").read_text())
        c = next((c for c in d.get("confirmed") or [] if c["effect"] == r["named"]), None)
        if not d.get("energy") or c is None or c.get("energy_after_m") is None:
            continue
        t = truth_energy(run_dir, r)
        r["energy_m"] = {"nominal": d["energy"]["energy_m"], "refit": c["energy_after_m"],
                         "refit_se": c.get("energy_after_se_m"), "truth": t and t["energy_m"],
                         "truth_se": t and t["energy_se_m"]}
        k += 1
        save_rows(results, rows)
    return k


def add_pm_drops(results: Path, outs: Sequence[Path]) -> int:
    """Add the posterior-mean rollout's Chamfer drop (:func:`~softsbi.workflows.stats.posterior_mean_chamfer`, as
    ``diagnose`` computes it now: the nominal fit's and each refit's posterior mean, ``PM_ROLLOUTS`` seeds) to the
    refits of stored correctly named rows made before diagnose computed it (``refits[i][7]``), where the nominal
    run and the named effect's refit are on disk; rewrites ``results``, returns the number of rows updated."""
    from softsbi.workflows.runs import load_run
    from softsbi.workflows.stats import posterior_mean_chamfer
    rows = load_rows(results)
    k = 0
    for r in rows:
        run_dir = find_run_dir(outs, r["id"], marker="report.json")
        if not (r.get("correct") and r.get("named")) or run_dir is None:
            continue
        todo = [x for x in r.get("refits") or [] if (len(x) < 8 or x[7] is None)
                and (run_dir / f"refit-{x[0]}" / "report.json").exists()]
        if not todo:
            continue
        before = posterior_mean_chamfer(load_run(run_dir), workers=1)
        for x in todo:
            after = posterior_mean_chamfer(load_run(run_dir / f"refit-{x[0]}"), workers=1)
            x.extend([None] * (8 - len(x)))
            x[7] = (1 - after["chamfer_m"] / before["chamfer_m"]) if before and after else None
        k += 1
        save_rows(results, rows)
    return k


def effect_size(run_dir: Path, case: dict[str, Any], n: int = 5) -> dict[str, float]:
    """How visible a case's hidden effect(s) are in its measurement, in metres of the run's own metric:
    the mean Chamfer to the measurement of ``n`` rollouts at the case's truth *without* the hidden
    effects (what the nominal model at the right parameters scores) minus that of ``n`` rollouts *with*
    them (:func:`truth_floor`'s oracle), seeds ``5000 + k`` for both. The prior-relative ``magnitude``
    says how far the effect's parameter is from off; this says how much of it reaches the sensor in this
    scenario (a grip's compliance hardly shows in a rope wound on a spool). Returns ``size_m``,
    ``without_m``, ``with_m`` and ``nominal_m``, the nominal fit's posterior-predictive Chamfer
    (``report.json``): ``nominal_m - with_m`` is what the fit leaves, misspecification and posterior width
    together."""
    from softsbi.workflows.runs import load_run
    run = load_run(run_dir)
    hidden = hidden_effects(case)
    own = {q for e in hidden for q in registry().effect(e)().param_space().names}
    without = _mean_chamfer_at(run, {k: v for k, v in case["truth"].items() if k not in own}, list(run.effects), n)
    with_ = _mean_chamfer_at(run, dict(case["truth"]), list(run.effects) + hidden, n)  # truth_floor's oracle
    return {"size_m": without - with_, "without_m": without, "with_m": with_,
            "nominal_m": float(json.loads((run_dir / "report.json").read_text())["chamfer_posterior_m"])}


def add_effect_sizes(results: Path, outs: Sequence[Path]) -> int:
    """Add ``effect_size`` (:func:`effect_size`) to every stored hidden-effect row whose run directory is in
    one of ``outs`` and that lacks it (rewrites ``results`` after each row, so an interrupted call loses
    nothing); returns the number of rows updated."""
    rows = load_rows(results)
    k = 0
    for r in rows:
        if r.get("magnitude") is None or "verdict" not in r or "nominal_m" in r.get("effect_size", {}):
            continue
        d = find_run_dir(outs, r["id"], "run.zarr")
        if d is None:
            continue
        if "effect_size" in r:  # stored before nominal_m: add it, nothing to simulate
            r["effect_size"]["nominal_m"] = float(json.loads((d / "report.json").read_text())["chamfer_posterior_m"])
            k += 1
            continue
        r["effect_size"] = effect_size(d, r)
        k += 1
        save_rows(results, rows)
    if k:
        save_rows(results, rows)
    return k


def add_floors(results: Path, out: Path) -> int:
    """Add ``floor_m`` (:func:`truth_floor`) to every stored hidden-effect row with a refit that lacks it
    (rewrites ``results``; controls and other-engine data have no truth in the fitted model); returns the
    number of rows updated."""
    rows = load_rows(results)
    k = 0
    for r in rows:
        if r.get("refits") and "floor_m" not in r and r.get("magnitude") is not None and (out / r["id"]).exists():
            r["floor_m"] = truth_floor(out / r["id"], r)
            r["chamfer_nominal_m"] = json.loads((out / r["id"] / "report.json").read_text())["chamfer_posterior_m"]
            k += 1
    save_rows(results, rows)
    return k


def done_ids(results: Path) -> set[str]:
    """Case ids already stored in ``results`` (one JSON object per line)."""
    if not results.exists():
        return set()
    return {r["id"] for r in load_rows(results)}


def suite_candidates(suite: str) -> list[str]:
    """The candidate effects a suite's cases are screened with by default: its ``candidates``, else the effects it
    hides (the ``mujoco`` and ``cross-engine`` suites: the four built-in physics effects only)."""
    return list(SUITES[suite].get("candidates", SUITES[suite]["effects"]))


def row_candidates(r: dict[str, Any]) -> list[str] | None:
    """The candidate effects a stored row's diagnosis screened: its ``candidates`` field, else (rows stored before
    the field) its suite's default (:func:`suite_candidates`); None for a row of an unknown suite."""
    if r.get("candidates") is not None:
        return list(r["candidates"])
    return suite_candidates(r["suite"]) if r.get("suite") in SUITES else None


def run_cases(suite: str, indices: "range | list[int]", results: Path, out: Path, seed: int = 0, rounds: int = 2,
              sims: int = 60, n_null: int = 30, max_null: int = 200, confirm: int = 0,
              workers: int | None = None, only: set[str] | None = None,
              confirm_budget: dict[str, int] | None = None,
              proposal: str = "corrected", alpha: float = ALPHA,
              min_magnitude: float | None = None, all_candidates: bool = False) -> list[dict[str, Any]]:
    """Run the cases ``indices`` not yet in ``results``; append one line per case as it finishes.

    ``only``: run just the cases whose ``truth_label`` is in this set (e.g. ``{"control"}``); the
    other indices are skipped, not renumbered, so every case keeps its definition. ``min_magnitude``: run just
    the hidden-effect cases whose magnitude is at least this (a choice on the covariate of the power curves, not
    on their outcome: a logistic curve fitted to them stays unbiased; spends the machine where a criterion above
    a detection threshold has few cases). With ``confirm``
    > 0 (refits) a case is stored under its own id with the suffix ``-refit<confirm>``: the screening-only
    and the refitted diagnosis of a case are two rows, summarised separately (:func:`select_rows`); with a
    ``confirm_budget`` the suffix also names it (``-refit2-3x100``); a nominal fit with truncated
    proposals adds ``-truncated``. ``all_candidates``: screen all named candidates (:data:`NAMED_CANDIDATES`, as
    ``softsbi diagnose`` screens every installed effect) where the suite screens fewer by default; the id then ends
    in ``-c<number of candidates>``."""
    screened = NAMED_CANDIDATES if all_candidates else suite_candidates(suite)
    have = done_ids(results)
    results.parent.mkdir(parents=True, exist_ok=True)
    new = []
    for i in indices:
        case = make_case(suite, seed, i)
        if only and case["truth_label"] not in only:
            continue
        if min_magnitude is not None and (case["magnitude"] is None or case["magnitude"] < min_magnitude):
            continue
        if confirm:
            case["id"] += f"-refit{confirm}"
            if confirm_budget:
                case["id"] += f"-{confirm_budget['rounds']}x{confirm_budget['sims_per_round']}"
        case["id"] += (f"-{TEST}" + ("" if proposal == "corrected" else f"-{proposal}")
                       + ("" if N_SUMMARIES == 13 else f"-s{N_SUMMARIES}")
                       + ("" if screened == suite_candidates(suite) else f"-c{len(screened)}"))
        if case["id"] in have:
            continue
        try:
            row = run_case(case, out, rounds, sims, n_null, max_null, confirm, workers, confirm_budget, proposal, alpha,
                           screened)
        except Exception as exc:  # noqa: BLE001 - a failed case is recorded, not retried silently
            row = {**case, "error": f"{type(exc).__name__}: {exc}"}
        with results.open("a") as f:
            f.write(json.dumps(row) + "\n")
        new.append(row)
        print(json.dumps({k: row.get(k) for k in ("id", "truth_label", "scenario", "magnitude", "verdict", "named",
                                                   "correct", "misspecification_p_text", "wall_s", "error")}),
              flush=True)
    return new


def select_rows(rows: list[dict[str, Any]], confirm: int | None = 0,
                confirm_budget: str | None = None, test: str | None = None,
                proposal: str | None = "corrected", alpha: float | None = None,
                n_summaries: int | None = None, n_candidates: int | None = None) -> list[dict[str, Any]]:
    """The stored rows diagnosed with ``confirm`` refits (rows stored before the field existed had none;
    None: any number), with ``confirm_budget`` (``"3x100"``) only those whose refits had that budget, and
    with ``test`` (``"joint"`` or ``"omnibus"``, rows without the field) only those decided with that
    misspecification test; with ``proposal`` only rows whose nominal fit drew its rounds so (rows without the
    field: ``"corrected"``; None: any); with ``alpha`` only rows decided at that level (:func:`row_alpha`); with
    ``n_summaries`` only rows whose tests used that many summaries per frame (rows without the field: 13); with
    ``n_candidates`` only rows whose diagnosis screened that many candidate effects (:func:`row_candidates`).

    A case diagnosed under several protocols that all pass the filters (e.g. refits at the nominal budget and
    at 3 x 100: two ids, one measurement) counts once: its row stored last (:func:`one_row_per_case`)."""
    def budget(r):
        cb = (r.get("budget") or {}).get("confirm_budget")
        return f"{cb['rounds']}x{cb['sims_per_round']}" if cb else None
    return one_row_per_case([r for r in rows if (confirm is None or int((r.get("budget") or {}).get("confirm", 0)) == confirm)
                             and (confirm_budget is None or budget(r) == confirm_budget)
                             and (test is None or r.get("test", "omnibus") == test)
                             and (proposal is None or r.get("proposal", "corrected") == proposal)
                             and (alpha is None or row_alpha(r) == alpha)
                             and (n_summaries is None or r.get("n_summaries", 13) == n_summaries)
                             and (n_candidates is None or len(row_candidates(r) or []) == n_candidates)])


def one_row_per_case(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``rows`` with one row per case (suite, seed and index: one measurement): of several, the one stored last
    (the newest protocol), in its place; rows without an ``index`` (tests' hand-made rows) are all kept."""
    last = {case_key(r): i for i, r in enumerate(rows)}
    return [r for i, r in enumerate(rows) if last[case_key(r)] == i]


def case_key(r: dict[str, Any]) -> tuple[Any, ...]:
    """The measurement a row diagnosed: (suite, seed, index) from :func:`make_case`'s id
    (``f"{suite}-s{seed}-{index}"`` and the protocol's suffixes); ``("row", id)`` for a row without an index."""
    if r.get("index") is None or not r.get("suite") or not r["id"].startswith(f"{r['suite']}-s"):
        return ("row", r["id"])
    return (r["suite"], r["id"][len(r["suite"]) + 2:].split("-")[0], r["index"])


def summarise(rows: list[dict[str, Any]], n_bins: int = 3) -> dict[str, Any]:
    """False-alarm rate (binomial SE, Clopper-Pearson 95%), confusion matrix, detection vs magnitude,
    and with refits the median error drop of the named effect's refit in correctly named cases."""
    rows = [r for r in rows if "verdict" in r]
    ctrl = [r for r in rows if r["truth_label"] == "control"]
    fa = sum(r["verdict"] != "nothing-missing" for r in ctrl)
    n = len(ctrl)
    out: dict[str, Any] = {"cases": len(rows), "controls": n, "false_alarms": fa}
    if n:
        p = fa / n
        ci = stats.binomtest(fa, n).proportion_ci(0.95, method="exact")
        out.update(false_alarm_rate=p, false_alarm_se=float(np.sqrt(p * (1 - p) / n)),
                   false_alarm_ci95=[float(ci.low), float(ci.high)])
    conf: dict[str, Counter] = defaultdict(Counter)
    for r in rows:
        conf[r["truth_label"]][r["called"]] += 1
    out["confusion"] = {k: dict(v) for k, v in sorted(conf.items())}
    edges = np.linspace(0.1, 1.0, n_bins + 1)
    power: dict[str, list[dict[str, Any]]] = {}
    for eff in sorted({r["truth_label"] for r in rows if r.get("magnitude") is not None}):
        rs = [r for r in rows if r["truth_label"] == eff]
        bins = []
        for lo, hi in zip(edges[:-1], edges[1:]):
            b = [r for r in rs if lo <= r["magnitude"] <= hi]
            bins.append({"magnitude": [float(lo), float(hi)], "n": len(b),
                         "detected": sum(r["verdict"] != "nothing-missing" for r in b),
                         "named_correctly": sum(bool(r["correct"]) for r in b)})
        power[eff] = bins
    out["power"] = power
    sized = [r for r in rows if r.get("effect_size")]
    if sized:
        # power over the effect's size in the data (cm): bins and a threshold per effect
        sedges = [-np.inf, 0.3, 1.0, 3.0, np.inf]  # a sensor effect can lower the Chamfer (size < 0)
        out["power_size"] = {eff: [{"size_cm": [lo, hi], "n": len(b), "detected": sum(r["verdict"] != "nothing-missing"
                                                                                   for r in b),
                                    "named_correctly": sum(bool(r["correct"]) for r in b)}
                                   for lo, hi in zip(sedges[:-1], sedges[1:])
                                   for b in [[r for r in sized if r["truth_label"] == eff
                                              and lo <= r["effect_size"]["size_m"] * 100 < hi]]]
                             for eff in sorted({r["truth_label"] for r in sized})}
        out["thresholds_size"] = {eff: detection_threshold([r for r in sized if r["truth_label"] == eff], by="size")
                                  for eff in out["power_size"] if "+" not in eff}
    single = {eff: [r for r in rows if r["truth_label"] == eff] for eff in power if "+" not in eff}
    out["thresholds"] = {eff: detection_threshold(rs) for eff, rs in single.items()}
    out["thresholds_detected"] = {eff: detection_threshold(rs, outcome="detected") for eff, rs in single.items()}
    # the same per task: an effect's size in the data at one magnitude depends on the motion (a soft grasp lags a
    # lifted cloth, while a cloth hanging in a breeze barely shows it), so one threshold per effect mixes tasks
    out["thresholds_detected_by_scenario"] = {
        eff: {sc: detection_threshold(b, outcome="detected")
              for sc in sorted({r["scenario"] for r in rs if r.get("scenario")})
              for b in [[r for r in rs if r.get("scenario") == sc]]}
        for eff, rs in single.items()}
    other = [r for r in rows if r["truth_label"] == "other-engine"]
    if other:
        out["other_engine"] = {"n": len(other), "misspecified-unexplained": sum(bool(r["correct"]) for r in other),
                               "screening": dict(Counter(r.get("screening_verdict", r["verdict"]) for r in other))}
    # a named effect with indistinguishable alternatives (diagnose: the data cannot tell them apart)
    alt = [r for r in rows if r.get("alternatives")]
    if alt:
        out["alternatives"] = {"n": len(alt), "named_correctly": sum(bool(r["correct"]) for r in alt),
                               "hidden_among_alternatives": sum(not r["correct"] and r["truth_label"] in r["alternatives"]
                                                                for r in alt)}
    drops = [d for r in rows if r["correct"] and r.get("named") for e, d, *_ in r.get("refits") or []
             if e == r["named"] and d is not None]
    if drops:
        out["refit_drop"] = {"n": len(drops), "median": float(np.median(drops))}
    # the drop of the reducible error: (before - after) / (before - oracle floor), floor from add_floors, or the
    # same oracle's score from add_effect_sizes (effect_size's with_m: truth_floor's computation, the same seeds)
    def floor_and_nominal(r):
        es = r.get("effect_size") or {}
        if r.get("floor_m"):
            return r["floor_m"], r["chamfer_nominal_m"]
        return (es["with_m"], es["nominal_m"]) if es.get("with_m") and es.get("nominal_m") else (None, None)
    # the named effect's refit of each correctly named case, with its Chamfer drop
    named_refits = [(r, x) for r in rows if r["correct"] and r.get("named")
                    for x in r.get("refits") or [] if x[0] == r["named"] and x[1] is not None]
    named_drops = [(r, x[1]) for r, x in named_refits]
    floors = [floor_and_nominal(r) for r, _ in named_drops]
    reducible = [(r, d * nom / (nom - fl)) for (r, d), (fl, nom) in zip(named_drops, floors)
                 if fl is not None and nom > fl]
    excess = [x for _, x in reducible]
    if excess:
        out["refit_drop_of_reducible"] = {"n": len(excess), "median": float(np.median(excess)),
                                          # the oracle scores no better than the nominal fit: a sensor effect that
                                          # adds spread (point noise), whose Chamfer cannot fall
                                          "floor_at_or_above_nominal": sum(fl is not None and nom <= fl
                                                                           for fl, nom in floors),
                                          "without_floor": sum(fl is None for fl, _ in floors)}
    # the fraction of the nominal's summary bias that the named refit removes (refits[i][4], diagnose's
    # bias_fall): the misfit check's test measures, in the 14 summaries per frame. A sensor effect that adds spread
    # (point noise) cannot lower a Chamfer (its optimum is the noise-free cloud), but it can remove this bias
    falls = [(r, x[4]) for r, x in named_refits if len(x) > 4 and x[4] is not None]
    if falls:
        out["refit_bias_fall"] = {"n": len(falls), "median": float(np.median([f for _, f in falls])),
                                  "without": len(named_drops) - len(falls)}
    # per hidden effect (one or a pair): the Chamfer drop, the reducible error's drop and the summary bias's fall,
    # so that a pooled median is read with the mix of effects behind it
    by_effect: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for key, pairs in (("chamfer", named_drops), ("reducible", reducible), ("bias", falls)):
        for r, x in pairs:
            by_effect[r["truth_label"]][key].append(x)
    if by_effect:
        out["refit_drop_by_effect"] = {
            k: {m: {"n": len(v[m]), "median": float(np.median(v[m])) if v[m] else None}
                for m in ("chamfer", "reducible", "bias")} for k, v in sorted(by_effect.items())}
    # the same cases' drop of the energy score (stats.energy_score, refits[i][6]) and of the posterior-mean
    # rollout's Chamfer (the fitted point estimate, refits[i][7]), where the refit stored it; each with the Chamfer
    # drop of exactly those cases, so the two medians compare like with like
    for key, idx in (("refit_drop_energy", 6), ("refit_drop_pm", 7)):
        both = [(x[1], x[idx]) for r in rows if r["correct"] and r.get("named") for x in r.get("refits") or []
                if x[0] == r["named"] and x[1] is not None and len(x) > idx and x[idx] is not None]
        if both:
            out[key] = {"n": len(both), "median": float(np.median([e for _, e in both])),
                        "median_chamfer_same_cases": float(np.median([c for c, _ in both]))}
    # the proper score in practice: the truth's own predictive distribution (add_truth_energies) against the
    # nominal fit's and the refit's, and the refit's share of the energy score above the truth's
    es = [r["energy_m"] for r in rows if r.get("energy_m") and r["energy_m"].get("truth") is not None]
    if es:
        red = [(e["nominal"] - e["refit"]) / (e["nominal"] - e["truth"]) for e in es if e["nominal"] > e["truth"]]
        out["energy_truth"] = {"n": len(es), "truth_below_nominal": sum(e["truth"] < e["nominal"] for e in es),
                               "truth_below_refit": sum(e["truth"] < e["refit"] for e in es),
                               "median_drop_of_reducible": float(np.median(red)) if red else None}
    return out


def detection_threshold(rows: list[dict[str, Any]], level: float = 0.9, by: str = "magnitude",
                        outcome: str = "named") -> dict[str, Any]:
    """The measured detection threshold of one hidden effect: a logistic power curve
    ``P(outcome | x) = 1 / (1 + exp(-(a + b x)))`` fitted by maximum likelihood to the cases
    (scipy), and the ``x`` where it reaches ``level`` (``m_level``; None when it does not within the
    range, or when the fit is degenerate: every case has the outcome or none; the range's lower end when the
    curve stays above ``level`` over the whole range). Then the criterion as
    measured: of the cases with ``x >= m_level``, how many were named correctly (``above_named``),
    detected (``above_detected``: any verdict but nothing-missing) and, not named, listed as an
    indistinguishable alternative of the named effect (``above_alternative``; the row's ``alternatives``).

    ``outcome="named"``: the curve of naming the hidden effect (the threshold above which it is named
    with probability ``level``). ``outcome="detected"``: the curve of detecting a misfit at all; the
    criterion then asks how often the effect is named where the test already sees it, which does not
    follow from the curve's own definition.

    ``by="magnitude"``: ``x`` is the prior-relative magnitude, range (0, 1]. ``by="size"``: ``x`` is
    ``log10`` of the effect's size in the data in cm (:func:`effect_size`; rows without it or with a
    size <= 0.01 cm are left out), range up to 10 cm; ``m_level`` is then reported in cm."""
    from scipy.optimize import minimize
    if by == "size":
        rows = [r for r in rows if (r.get("effect_size") or {}).get("size_m", 0) > 1e-4]
        m = np.log10(np.array([r["effect_size"]["size_m"] * 100 for r in rows], float))
        lo, hi = -2.0, 1.0
    else:
        m = np.array([r["magnitude"] for r in rows], float)
        lo, hi = 0.0, 1.0
    named = np.array([bool(r["correct"]) for r in rows], float)
    detected = np.array([r.get("verdict", "nothing-missing") != "nothing-missing" for r in rows], float)
    # not named, but listed as indistinguishable from the named effect (diagnose: the data cannot tell them apart)
    alternative = np.array([not r["correct"] and r.get("truth_label") in (r.get("alternatives") or [])
                            for r in rows], float)
    if outcome not in ("named", "detected"):
        raise ValueError(f"outcome {outcome!r}: use 'named' or 'detected'")
    y = named if outcome == "named" else detected
    out: dict[str, Any] = {"n": len(rows), "named_correctly": int(named.sum()), "detected": int(detected.sum()),
                           "level": level, "m_level": None, "by": by, "outcome": outcome}
    if len(rows) < 4 or y.sum() == 0:
        return out

    def nll(w):
        z = w[0] + w[1] * m
        return float(np.sum(np.logaddexp(0, z) - y * z)) + 1e-3 * float(w @ w)  # tiny ridge: separable data

    w = minimize(nll, np.zeros(2), method="BFGS").x
    out["curve"] = [float(w[0]), float(w[1])]
    logit = np.log(level / (1 - level))
    m_lv = None
    if w[1] > 0:
        m_lv = max((logit - w[0]) / w[1], lo)  # a curve above the level over the whole range: every case
    elif w[0] + w[1] * hi >= logit:
        m_lv = lo  # flat or falling, yet above the level up to the range's end: every case
    if m_lv is not None and m_lv <= hi:
        above = m >= m_lv
        out.update(m_level=float(10 ** m_lv if by == "size" else m_lv), above=int(above.sum()),
                   above_named=int(named[above].sum()), above_detected=int(detected[above].sum()),
                   above_alternative=int(alternative[above].sum()))
    return out


def markdown(summary: dict[str, Any], rows: list[dict[str, Any]]) -> str:
    """The summary as Markdown tables (BENCHMARKS.md): false alarms, confusion matrix, power, cases."""
    out = []
    if summary.get("controls"):
        lo, hi = summary["false_alarm_ci95"]
        out.append(f"False alarms: {summary['false_alarms']} of {summary['controls']} controls = "
                   f"{summary['false_alarm_rate']:.2f} ± {summary['false_alarm_se']:.2f} (binomial SE; "
                   f"Clopper-Pearson 95% interval {lo:.2f}-{hi:.2f}).\n")
    cols = sorted({c for v in summary["confusion"].values() for c in v})
    out.append("| truth \\ called | " + " | ".join(cols) + " |")
    out.append("|---" * (len(cols) + 1) + "|")
    for truth, v in summary["confusion"].items():
        out.append(f"| {truth} | " + " | ".join(str(v.get(c, 0)) for c in cols) + " |")
    out.append("\n| hidden effect | " + " | ".join(f"magnitude {b['magnitude'][0]:.1f}-{b['magnitude'][1]:.1f}"
                                                for b in next(iter(summary["power"].values()), [])) + " |")
    out.append("|---" * (1 + len(next(iter(summary["power"].values()), []))) + "|")
    for eff, bins in summary["power"].items():
        out.append(f"| {eff} | " + " | ".join(f"{b['named_correctly']}/{b['n']} named ({b['detected']} detected)"
                                              if b["n"] else "-" for b in bins) + " |")
    th = {k: v for k, v in (summary.get("thresholds") or {}).items() if v["n"]}
    if th:
        out.append("\n| hidden effect | cases | named correctly | magnitude where the fitted power curve reaches 90% "
                   "| named correctly above it |")
        out.append("|---|---|---|---|---|")
        for eff, t in th.items():
            lv = (f"{t['m_level']:.2f}", f"{t['above_named']} of {t['above']}") if t.get("m_level") is not None \
                else ("not reached in (0, 1]", "-")
            out.append(f"| {eff} | {t['n']} | {t['named_correctly']} | {lv[0]} | {lv[1]} |")
    td = {k: v for k, v in (summary.get("thresholds_detected") or {}).items() if v["n"]}
    if td:
        out.append("\nThe criterion above the detection threshold (the magnitude where the fitted curve of detecting a "
                   "misfit at all reaches 90%):\n")
        out.append("| hidden effect | cases | detected | magnitude where detection reaches 90% | detected above it "
                   "| named correctly above it |")
        out.append("|---|---|---|---|---|---|")
        for eff, t in td.items():
            alt = (f" (+{t['above_alternative']} listed as an indistinguishable alternative)"
                   if t.get("above_alternative") else "")
            lv = (f"{t['m_level']:.2f}", f"{t['above_detected']} of {t['above']}",
                  f"{t['above_named']} of {t['above']}{alt}") if t.get("m_level") is not None \
                else ("not reached in (0, 1]", "-", "-")
            out.append(f"| {eff} | {t['n']} | {t['detected']} | {lv[0]} | {lv[1]} | {lv[2]} |")
    tds = summary.get("thresholds_detected_by_scenario") or {}
    if tds:
        out.append("\nThe same criterion per task (each effect's detection curve fitted to the cases of one scenario; "
                   "\"-\": detection never reaches 90% there, or too few cases to fit a curve):\n")
        scs = sorted({sc for v in tds.values() for sc in v})
        out.append("| hidden effect | " + " | ".join(f"{sc}: threshold, named above it" for sc in scs) + " |")
        out.append("|---" * (1 + len(scs)) + "|")
        for eff, per in tds.items():
            cells = []
            for sc in scs:
                t = per.get(sc) or {}
                cells.append(f"{t['m_level']:.2f}, {t['above_named']} of {t['above']}" if t.get("m_level") is not None
                             else f"- (n = {t.get('n', 0)})")
            out.append(f"| {eff} | " + " | ".join(cells) + " |")
        cells = [t for per in tds.values() for t in per.values() if t.get("m_level") is not None and t["above"]]
        out.append(f"\nOver the effect-task cells with a threshold: {sum(t['above_named'] for t in cells)} of "
                   f"{sum(t['above'] for t in cells)} cases above their cell's threshold named correctly.")
    if summary.get("power_size"):
        out.append("\nBy the effect's size in the data (Chamfer to the measurement at the truth without the effect "
                   "minus with it):\n")
        out.append("| hidden effect | < 0.3 cm | 0.3-1 cm | 1-3 cm | >= 3 cm | size where the power curve reaches 90% "
                   "| named correctly above it |")
        out.append("|---|---|---|---|---|---|---|")
        for eff, bins in summary["power_size"].items():
            t = (summary.get("thresholds_size") or {}).get(eff) or {}
            lv = (f"{t['m_level']:.2f} cm", f"{t['above_named']} of {t['above']}") if t.get("m_level") is not None \
                else ("not reached (up to 10 cm)" if "curve" in t else "too few cases", "-")
            out.append(f"| {eff} | " + " | ".join(f"{b['named_correctly']}/{b['n']} named ({b['detected']} detected)"
                                                  if b["n"] else "-" for b in bins) + f" | {lv[0]} | {lv[1]} |")
    if summary.get("other_engine"):
        oe = summary["other_engine"]
        out.append(f"\nOther engine: {oe['misspecified-unexplained']} of {oe['n']} misspecified-unexplained "
                   f"(screening verdicts: {oe['screening']}).")
    if summary.get("alternatives"):
        a = summary["alternatives"]
        out.append(f"\nNamed with indistinguishable alternatives: {a['n']} cases; the named effect was the hidden one in "
                   f"{a['named_correctly']}, an alternative was in {a['hidden_among_alternatives']}.")
    if summary.get("refit_drop"):
        rd = summary["refit_drop"]
        out.append(f"\nMedian refit error drop, correctly named cases: {rd['median'] * 100:.0f}% (n = {rd['n']}).")
    if summary.get("refit_drop_of_reducible"):
        rd = summary["refit_drop_of_reducible"]
        out.append(f"Median refit drop of the reducible error (nominal Chamfer minus the truth's), correctly named "
                   f"cases: {rd['median'] * 100:.0f}% (n = {rd['n']}"
                   + (f"; the truth scores no better than the nominal fit in {rd['floor_at_or_above_nominal']} more, "
                      f"whose Chamfer cannot fall (sensor spread), and {rd['without_floor']} have no truth's score "
                      f"stored" if "without_floor" in rd else "") + ").")
    if summary.get("refit_bias_fall"):
        rb = summary["refit_bias_fall"]
        out.append(f"Median fall of the summary bias (the nominal's systematic deviation from the measurement in check's "
                   f"summaries, which the named refit removes), correctly named cases: {rb['median'] * 100:.0f}% "
                   f"(n = {rb['n']}; {rb['without']} refits stored before it was kept).")
    if summary.get("refit_drop_by_effect"):
        def cell(v):
            return "-" if not v["n"] else f"{v['median'] * 100:.0f}% (n = {v['n']})"
        out.append("\n| hidden effect, correctly named | Chamfer drop | drop of the reducible error | fall of the "
                   "summary bias |")
        out.append("|---|---|---|---|")
        for k, v in summary["refit_drop_by_effect"].items():
            out.append(f"| {k} | {cell(v['chamfer'])} | {cell(v['reducible'])} | {cell(v['bias'])} |")
    if summary.get("refit_drop_energy"):
        rd = summary["refit_drop_energy"]
        out.append(f"Median refit drop of the energy score, correctly named cases that stored it: "
                   f"{rd['median'] * 100:.0f}% (n = {rd['n']}; their Chamfer drop: "
                   f"{rd['median_chamfer_same_cases'] * 100:.0f}%).")
    if summary.get("refit_drop_pm"):
        rd = summary["refit_drop_pm"]
        out.append(f"Median refit drop of the posterior-mean rollout's Chamfer, correctly named cases that stored it: "
                   f"{rd['median'] * 100:.0f}% (n = {rd['n']}; their posterior-predictive Chamfer drop: "
                   f"{rd['median_chamfer_same_cases'] * 100:.0f}%).")
    if summary.get("energy_truth"):
        et = summary["energy_truth"]
        red = et["median_drop_of_reducible"]
        out.append(f"The truth's own predictive distribution scores below the nominal fit in {et['truth_below_nominal']} "
                   f"and below the refit in {et['truth_below_refit']} of {et['n']} cases (a proper score); median "
                   f"share of the energy score above the truth's that the refit removes: "
                   + ("-" if red is None else f"{red * 100:.0f}%") + ".")
    out.append("\n| case | truth | scenario | magnitude | misspecification p | verdict | named | wall [s] |")
    out.append("|---|---|---|---|---|---|---|---|")
    for r in rows:
        if "verdict" not in r:
            err = r.get("error", "")[:60]
            out.append(f"| {r['id']} | {r['truth_label']} | {r['scenario']} | | | error: {err} | | |")
            continue
        m = "" if r["magnitude"] is None else f"{r['magnitude']:.2f}"
        verdict = r["verdict"]
        if r.get("screening_verdict", verdict) != verdict:
            verdict += f" (screening: {r['screening_verdict']})"
        refits = "; ".join(f"{x[0]} Chamfer {-x[1] * 100:+.0f}%" + (f", check p {x[2]:.2g}" if len(x) > 2 and x[2] is not None
                                                             else "") for x in r.get("refits") or [] if x[1] is not None)
        named = (r["named"] or "") + (f" (refits: {refits})" if refits else "")
        out.append(f"| {r['id']} | {r['truth_label']} | {r['scenario']} | {m} | {r['misspecification_p_text']} | "
                   f"{verdict} | {named} | {r['wall_s']:.0f} |")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("--suite", default="mujoco", choices=sorted(SUITES))
    r.add_argument("--cases", default="0:10", help="index range start:stop, or indices i,j,k")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--results", type=Path, default=Path("benchmarks/results/diagnose_stats.jsonl"))
    r.add_argument("--out", type=Path, default=Path("runs/diagnose_stats"))
    r.add_argument("--rounds", type=int, default=2)
    r.add_argument("--sims", type=int, default=60)
    r.add_argument("--n-null", type=int, default=30)
    r.add_argument("--max-null", type=int, default=200)
    r.add_argument("--confirm", type=int, default=0)
    r.add_argument("--workers", type=int, default=None)
    r.add_argument("--confirm-budget", default=None, help="ROUNDSxSIMS of the confirmation refits (default: "
                                                          "the nominal fit's)")
    r.add_argument("--proposal", default="corrected", choices=["corrected", "truncated"],
                   help="the nominal fits' proposals (the refits' are truncated)")
    r.add_argument("--only", default=None, help="comma-separated truth labels to run (e.g. control); other "
                                                "indices in --cases are skipped")
    r.add_argument("--alpha", type=float, default=ALPHA, help="family-wise level of the verdicts")
    r.add_argument("--min-magnitude", type=float, default=None,
                   help="run only hidden-effect cases with at least this magnitude (controls skipped)")
    r.add_argument("--all-candidates", action="store_true",
                   help="screen all named candidates, as `softsbi diagnose` does, where the suite screens fewer "
                        "(mujoco, cross-engine: the four built-in physics effects); ids end in -c10")
    f = sub.add_parser("refit", help="refit stored cases' nominal runs with an effect at another budget")
    f.add_argument("--runs", default="CASE_ID:EFFECT", help="comma-separated CASE_ID:EFFECT (run dirs under --out)")
    f.add_argument("--out", type=Path, default=Path("runs/diagnose_stats"))
    f.add_argument("--rounds", type=int, default=3)
    f.add_argument("--sims", type=int, default=100)
    f.add_argument("--proposal", default="truncated")
    fl = sub.add_parser("floor", help="add the oracle floor (truth re-simulated) to stored rows with refits")
    fl.add_argument("--results", type=Path, default=Path("benchmarks/results/diagnose_stats.jsonl"))
    fl.add_argument("--out", type=Path, default=Path("runs/diagnose_stats"))
    te = sub.add_parser("truth-energy", help="add the energy scores of the nominal fit, the named refit and the "
                                             "truth's own predictive distribution to stored correctly named rows")
    te.add_argument("--results", type=Path, default=Path("benchmarks/results/diagnose_stats.jsonl"))
    te.add_argument("--out", type=Path, nargs="+", default=[Path("runs/diagnose_stats")],
                    help="folders holding the cases' run directories")
    mg = sub.add_parser("merge", help="merge rows run apart into --results: same id replaces (the case run again), "
                                      "new ids are appended")
    mg.add_argument("files", type=Path, nargs="+")
    mg.add_argument("--results", type=Path, default=Path("benchmarks/results/diagnose_stats.jsonl"))
    mg.add_argument("--note", default=None, help="why replaced rows were run again (stored as 'rerun')")
    sz = sub.add_parser("size", help="add each hidden effect's size in the data (Chamfer at the truth without "
                                     "it minus with it) to stored rows")
    sz.add_argument("--results", type=Path, default=Path("benchmarks/results/diagnose_stats.jsonl"))
    sz.add_argument("--out", type=Path, nargs="+", default=[Path("runs/diagnose_stats")],
                    help="folders holding the cases' run directories")
    pm = sub.add_parser("pm-rollout", help="add the posterior-mean rollout's Chamfer drop to the refits of stored "
                                           "correctly named rows whose runs are on disk")
    pm.add_argument("--results", type=Path, default=Path("benchmarks/results/diagnose_stats.jsonl"))
    pm.add_argument("--out", type=Path, nargs="+", default=[Path("runs/diagnose_stats")],
                    help="folders holding the cases' run directories")
    rd = sub.add_parser("redecide", help="apply rule 3 again to stored rows with a check-accepted refit whose "
                                         "Chamfer did not fall (adds the summary bias), or with the third verdict "
                                         "after refits (refits below rule 2's share may follow)")
    rd.add_argument("--results", type=Path, default=Path("benchmarks/results/diagnose_stats.jsonl"))
    rd.add_argument("--out", type=Path, nargs="+", default=[Path("runs/diagnose_stats")],
                    help="folders holding the cases' run directories")
    for cmd, (_, _, _, _, what) in REDO_STORED.items():
        rs = sub.add_parser(cmd, help=f"{what}, then apply rule 3 again")
        rs.add_argument("--results", type=Path, default=Path("benchmarks/results/diagnose_stats.jsonl"))
        rs.add_argument("--out", type=Path, nargs="+", default=[Path("runs/diagnose_stats")],
                        help="folders holding the cases' run directories")
        rs.add_argument("--ids", default=None, help="comma-separated case ids (default: every row with such a refit)")
        rs.add_argument("--list", action="store_true", help=f"only list the rows and refits ({cmd})")
    rg = sub.add_parser("rediagnose", help="diagnose again, at another level, the stored rows whose verdict could "
                                           "change at it (from their stored nominal runs)")
    rg.add_argument("--results", type=Path, default=Path("benchmarks/results/diagnose_stats.jsonl"))
    rg.add_argument("--out", type=Path, nargs="+", default=[Path("runs/diagnose_stats")],
                    help="folders holding the cases' run directories")
    rg.add_argument("--alpha", type=float, default=ALPHA)
    rg.add_argument("--ids", default=None, help="comma-separated case ids (default: every row that could change)")
    rg.add_argument("--list", action="store_true", help="only list the rows that could change and their run dirs")
    s = sub.add_parser("summary")
    s.add_argument("--results", type=Path, default=Path("benchmarks/results/diagnose_stats.jsonl"))
    s.add_argument("--markdown", action="store_true", help="Markdown tables instead of JSON")
    s.add_argument("--confirm", type=int, default=0, help="summarise the rows run with this many refits "
                                                          "(-1: any number)")
    s.add_argument("--confirm-budget", default=None, help="only rows whose refits had this budget (3x100)")
    s.add_argument("--test", default="joint", choices=["joint", "omnibus", "any"],
                   help="only rows decided with this misspecification test (omnibus: rows stored before the joint test)")
    s.add_argument("--alpha", type=float, default=None, help="only rows decided at this level (rows stored before "
                                                             "the field: 0.01; default: any)")
    s.add_argument("--summaries", type=int, default=None, choices=[13, 14],
                   help="only rows whose tests used this many summaries per frame (13: before the local thickness; "
                        "default: any)")
    s.add_argument("--proposal", default="corrected", choices=["corrected", "truncated", "any"],
                   help="only rows whose nominal fit used these proposals (rows stored before the field: corrected)")
    s.add_argument("--candidates", type=int, default=None,
                   help="only rows whose diagnosis screened this many candidate effects (default: any)")
    a = ap.parse_args()
    if a.cmd == "merge":
        print(json.dumps(merge_rows(a.results, a.files, a.note)))
        return
    if a.cmd == "size":
        print(f"{add_effect_sizes(a.results, a.out)} rows updated")
        return
    if a.cmd == "rediagnose":
        ids = a.ids.split(",") if a.ids else None
        if a.list:
            for r in load_rows(a.results):
                if awaits_level(r, a.alpha, ids) and can_change_at(r, a.alpha):
                    print(r["id"], r["truth_label"], r.get("misspecification_p"), find_run_dir(a.out, r["id"]))
            return
        print(f"changed: {rediagnose_rows(a.results, a.out, a.alpha, 1, ids)}")
        return
    if a.cmd in REDO_STORED:
        done, select, describe, redo, _ = REDO_STORED[a.cmd]
        ids = a.ids.split(",") if a.ids else None
        if a.list:
            for r, _, _, todo in stored_diagnoses(load_rows(a.results), a.out, ids, done, select):
                print(r["id"], r["truth_label"], r["verdict"], r["named"], [describe(c) for c in todo])
            return
        print(f"changed: {redo(a.results, a.out, 1, ids)}")
        return
    if a.cmd == "redecide":
        print(f"changed: {redecide_rows(a.results, a.out)}")
        return
    if a.cmd == "floor":
        print(f"{add_floors(a.results, a.out)} rows updated")
        return
    if a.cmd == "pm-rollout":
        print(f"{add_pm_drops(a.results, a.out)} rows updated")
        return
    if a.cmd == "truth-energy":
        print(f"{add_truth_energies(a.results, a.out)} rows updated")
        return
    if a.cmd == "refit":
        for item in a.runs.split(","):
            case_id, effect = item.split(":")
            print(json.dumps(refit_case(a.out / case_id, effect, a.rounds, a.sims, a.proposal)), flush=True)
        return
    if a.cmd == "run":
        if ":" in a.cases:
            lo, hi = (int(x) for x in a.cases.split(":"))
            indices: Any = range(lo, hi)
        else:
            indices = [int(x) for x in a.cases.split(",")]
        cb = None
        if a.confirm_budget:
            r_, n_ = (int(x) for x in a.confirm_budget.lower().split("x"))
            cb = {"rounds": r_, "sims_per_round": n_}
        run_cases(a.suite, indices, a.results, a.out, a.seed, a.rounds, a.sims, a.n_null, a.max_null,
                  a.confirm, a.workers, set(a.only.split(",")) if a.only else None, cb, a.proposal, a.alpha,
                  a.min_magnitude, a.all_candidates)
    else:
        rows = select_rows(load_rows(a.results),
                           None if a.confirm < 0 else a.confirm, a.confirm_budget,
                           None if a.test == "any" else a.test, None if a.proposal == "any" else a.proposal,
                           a.alpha, a.summaries, a.candidates)
        summ = summarise(rows)
        print(markdown(summ, rows) if a.markdown else json.dumps(summ, indent=2))


if __name__ == "__main__":
    main()
