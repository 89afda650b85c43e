"""The demo: the whole real-to-sim story on a built-in case that needs no data files.

A lift recording is simulated at parameters the fit is not shown, with a hidden breeze the
nominal model lacks. The demo fits the nominal model, checks it against the recording, diagnoses
the missing effect among all installed ones (refitting the top candidates) and compares the nominal fit with
the named effect's refit. "Before" and "after"
are the posterior-predictive Chamfer of the two fits: the mean over rollouts at their posterior
samples (report.json's ``chamfer_posterior_m``, which ``compare`` reproduces exactly).

The steps report to a :class:`DemoCallbacks` (the CLI prints them); :func:`run_demo` returns
every number as one dict.
"""
from __future__ import annotations

import contextlib
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from softsbi.core.metrics import describe_change
from softsbi.core.results.comparison import CompareResult, Metric
from softsbi.core.errors import ParameterError
from softsbi.core.results import Diagnosis, to_json
from softsbi.inference.contraction import contraction_from_report
from softsbi.core.types import Recording
from softsbi.plugins import registry
from softsbi.report.text import check_summary
from softsbi.scenarios.builtin import lift_scenario
from softsbi.workflows import pools
from softsbi.workflows.criticism.check import check_run
from softsbi.core.defaults import BACKEND, DEMO_ROUNDS, DEMO_SIMS, ESTIMATOR, PROPOSAL, SEED
from softsbi.workflows.criticism.compare import compare_runs
from softsbi.workflows.criticism.diagnose import diagnose_run
from softsbi.workflows.criticism.stats import PosteriorPredictive
from softsbi.workflows.fit.run import FitCallbacks, FitConfig, FitResult, read_report, run_fit
from softsbi.workflows.lock import check_out_apart
from softsbi.workflows.measurement import simulate_recording
from softsbi.core.defaults import CheckSettings, DiagnoseSettings

#: the demo's hidden parameter values (unit-cube positions; the user is not told them before the fit ends)
DEMO_TRUTH_UNIT = {"bend": 0.62, "stretch": 0.45, "friction": 0.35, "scale": 0.55, "mass": 0.5}
#: the demo's hidden effect: a breeze the nominal model lacks
DEMO_HIDDEN_EFFECT = {"wind": {"wind_x": 0.0, "wind_y": 0.8}}


class DemoCallbacks:
    """What the demo tells its user at each step (every method does nothing by default)."""

    def step(self, title: str) -> None:
        """A new step begins (``title`` names it)."""

    def line(self, text: str) -> None:
        """A sentence for the user."""

    @contextlib.contextmanager
    def fitting(self) -> Iterator[FitCallbacks]:
        """Progress callbacks for one fit."""
        yield FitCallbacks()

    @contextlib.contextmanager
    def working(self, text: str) -> Iterator[None]:
        """A longer computation (``text`` says which) runs inside this context."""
        yield

    def fit_done(self, report: dict[str, Any], run_dir: Path) -> None:
        """A fit finished; ``report`` is its report.json."""

    def diagnosis_done(self, diagnosis: Diagnosis) -> None:
        """The diagnosis finished (``diagnose_run``'s result)."""

    def comparison_done(self, comparison: CompareResult, effect: str) -> None:
        """``compare_runs``' result of the nominal fit and the refit with ``effect``."""


def demo_recording(quick: bool, backend: str = BACKEND) -> tuple[Recording, dict[str, float]]:
    """The demo's lift recording simulated on ``backend`` and its hidden values (with the hidden breeze unless
    ``quick``)."""
    sc = lift_scenario(None)
    space = registry().simulator(backend)().param_space(sc)
    unit = {**dict.fromkeys(space.names, 0.5), **DEMO_TRUTH_UNIT}  # a parameter it does not name: the prior's middle
    u = np.array([unit[n] for n in space.names])
    truth = space.as_dict(space.from_unit(u))
    hidden_effects = [] if quick else list(DEMO_HIDDEN_EFFECT)
    truth_all = dict(truth, **({} if quick else DEMO_HIDDEN_EFFECT["wind"]))
    return simulate_recording(backend, sc, truth_all, effects=hidden_effects), truth_all


