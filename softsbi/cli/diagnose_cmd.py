"""``softsbi diagnose``: is an effect missing from a fit's model, and which."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import typer

from softsbi.cli.command import json_done
from softsbi.cli.options import H_ALPHA, H_JSON, H_MAX_NULL, H_RECOMPUTE, H_WORKERS, names, setting
from softsbi.cli.output import Output
from softsbi.core.defaults import DiagnoseSettings
from softsbi.core.errors import SoftsbiError


def print_diagnosis(o: Output, diagnosis: Any) -> None:
    """A :class:`~softsbi.core.results.Diagnosis` as its candidates' table, its verdict and its paragraphs on
    stdout (:mod:`softsbi.report.text` words them)."""
    from softsbi.report.text import diagnosis_columns, diagnosis_rows, diagnosis_text  # start-up: numpy, scipy
    o.table(diagnosis_columns(diagnosis), diagnosis_rows(diagnosis),
            title="Candidate effects, by the screening's evidence")
    o.line(f"verdict: {diagnosis.verdict}")
    for paragraph in diagnosis_text(diagnosis):
        o.line(paragraph)


def print_joint_diagnosis(o: Output, joint: Any, where: str = "DIR") -> None:
    """A :class:`~softsbi.core.results.joint.JointDiagnosis` as its candidates' table, its recordings' own verdicts, the
    set's verdict and its paragraphs on stdout (:mod:`softsbi.report.joint_text` words them; ``where``: its folder)."""
    from softsbi.report.joint_text import (JOINT_COLUMNS, RECORDING_COLUMNS, joint_rows, joint_text,  # start-up
                                           no_candidate_words, recording_rows)
    if joint.candidates:
        o.table(JOINT_COLUMNS, joint_rows(joint), title="Candidate effects refitted on every recording, by summed score")
    else:
        o.line(no_candidate_words(joint))
    o.table(RECORDING_COLUMNS, recording_rows(joint), title="Each recording's own diagnosis")
    o.line(f"verdict for the {'rig' if joint.rig else 'task'}: {joint.verdict}")
    for paragraph in joint_text(joint, where):
        o.line(paragraph)


def diagnose(run: list[Path] = typer.Argument(..., help="run directory of a finished fit (nominal model); several "
                                               "(with --out: 3 or more fits of one task's recordings, or 2 or more "
                                               "of one rig's motions): one verdict for the task or the rig"),
             effect: list[str] = typer.Option(None, "--effect", help="candidate effects (default: all installed)"),
             confirm: int = setting(DiagnoseSettings, "confirm", "refit the top N named candidates (trained ones by "
                                    "their amortised score, then the screening's) and at most one pair when none "
                                    "explains the misfit alone; 0 = no refit. With several runs, also the number "
                                    "of candidates refitted on every recording"),
             refit_rounds: Optional[int] = setting(DiagnoseSettings, "refit_rounds",
                                                   "rounds of a refit (default: the run's; a candidate the task "
                                                   "trained is then its amortised posterior, and N >= 2 fits it in "
                                                   "sequential rounds)"),
             refit_sims: Optional[int] = setting(DiagnoseSettings, "refit_sims",
                                                 "simulations per round of a refit (default: the run's)"),
             refine: int = setting(DiagnoseSettings, "refine", "amortised refits that are adequate and improving but "
                                   "whose effect the data may leave off, refined by 2 sequential rounds of 150 after "
                                   "their amortised posterior (at most N; 0 = none)"),
             candidate: list[str] = typer.Option(None, "--candidate", help="with several runs: a candidate to refit "
                                                 "on every recording and weigh for the task (repeat it; default: "
                                                 "those the recordings' own diagnoses refitted most often, the first "
                                                 "--confirm)"),
             k_se: float = setting(DiagnoseSettings, "k_se", "standard errors by which a refit's summary energy score "
                                                             "must fall to count, and within which two refits tie "
                                                             "(with several runs: summed, paired over recordings)"),
             n_null: int = setting(DiagnoseSettings, "n_null", "posterior-predictive simulations the null starts with"),
             max_null: int = setting(DiagnoseSettings, "max_null", H_MAX_NULL),
             alpha: float = setting(DiagnoseSettings, "alpha", H_ALPHA),
             workers: Optional[int] = setting(DiagnoseSettings, "workers", H_WORKERS),
             recompute: bool = typer.Option(False, "--recompute", help=H_RECOMPUTE),
             out_dir: Optional[Path] = typer.Option(None, "--out", help="output folder of diagnosis.json, the check and "
                                                    "the refits (default: RUN), to keep two diagnoses of one run "
                                                    "apart; RUN is then not written. With several runs (required): "
                                                    "the folder of joint-diagnosis.json, each run keeping its own "
                                                    "diagnosis and refits in its folder"),
             as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Is an effect missing, and which? Detect (check's test), propose (the screening ranks the candidates and the
    top ones are refitted), decide (a refit explains the misfit when check accepts it and its summary energy score
    falls). Several runs of one task's recordings: each is diagnosed, the candidates their diagnoses refitted are
    refitted on every recording, and a candidate is named for the task when its summed score falls by --k-se standard
    errors paired over recordings, Fisher's combined test of its refits' checks does not reject, and more recordings
    switch it on than chance allows."""
    runs, effects, candidates = run, names(effect, "--effect") or None, names(candidate, "--candidate") or None
    if len(runs) > 1 and out_dir is None:
        raise SoftsbiError(f"diagnosing {len(runs)} runs together needs --out DIR, the folder of their "
                           f"joint-diagnosis.json (each run keeps its own diagnosis in its folder)")
    if candidate and len(runs) == 1:
        raise SoftsbiError("--candidate weighs candidates across several recordings; with one run, name the family "
                           "with --effect")
    from softsbi.cli.progress import shown  # start-up: the workflows' progress
    from softsbi.core.results import to_json  # start-up: numpy
    from softsbi.workflows.criticism.diagnose import diagnose_run  # start-up: the diagnosis workflow
    from softsbi.workflows.criticism.joint import diagnose_runs  # start-up: the diagnosis workflow
    o = Output(as_json)
    with shown(o):
        settings = DiagnoseSettings(confirm=confirm, refit_rounds=refit_rounds, refit_sims=refit_sims, k_se=k_se,
                                    refine=refine, workers=workers, n_null=n_null, max_null=max_null, alpha=alpha)
        if len(runs) > 1:
            joint = diagnose_runs(runs, effects=effects, settings=settings, progress=o.message, recompute=recompute,
                                  out_dir=out_dir, candidates=candidates)
        else:
            out = diagnose_run(runs[0], effects=effects, settings=settings, progress=o.message,
                               recompute=recompute, out_dir=out_dir)
    if len(runs) > 1:
        if not json_done(o, to_json(joint)):
            print_joint_diagnosis(o, joint, str(out_dir))
    elif not json_done(o, to_json(out)):
        print_diagnosis(o, out)
