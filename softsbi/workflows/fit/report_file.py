"""A fit's ``report.json``: the Chamfer summary of a set of rollouts (:func:`chamfer_stats`, shared with
``check``), the report's construction (:func:`build_report`) and its reading (:func:`read_report`).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from softsbi.core.results.fitreport import REQUIRED_KEYS
from softsbi.core.results import ResultDamaged, read_json
from softsbi.core.store import RunStore
from softsbi.core.types import STATUS_OK, ParamSpace, Recording
from softsbi.inference.contraction import INFORMED_MAX_RATIO, bound_pressure, contraction
from softsbi.plugins import registry
from softsbi.workflows.fit.config import CHAMFER_M, FitConfig, RunRecord
from softsbi.workflows.fit.task_store import served_by_task


class RoundsOutcome(Protocol):
    """What :func:`build_report` reads of a fit's rounds (:class:`~softsbi.workflows.fit.rounds.Rounds`)."""

    store: RunStore
    #: whether the estimator is sequential (else every round drew from the prior)
    sequential: bool
    #: each round's summary, as ``report.json``'s ``per_round`` before it is cut down
    summaries: list[dict[str, Any]]
    #: :func:`chamfer_stats` of the first round's prior draws (empty, :class:`ChamferStats` ``()``, when not scored)
    prior_stats: "ChamferStats"


@dataclass(frozen=True, kw_only=True)
class ChamferStats:
    """The Chamfer summary of a set of rollouts (:func:`chamfer_stats`); every field None (``failed`` 0) for rollouts
    that were not scored (a fit without a metric's reference).

    Attributes:
        mean_m, std_m: mean and standard deviation over the successful simulations of each one's mean over the
            metric's frames (the metric's unit: m, or px for an image fit); None when none succeeded.
        per_frame_m: ``(T,)`` the per-frame mean over the successful simulations; None when none succeeded.
        n: the successful simulations (None when not scored). failed: the failed ones.
        one_sided_mean_m, one_sided_std_m, one_sided_per_frame_m: the same of the one-sided Chamfer (measured to
            simulated, m), None when it was not computed.
    """

    mean_m: float | None = None
    std_m: float | None = None
    per_frame_m: list[float] | None = None
    n: int | None = None
    failed: int = 0
    one_sided_mean_m: float | None = None
    one_sided_std_m: float | None = None
    one_sided_per_frame_m: list[float] | None = None


def chamfer_stats(chamfer: np.ndarray, status: np.ndarray, frames: list[int] | None = None,
                  one_sided: np.ndarray | None = None) -> ChamferStats:
    """Summary of per-frame Chamfer values ``chamfer (N, T)`` of ``N`` simulations with ``status (N,)``:
    each simulation's mean over ``frames`` (None = all), then ``mean_m``/``std_m`` over the successful
    ones, ``per_frame_m (T,)`` (mean over them), ``n``, ``failed``; with ``one_sided (N, T)`` also
    ``one_sided_mean_m``, ``one_sided_std_m``, ``one_sided_per_frame_m`` (:class:`ChamferStats`). The fit's report
    and ``check`` both summarise with this, so their numbers agree."""
    fr = slice(None) if frames is None else list(frames)
    ok = (status == STATUS_OK) & np.all(np.isfinite(chamfer), axis=1)
    per_sim = chamfer[ok][:, fr].mean(1) if ok.any() else np.array([])
    one: dict[str, Any] = {}
    if one_sided is not None:
        ok1 = ok & np.all(np.isfinite(one_sided), axis=1)
        o = one_sided[ok1][:, fr].mean(1) if ok1.any() else np.array([])
        one = {"one_sided_mean_m": float(o.mean()) if len(o) else None,
               "one_sided_std_m": float(o.std()) if len(o) else None,
               "one_sided_per_frame_m": one_sided[ok1].mean(0).tolist() if ok1.any() else None}
    return ChamferStats(mean_m=float(per_sim.mean()) if len(per_sim) else None,
                        std_m=float(per_sim.std()) if len(per_sim) else None,
                        per_frame_m=chamfer[ok].mean(0).tolist() if ok.any() else None,
                        n=int(ok.sum()), failed=int((status != STATUS_OK).sum()), **one)


#: what every reader of a fit's ``report.json`` needs in it (a file without them is damaged): the typed report's
#: required keys, one definition for the dict reader and :class:`~softsbi.core.results.fitreport.FitReport`
REPORT_KEYS = REQUIRED_KEYS


def read_report(run_dir: str | Path) -> dict[str, Any]:
    """A finished fit's ``report.json``.

    Raises:
        ResultDamaged: it is empty, cut short, not JSON or lacks :data:`REPORT_KEYS`; one line naming it and the
            command that writes it again (the fit's own, which resumes the finished run and rewrites only the
            report).
    """
    run_dir = Path(run_dir)
    return read_json(run_dir / "report.json", f"re-running the fit with the same `softsbi fit ... --out {run_dir}` "
                                              f"command", REPORT_KEYS)


def damaged_report(run_dir: Path) -> ResultDamaged | None:
    """The error :func:`read_report` raises for ``run_dir``'s ``report.json``; None when it is sound or absent."""
    if not (run_dir / "report.json").exists():
        return None
    try:
        read_report(run_dir)
    except ResultDamaged as exc:
        return exc
    return None


