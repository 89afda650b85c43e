"""``softsbi check`` (where and when a fit misses its measurement) and ``softsbi compare`` (two fits' misses side by
side)."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from softsbi.cli.command import json_done
from softsbi.cli.options import H_ALPHA, H_JSON, H_MAX_NULL, H_N_EVAL, H_RECOMPUTE, H_WORKERS, setting
from softsbi.cli.output import Output
from softsbi.core.defaults import CheckSettings


def check(run: Path = typer.Argument(..., help="run directory of a finished fit"),
          n_eval: int = setting(CheckSettings, "n_eval", H_N_EVAL),
          max_null: int = setting(CheckSettings, "max_null", H_MAX_NULL),
          alpha: float = setting(CheckSettings, "alpha", H_ALPHA),
          workers: Optional[int] = setting(CheckSettings, "workers", H_WORKERS),
          recompute: bool = typer.Option(False, "--recompute", help=H_RECOMPUTE),
          as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Posterior predictive check: where and when the fitted model misses the measurement."""
    from softsbi.cli.progress import shown  # start-up: the workflows' progress
    from softsbi.core.results import to_json  # start-up: numpy
    from softsbi.report.text import check_summary, joint_test_line  # start-up: numpy, scipy
    from softsbi.workflows.criticism.check import check_run  # start-up: the check workflow
    o = Output(as_json)
    with shown(o):
        out = check_run(run, CheckSettings(n_eval=n_eval, workers=workers, alpha=alpha, max_null=max_null),
                        recompute=recompute, message=o.message)
    if json_done(o, to_json(out)):
        return
    o.table(["phase", "time [s]", "Chamfer [cm]", "worst region"],
            [[ph.phase + ("" if ph.in_fit else " (not fitted)"), f"{ph.t_s[0]:.2f}-{ph.t_s[1]:.2f}",
              f"{ph.chamfer_m * 100:.2f}", ph.worst_region] for ph in out.phases],
            title="Error by phase of the motion")
    o.line(joint_test_line(out.test))
    o.line(check_summary(out))


def compare(run_a: Path = typer.Argument(..., help="first run (e.g. nominal model)"),
            run_b: Path = typer.Argument(..., help="second run (e.g. with the effect added)"),
            out: Optional[Path] = typer.Option(None, help="output folder (default: RUN_B)"),
            n_eval: int = setting(CheckSettings, "n_eval", H_N_EVAL + ", per run"),
            max_null: int = setting(CheckSettings, "max_null", H_MAX_NULL + " (each run's check)"),
            alpha: float = setting(CheckSettings, "alpha", H_ALPHA + " (each run's check)"),
            workers: Optional[int] = setting(CheckSettings, "workers", H_WORKERS),
            recompute: bool = typer.Option(False, "--recompute", help=H_RECOMPUTE),
            as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Two runs side by side: error per time step and region, before vs after."""
    from softsbi.cli.progress import shown  # start-up: the workflows' progress
    from softsbi.core.results import to_json  # start-up: numpy
    from softsbi.report.text import compare_summary  # start-up: numpy, scipy
    from softsbi.workflows.criticism.compare import compare_runs  # start-up: the check workflow
    o = Output(as_json)
    with shown(o):
        res = compare_runs(
            run_a,
            run_b,
            out or run_b,
            CheckSettings(n_eval=n_eval, workers=workers, alpha=alpha, max_null=max_null),
            recompute=recompute,
            message=o.message,
        )
    if json_done(o, to_json(res)):
        return
    o.table(["", str(run_a), str(run_b), "change"],
            [[row.what, f"{row.a * 100:.2f} cm", f"{row.b * 100:.2f} cm", f"{row.change * 100:+.0f}%"]
             for row in res.rows], title="Posterior-predictive error")
    o.line(compare_summary(res))
    o.line(f"wrote {res.png} and {Path(res.png).with_name('compare.json')}")
