"""Two runs of the same measurement side by side: error per time step and region, before vs after.

Each run's errors are its own ``check`` (:func:`~softsbi.workflows.check.check_run`): clouds seen
through that fit's sensor model, the headline averaged over the fit's frames; runs whose sensor
models differ (``--sensor height|camera``, the camera itself, ``--min-height``, ``--frames``:
:func:`~softsbi.workflows.check.sensor_model`) are compared on different metrics, which the summary says.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from softsbi.core.errors import SoftsbiError
from softsbi.core.metrics import describe_change
from softsbi.report import fit_label, plot_compare
from softsbi.workflows.check import MAX_NULL, check_run, sensor_model
from softsbi.workflows.defaults import N_EVAL
from softsbi.workflows.lock import check_out_dir
from softsbi.workflows.runs import load_run
from softsbi.workflows.stats import posterior_mean_chamfer


def compare_runs(run_a: str | Path, run_b: str | Path, out_dir: str | Path, n_eval: int = N_EVAL,
                 workers: int | None = None, max_null: int = MAX_NULL) -> dict[str, Any]:
    """Posterior predictive checks of two runs of the same measurement, side by side.

    Writes ``compare.png`` (Chamfer per frame, error per region) and ``compare.json``.
    ``n_eval`` and ``max_null`` go to each run's :func:`~softsbi.workflows.check.check_run`.

    Returns:
        dict with ``table`` (rows ``what``, ``a``, ``b``, relative ``change``: the posterior-predictive Chamfer
        first, then the one-sided Chamfer, the energy score and the posterior-mean rollout's Chamfer
        (:func:`~softsbi.workflows.stats.posterior_mean_chamfer`) where both runs have them, per phase, per
        region), ``summary`` (says when the
        two fits use different sensor models, :func:`~softsbi.workflows.check.sensor_model`: sensor kind,
        virtual camera, height cut or frames, so their Chamfer values measure different things),
        ``same_sensor``, both checks, ``posterior_mean_chamfer`` (``{"a", "b"}``, each run's
        :func:`~softsbi.workflows.stats.posterior_mean_chamfer` or None), and the paths of the figure and the JSON.

    Raises:
        SoftsbiError: the runs were fitted to different measurements; RunDirError: ``out_dir`` or a run directory
            cannot be written (all checked before the first rollout).
    """
    # everything that can be refused is, before the first rollout: both runs, the measurement, the folders
    ra, rb = load_run(run_a), load_run(run_b)
    if ra.config.get("observed_source") != rb.config.get("observed_source"):
        raise SoftsbiError(f"the runs were fitted to different measurements ({ra.config.get('observed_source')} vs "
                           f"{rb.config.get('observed_source')}); compare runs of the same measurement")
    if len(ra.scenario.times) != len(rb.scenario.times):
        raise SoftsbiError("the two runs have different frame counts; compare runs of the same measurement")
    check_out_dir(out_dir)
    for run in (run_a, run_b):
        check_out_dir(run, "run directory", "compare writes each run's check.json and check.png into it: copy the "
                                            "run directory to a writable place and compare the copy")
    a = check_run(run_a, n_eval=n_eval, workers=workers, plot=True, max_null=max_null)
    b = check_run(run_b, n_eval=n_eval, workers=workers, plot=True, max_null=max_null)
    rows = [{"what": "Chamfer, mean over the fit's frames", "a": a["chamfer_mean_m"], "b": b["chamfer_mean_m"]}]
    if a.get("chamfer_one_sided_mean_m") is not None and b.get("chamfer_one_sided_mean_m") is not None:
        rows.append({"what": "one-sided Chamfer (measured -> simulated)", "a": a["chamfer_one_sided_mean_m"],
                     "b": b["chamfer_one_sided_mean_m"]})
    energy = ({"what": "energy score (Chamfer less half the mean Chamfer between two rollouts)",
               "a": a["energy"]["energy_m"], "b": b["energy"]["energy_m"]} if a.get("energy") and b.get("energy")
              else None)
    if energy:
        rows.append(energy)
    pm_a, pm_b = posterior_mean_chamfer(ra, workers=workers), posterior_mean_chamfer(rb, workers=workers)
    pm = ({"what": "posterior-mean rollout Chamfer (the fitted point estimate)", "a": pm_a["chamfer_m"],
           "b": pm_b["chamfer_m"]} if pm_a and pm_b else None)
    if pm:
        rows.append(pm)
    for pa, pb in zip(a["phases"], b["phases"]):
        rows.append({"what": f"{pa['phase']} phase ({pa['t_s'][0]:.2f}-{pa['t_s'][1]:.2f} s)", "a": pa["chamfer_m"],
                     "b": pb["chamfer_m"]})
    for name in a["regions"]:
        rows.append({"what": f"region {name}", "a": a["region_mean_m"][name], "b": b["region_mean_m"].get(name, np.nan)})
    for r in rows:
        r["change"] = (r["b"] - r["a"]) / r["a"] if r["a"] else 0.0
    same_sensor = sensor_model(ra) == sensor_model(rb)
    la = fit_label(ra.config)
    lb = fit_label(rb.config)
    summary = (f"{lb} vs {la}: posterior-predictive Chamfer {rows[0]['a'] * 100:.2f} -> {rows[0]['b'] * 100:.2f} cm "
               f"({describe_change(rows[0]['a'], rows[0]['b'])})"
               + (f", energy score {energy['a'] * 100:.2f} -> {energy['b'] * 100:.2f} cm "
                  f"({describe_change(energy['a'], energy['b'])})" if energy else "")
               + (f", posterior-mean rollout {pm['a'] * 100:.2f} -> {pm['b'] * 100:.2f} cm "
                  f"({describe_change(pm['a'], pm['b'])})" if pm else "")
               + "; misspecification "
               f"{a['misspecification']['p_text']} -> {b['misspecification']['p_text']}."
               + ("" if same_sensor else " The two fits use different sensor models (--sensor / --min-height / "
                                         "--frames), so their Chamfer values measure different things."))
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    png = out_dir / "compare.png"
    plot_compare(png, a, b, la, lb)
    res = {"run_a": str(run_a), "run_b": str(run_b), "label_a": la, "label_b": lb, "table": rows,
           "summary": summary, "same_sensor": same_sensor, "check_a": a, "check_b": b,
           "posterior_mean_chamfer": {"a": pm_a, "b": pm_b}, "png": str(png),
           "json": str(out_dir / "compare.json")}
    (out_dir / "compare.json").write_text(json.dumps(res, indent=2))
    return res
