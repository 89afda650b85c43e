"""Two fits of the same measurement side by side: error per time step and region, before vs after.

Each run's errors are its own ``check`` (:func:`~softsbi.workflows.criticism.check.check_run`, reused from its
``check.json`` when that holds the same fit and settings): clouds seen through that fit's sensor model, the
headline averaged over the fit's frames; runs whose sensor models differ
(:func:`~softsbi.workflows.criticism.check.sensor_model`) are compared on different metrics, which the summary says.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

from softsbi.core.errors import SoftsbiError
from softsbi.core.results.comparison import CompareResult, Metric, Row
from softsbi.core.results import CheckResult, check_result_path, write_result
from softsbi.report import fit_label, plot_compare
from softsbi.report.text import row_label
from softsbi.workflows import pools
from softsbi.workflows.criticism.check import check_run, sensor_model
from softsbi.workflows.lock import check_out_dir
from softsbi.workflows.fit.runs import load_run
from softsbi.workflows.criticism.screening import check_resolution
from softsbi.core.defaults import CheckSettings


@pools.shared_executors()
def compare_runs(run_a: str | Path, run_b: str | Path, out_dir: str | Path, settings: CheckSettings | None = None, *,
                 recompute: bool = False, message: Callable[[str], None] | None = None) -> CompareResult:
    """Posterior predictive checks of two runs of the same measurement, side by side.

    Writes ``compare.png`` (Chamfer per frame, error per region) and ``compare.json``. Everything that can be refused
    is, before the first rollout: both runs, the measurement, the folders.

    Args:
        run_a, run_b: finished fits of one measurement (e.g. the nominal model and a refit with an effect), as
            ``str`` or :class:`~pathlib.Path`.
        out_dir: where the figure and the JSON go (``str`` or ``Path``; created if missing).
        settings: each run's :func:`~softsbi.workflows.criticism.check.check_run` settings
            (:class:`~softsbi.core.defaults.CheckSettings`; None: the defaults); its ``alpha`` is the level both
            misspecification tests decide at (``p <= alpha``).
        recompute: check both runs again even when their ``check.json`` hold the same settings.
        message: told in one line what each check wrote, reused or computed again (a damaged ``check.json``).

    Returns:
        the :class:`~softsbi.core.results.comparison.CompareResult`: rows keyed by their
        :class:`~softsbi.core.results.comparison.Metric` (posterior-predictive Chamfer first, then the one-sided
        Chamfer, the Chamfer energy score and the posterior-mean rollout's Chamfer where both runs have them, per
        phase, per region) and both checks.

    Raises:
        SoftsbiError: ``alpha`` outside (0, 1) or a null cap that cannot resolve it; either is not a finished fit, or
            the runs were fitted to different measurements; RunDirError: ``out_dir`` or a run directory cannot be
            written. All before the first rollout.
    """
    out_dir = check_out_dir(out_dir)
    check_result_path(out_dir / "compare.json")
    check_result_path(out_dir / "compare.png")
    settings = settings or CheckSettings()
    check_resolution(settings.alpha, settings.max_null)
    run_a, run_b = Path(run_a), Path(run_b)
    ra, rb = load_run(run_a, None), load_run(run_b, None)  # every evaluation sample: each check uses its run as is
    if ra.record.observed_source != rb.record.observed_source or len(ra.dense) != len(rb.dense):
        raise SoftsbiError(f"the runs were fitted to different measurements ({ra.record.observed_source} vs "
                           f"{rb.record.observed_source}); compare runs of the same measurement")
    for run in (run_a, run_b):
        check_out_dir(run, "run directory", "compare writes each run's check.json and check.png into it: copy the "
                                            "run directory to a writable place and compare the copy")
        for name in ("check.json", "check.png"):  # the second run's too, before the first run's check
            check_result_path(run / name)
    a, b = (check_run(r, settings, recompute=recompute, message=message) for r in (ra, rb))
    rows = compare_rows(a, b)
    out_dir.mkdir(parents=True, exist_ok=True)
    png = out_dir / "compare.png"
    res = CompareResult(
        run_a=str(run_a),
        run_b=str(run_b),
        label_a=fit_label(ra.config.to_json()),
        label_b=fit_label(rb.config.to_json()),
        rows=tuple(rows),
        same_sensor=sensor_model(ra) == sensor_model(rb),
        check_a=a,
        check_b=b,
        png=str(png),
    )
    plot_compare(png, res)
    write_result(out_dir / "compare.json", res)
    return res


def compare_rows(a: CheckResult, b: CheckResult) -> tuple[Row, ...]:
    """The rows of a comparison of checks ``a`` and ``b`` (m), each keyed by its
    :class:`~softsbi.core.results.comparison.Metric` and labelled by :func:`~softsbi.report.text.row_label`: the
    posterior-predictive Chamfer, then the one-sided Chamfer, the Chamfer energy score and the posterior-mean
    rollout's Chamfer where both checks have them, then per phase (in ``a``'s phases) and per region (``a``'s
    regions; NaN where ``b`` lacks one)."""
    pairs: list[tuple[Metric, float, float, str]] = [(Metric.CHAMFER, a.chamfer_mean_m, b.chamfer_mean_m, "")]
    if a.chamfer_one_sided_mean_m is not None and b.chamfer_one_sided_mean_m is not None:
        pairs.append((Metric.CHAMFER_ONE_SIDED, a.chamfer_one_sided_mean_m, b.chamfer_one_sided_mean_m, ""))
    if a.energy and b.energy:
        pairs.append((Metric.ENERGY_CHAMFER, a.energy.energy_m, b.energy.energy_m, ""))
    if a.posterior_mean and b.posterior_mean:
        pairs.append((Metric.POSTERIOR_MEAN, a.posterior_mean["chamfer_m"], b.posterior_mean["chamfer_m"], ""))
    pairs += [(Metric.PHASE, pa.chamfer_m, pb.chamfer_m, pa.phase) for pa, pb in zip(a.phases, b.phases)]
    pairs += [(Metric.REGION, a.region_mean_m[n], b.region_mean_m.get(n, float("nan")), n) for n in a.regions]
    return tuple(Row(what=row_label(m, a, b, part), a=va, b=vb, metric=m, part=part) for m, va, vb, part in pairs)