def build_report(recording: Recording, cfg: FitConfig, space: ParamSpace, loop: RoundsOutcome,
                 ev_stats: ChamferStats, samples: np.ndarray, wall: float, metric: str) -> dict[str, Any]:
    """``report.json``: settings, posterior summaries (physical units), Chamfer of prior and
    posterior-predictive rollouts (``ev_stats``), per-round summaries (each round's ``chamfer_posterior``: the
    :class:`ChamferStats` of the rollouts drawn from its posterior), and the truth when simulated."""
    summaries, prior = loop.summaries, loop.prior_stats
    failed = sum(s["failed"] for s in summaries) + ev_stats.failed
    total = sum(s["simulations"] for s in summaries) + cfg.n_eval
    report = {
        "observed": recording.source,
        "backend": cfg.backend, "estimator": cfg.estimator, "effects": cfg.effects,
        "parameters": space.to_json(), "fixed": cfg.fixed,
        "rounds": cfg.rounds, "sims_per_round": cfg.sims_per_round, "simulations": total,
        "proposal": cfg.proposal if loop.sequential else "prior",
        "min_height_m": cfg.min_height, "frames": cfg.frames,
        "failed_simulations": failed,
        # simulations of the rounds read from the simulation bank instead of simulated (per round in per_round)
        "bank_hits": sum(s["bank_hits"] for s in summaries),
        "chamfer_prior_m": prior.mean_m,
        "chamfer_prior_std_m": prior.std_m,
        "chamfer_posterior_m": ev_stats.mean_m,
        "chamfer_posterior_std_m": ev_stats.std_m,
        "chamfer_posterior_n": ev_stats.n,
        # the metric: per frame, simulated and measured clouds seen through the fit's sensor
        # model; the headline values above are the mean over metric_frames
        # the sensor model stored with the run, which its simulations' per-frame metric used (_sim_context)
        "metric_min_z_m": RunRecord.from_run_config(loop.store.config).metric_min_z if metric == CHAMFER_M else None,
        "metric_frames": cfg.frames if metric == "chamfer_m" else None, "metric_sensor": cfg.sensor,
        "chamfer_posterior_one_sided_m": ev_stats.one_sided_mean_m,
        "chamfer_posterior_one_sided_std_m": ev_stats.one_sided_std_m,
        "chamfer_prior_per_frame_m": prior.per_frame_m,
        "chamfer_posterior_per_frame_m": ev_stats.per_frame_m,
        "chamfer_posterior_one_sided_per_frame_m": ev_stats.one_sided_per_frame_m,
        "posterior_mean": space.as_dict(samples.mean(0)),
        "posterior_std": space.as_dict(samples.std(0)),
        "posterior_q05": space.as_dict(np.quantile(samples, 0.05, axis=0)),
        "posterior_q95": space.as_dict(np.quantile(samples, 0.95, axis=0)),
        "posterior_median": space.as_dict(np.median(samples, axis=0)),
        # width of the 90% interval over the prior's, in each parameter's own scale (log for log ones)
        "contraction": contraction(space, samples), "informed_max_width_ratio": INFORMED_MAX_RATIO,
        # parameters whose posterior piles up at a prior bound: a prior too narrow, or a misspecified model
        "posterior_at_bounds": bound_pressure(space, samples),
        "truth": recording.truth,
        "per_round": [{"round": s["round"], "usable": s["usable"], "failed": s["failed"], "bank_hits": s["bank_hits"],
                       "chamfer_posterior_m": s["chamfer_posterior"].mean_m,
                       "chamfer_posterior_std_m": s["chamfer_posterior"].std_m,
                       "mass_in_box": s["mass_in_box"], "train_seconds": s["train"].get("seconds"),
                       "posterior_mean": s["posterior_mean"],
                       **({"task": s["train"]["task"]} if served_by_task(s["train"]) else {})} for s in summaries],
        "wall_time_s": wall,
        "metric": metric,
    }
    if metric == "mask_chamfer_px":  # the paper's image metric: HSV cloth masks, bidirectional Chamfer (px)
        for k in ("prior", "prior_std", "posterior", "posterior_std"):
            report[f"mask_chamfer_{k}_px"] = report.pop(f"chamfer_{k}_m")
            report[f"chamfer_{k}_m"] = None
        for row in report["per_round"]:
            row["mask_chamfer_posterior_px"] = row.pop("chamfer_posterior_m")
            row["mask_chamfer_posterior_std_px"] = row.pop("chamfer_posterior_std_m")
        if report["mask_chamfer_prior_px"] and report["mask_chamfer_posterior_px"]:
            report["chamfer_reduction"] = 1 - report["mask_chamfer_posterior_px"] / report["mask_chamfer_prior_px"]
    elif report["chamfer_prior_m"] and report["chamfer_posterior_m"]:
        report["chamfer_reduction"] = 1 - report["chamfer_posterior_m"] / report["chamfer_prior_m"]
    if recording.truth:
        # an effect added by the fit but absent from the measurement is truly switched off
        truth = dict(recording.truth)
        for e in cfg.effects:
            for k, v in registry().effect(e)().nominal().items():
                truth.setdefault(k, v)
        report["truth"] = truth
        report["truth_in_90pct_interval"] = {
            n: bool(report["posterior_q05"][n] <= truth[n] <= report["posterior_q95"][n])
            for n in space.names if n in truth}
    return report