def check_demo_backend(backend: str, quick: bool) -> None:
    """Refuse, before any work, a backend that is not installed or cannot apply the hidden effect (unless ``quick``).

    Raises:
        ParameterError: one line naming the backend and the installed ones that can run the demo.
    """
    reg = registry()
    names = reg.names("simulator")
    able = " or ".join(b for b in names
                       if not any(reg.simulator(b).supports(reg.effect(e)) for e in DEMO_HIDDEN_EFFECT))
    if backend not in names:
        raise ParameterError(f"--backend {backend}: no such simulator is installed; the demo runs on {able}")
    why = next((w for e in DEMO_HIDDEN_EFFECT if (w := reg.simulator(backend).supports(reg.effect(e)))), None)
    if not quick and why is not None:
        raise ParameterError(f"--backend {backend}: the demo's hidden {', '.join(DEMO_HIDDEN_EFFECT)} needs {why}; "
                             f"run it on {able}, or add --quick (no hidden effect)")


def _fit(ui: DemoCallbacks, recording: Recording, cfg: FitConfig, run_dir: Path) -> FitResult:
    with ui.fitting() as callbacks:
        res = run_fit(run_dir, recording, cfg, callbacks=callbacks)
    ui.fit_done(res.report.to_json(), run_dir)
    return res


@pools.shared_executors()
def run_demo(out: str | Path = "softsbi-demo", quick: bool = False, rounds: int = DEMO_ROUNDS,
             sims_per_round: int = DEMO_SIMS, estimator: str = ESTIMATOR, seed: int = SEED,
             workers: int | None = None, proposal: str = PROPOSAL, ui: DemoCallbacks | None = None,
             backend: str = BACKEND) -> dict[str, Any]:
    """Run the demo on simulator ``backend`` into ``out`` (``nominal/``, ``with-<effect>/``, ``compare.png``): the
    recording is simulated, fitted and diagnosed on the same engine.

    Returns:
        ``{"out", "quick", "nominal" (report), "inside_90", "parameters" (all hidden values inside the 90%
        interval, all parameters), "informed" and "not_informed" (names; :mod:`softsbi.inference.contraction`),
        "inside_90_informed" (the informed parameters' hidden values inside), "wall_s"}`` and, unless
        ``quick``: ``check``, ``diagnosis``, ``refit`` (report), ``compare`` (without the per-run
        checks), ``named``, ``named_correctly``, ``chamfer_before_m``, ``chamfer_after_m``.

    Raises:
        ParameterError: a ``backend`` that cannot run it (:func:`check_demo_backend`).
        RunDirError: ``out`` is, or lies inside, the run directory of a fit
            (:func:`~softsbi.workflows.lock.check_out_apart`). Everything
        :func:`~softsbi.workflows.fit.run.run_fit` raises.
    """
    check_demo_backend(backend, quick)
    out = check_out_apart(out, "demo")
    ui = ui or DemoCallbacks()
    t0 = time.perf_counter()
    ui.step("softsbi demo")
    ui.line(f"A cloth lift simulated on {backend} at hidden parameters{'' if quick else ' with a hidden effect'}: "
            f"{rounds} rounds x {sims_per_round} simulations per fit, estimator {estimator}, {proposal} proposals.")
    recording, _ = demo_recording(quick, backend)
    cfg = FitConfig(backend=backend, estimator=estimator, rounds=rounds, sims_per_round=sims_per_round, seed=seed,
                    workers=workers, proposal=proposal)
    nominal = out / "nominal"
    ui.step("1. fit the nominal model")
    res = _fit(ui, recording, cfg, nominal)
    doc: dict[str, Any] = {"out": str(out), "quick": quick, "nominal": res.report.to_json()}
    if quick:
        return _finish(ui, doc, doc["nominal"], t0, "")
    return _find_and_add_effect(ui, doc, recording, cfg, out, res, workers, t0)


