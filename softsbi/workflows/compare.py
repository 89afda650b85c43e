"""Two fits of the same measurement side by side: error per time step and region, before vs after.

Each run's errors are its own ``check`` (:func:`~softsbi.workflows.check.check_run`, reused from its
``check.json`` when that holds the same fit and settings): clouds seen through that fit's sensor model, the
headline averaged over the fit's frames; runs whose sensor models differ
(:func:`~softsbi.workflows.check.sensor_model`) are compared on different metrics, which the summary says.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

from softsbi.core.errors import SoftsbiError
from softsbi.core.results import CompareResult, Row, check_result_path, write_result
from softsbi.report import fit_label, plot_compare
from softsbi.workflows.check import check_run, sensor_model
from softsbi.workflows.lock import check_out_dir
from softsbi.workflows.runs import load_run
from softsbi.workflows.screening import check_resolution
from softsbi.workflows.stats import ALPHA, MAX_NULL, N_NULL


def compare_runs(run_a: str | Path, run_b: str | Path, out_dir: str | Path, n_eval: int = N_NULL,
                 workers: int | None = None, max_null: int = MAX_NULL, recompute: bool = False,
                 message: Callable[[str], None] | None = None) -> CompareResult:
    """Posterior predictive checks of two runs of the same measurement, side by side.

    Writes ``compare.png`` (Chamfer per frame, error per region) and ``compare.json``. Everything that can be refused
    is, before the first rollout: both runs, the measurement, the folders.

    Args:
        run_a, run_b: finished fits of one measurement (e.g. the nominal model and a refit with an effect).
        out_dir: where the figure and the JSON go.
        n_eval, max_null: each run's :func:`~softsbi.workflows.check.check_run` settings.
        recompute: check both runs again even when their ``check.json`` hold the same settings.
        message: told in one line what each check wrote, reused or computed again (a damaged ``check.json``).

    Returns:
        the :class:`~softsbi.core.results.CompareResult`: rows ``what``, ``a``, ``b`` (posterior-predictive
        Chamfer first, then the one-sided Chamfer, the energy score and the posterior-mean rollout's Chamfer where
        both runs have them, per phase, per region) and both checks.

    Raises:
        SoftsbiError: a null cap that cannot resolve the checks' level; either is not a finished fit, or the runs
            were fitted to different measurements; RunDirError: ``out_dir`` or a run directory cannot be written.
    """
    check_resolution(ALPHA, max_null, 2)
    ra, rb = load_run(run_a), load_run(run_b)
    if ra.config.get("observed_source") != rb.config.get("observed_source") or len(ra.dense) != len(rb.dense):
        raise SoftsbiError(f"the runs were fitted to different measurements ({ra.config.get('observed_source')} vs "
                           f"{rb.config.get('observed_source')}); compare runs of the same measurement")
    check_out_dir(out_dir)
    check_result_path(Path(out_dir) / "compare.json")
    for run in (run_a, run_b):
        check_out_dir(run, "run directory", "compare writes each run's check.json and check.png into it: copy the "
                                            "run directory to a writable place and compare the copy")
    a = check_run(run_a, n_eval=n_eval, workers=workers, max_null=max_null, recompute=recompute, message=message)
    b = check_run(run_b, n_eval=n_eval, workers=workers, max_null=max_null, recompute=recompute, message=message)
    n = f"n={a.n_rollouts}" + ("" if b.n_rollouts == a.n_rollouts else f" and {b.n_rollouts}")
    rows = [Row(f"posterior-predictive Chamfer, mean over the fit's frames ({n} rollouts)", a.chamfer_mean_m,
                b.chamfer_mean_m)]
    if a.chamfer_one_sided_mean_m is not None and b.chamfer_one_sided_mean_m is not None:
        rows.append(Row("one-sided Chamfer (measured -> simulated)", a.chamfer_one_sided_mean_m,
                        b.chamfer_one_sided_mean_m))
    if a.energy and b.energy:
        rows.append(Row("energy score (a proper score: Chamfer less half the mean Chamfer between two rollouts)",
                        a.energy.energy_m, b.energy.energy_m))
    if a.posterior_mean and b.posterior_mean:
        rows.append(Row("posterior-mean rollout Chamfer (the fitted point estimate)", a.posterior_mean["chamfer_m"],
                        b.posterior_mean["chamfer_m"]))
    rows += [Row(f"{pa.phase} phase ({pa.t_s[0]:.2f}-{pa.t_s[1]:.2f} s)", pa.chamfer_m, pb.chamfer_m)
             for pa, pb in zip(a.phases, b.phases)]
    rows += [Row(f"region {n}", a.region_mean_m[n], b.region_mean_m.get(n, float("nan"))) for n in a.regions]
    out_dir.mkdir(parents=True, exist_ok=True)
    png = out_dir / "compare.png"
    res = CompareResult(str(run_a), str(run_b), fit_label(ra.config), fit_label(rb.config), tuple(rows),
                        sensor_model(ra) == sensor_model(rb), a, b, str(png))
    plot_compare(png, res)
    write_result(out_dir / "compare.json", res)
    return res