def _find_and_add_effect(ui: DemoCallbacks, doc: dict[str, Any], recording: Recording, cfg: FitConfig, out: Path,
                         res: FitResult, workers: int | None, t0: float) -> dict[str, Any]:
    """Steps 2-5: check, diagnose (with its refits), the named effect's refit, compare."""
    nominal = out / "nominal"
    ui.step("2. check: where does the model miss the measurement?")
    pool = PosteriorPredictive(nominal, workers)  # one null for check and diagnose
    with ui.working("posterior predictive check ..."):
        chk = check_run(nominal, pool=pool, settings=CheckSettings(workers=workers))
    doc["check"] = to_json(chk)
    ui.line(check_summary(chk))
    ui.step("3. diagnose: which installed effect explains the residual?")
    with ui.working("screening candidate effects and refitting the top ones ..."):
        diag = diagnose_run(
            nominal, pool=pool, progress=ui.line, settings=DiagnoseSettings(workers=workers)
        )  # diagnose's defaults
    doc["diagnosis"] = to_json(diag)
    ui.diagnosis_done(diag)
    if diag.verdict != "missing-effect":
        ui.line(f"verdict {diag.verdict}: no named effect to add; stopping here")
        return doc
    eff = "+".join(diag.decision.named)
    refit = Path(diag.refit(diag.decision.named).run)
    ui.step(f"4. add the effect: the refit with {eff} (what `softsbi fit ... --effect {eff}` gives)")
    ui.fit_done(read_report(refit), refit)
    ui.step("5. compare: error before and after")
    with ui.working("comparing the two fits ..."):
        comp = compare_runs(nominal, refit, out, settings=CheckSettings(workers=workers))
    ui.comparison_done(comp, eff)
    a, b = comp.check_a, comp.check_b
    chamfer = comp.row(Metric.CHAMFER)
    before, after = chamfer.a, chamfer.b
    doc.update(refit=read_report(refit), compare=to_json(comp), named=eff,
               named_correctly=set(diag.decision.named) == set(DEMO_HIDDEN_EFFECT), chamfer_before_m=before,
               chamfer_after_m=after)
    ui.step("the numbers")
    ui.line(f"hidden effect: {', '.join(DEMO_HIDDEN_EFFECT)}; diagnosis named: {eff} "
            f"({'correct' if doc['named_correctly'] else 'WRONG'}).")
    ui.line(f"posterior-predictive Chamfer: {before * 100:.2f} cm (nominal, n={a.n_rollouts} rollouts) -> "
            f"{after * 100:.2f} cm (with {eff}, n={b.n_rollouts} rollouts), "
            f"{describe_change(before, after)}.")
    if a.energy and b.energy:
        ea, eb = a.energy.energy_m, b.energy.energy_m
        ui.line(f"Chamfer energy score (a proper score: the Chamfer less half the mean Chamfer between two rollouts): "
                f"{ea * 100:.2f} cm -> {eb * 100:.2f} cm, {describe_change(ea, eb)}.")
        doc.update(energy_before_m=ea, energy_after_m=eb)
    if a.posterior_mean and b.posterior_mean:
        pa, pb = a.posterior_mean["chamfer_m"], b.posterior_mean["chamfer_m"]
        ui.line(f"posterior-mean rollout Chamfer (the fitted point estimate, without the posterior's width): "
                f"{pa * 100:.2f} cm -> {pb * 100:.2f} cm, {describe_change(pa, pb)}.")
        doc.update(pm_chamfer_before_m=pa, pm_chamfer_after_m=pb)
    figures = f" Figures: {out}/compare.png, {nominal}/check.png, {refit}/posterior_pairs.png"
    return _finish(ui, doc, doc["refit"], t0, figures, what="the refit's ")


def _finish(ui: DemoCallbacks, doc: dict[str, Any], report: dict[str, Any], t0: float, figures: str,
            what: str = "the ") -> dict[str, Any]:
    inside = report["truth_in_90pct_interval"]
    con = contraction_from_report(report)
    informed = [n for n in inside if con[n]["informed"]]
    doc.update(inside_90=sum(inside.values()), parameters=len(inside), informed=informed,
               inside_90_informed=sum(inside[n] for n in informed),
               not_informed=[n for n in inside if n not in informed], wall_s=time.perf_counter() - t0)
    j = len(doc["not_informed"])
    ui.line(f"{doc['inside_90_informed']} of {len(informed)} informed parameters' hidden values inside {what}90% "
            f"posterior interval; {j} parameter{'' if j == 1 else 's'} not informed"
            f"{' (' + ', '.join(doc['not_informed']) + ': 90% interval wider than half the prior)' if j else ''}. "
            f"Total {doc['wall_s']:.0f} s.{figures}")
    return doc
