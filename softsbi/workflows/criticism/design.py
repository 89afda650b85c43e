"""The motion to record next (``softsbi design RUN``): rank the motions the object supports by how well one more
recording of each would inform the candidates a diagnosis left undecided.

The measure is a motion's *expected posterior contraction* of each undecided effect: the 90% interval width of the
effect's best-informed parameter over its prior's width, under the prior predictive (a Bayesian design utility: the
expected posterior variance of the quantity of interest, Chaloner & Verdinelli 1995, section 2.2, read as an
interval width as softsbi's training reports read it). A motion *informs* an effect when that ratio is at most
:data:`~softsbi.core.defaults.INFORMED_MAX_RATIO` (0.5), the criterion of ``task train``'s report and of the
diagnosis's "not informed by this task". It is measured where it can be and estimated where it cannot:

* **trained task** of the motion with the effect's model in the fit's simulation bank (``softsbi task train`` on a
  recording of that motion): the report's median width ratio over its held-out prior simulations. Seconds.
* **linear estimate** otherwise (:func:`linear_widths`): at the fit's cloth (its posterior median; a parameter the
  motion adds at its prior midpoint), the screening's finite differences (:func:`~softsbi.workflows.criticism.
  screening.sensitivity_jobs`) of the check's summary statistics, each simulated with :data:`FD_SEEDS` seeds; the
  Fisher information ``J^T P J`` over every inferred parameter and the effect's, with ``P`` the summaries' noise
  precision from :data:`NOISE_SEEDS` seeds of the base simulation (:func:`noise_precision`: frame by frame, without
  bias), plus the uniform prior's precision (:data:`PRIOR_PRECISION`); the effect parameter's marginal
  variance, the diagonal of its inverse (so a nominal parameter that mimics the effect widens it: the linearised
  Cramer-Rao bound); the width ``2 * 1.645 * sd`` over the prior's, at most 1. Local and linear, and a bound an
  estimator trained on a budget does not reach, so an optimistic estimate; the cost is
  ``NOISE_SEEDS + FD_SEEDS x (D + sum_e (1 + D_e))`` simulations per motion, printed first.

The bound is optimistic: a trained estimator does not reach it at its simulation budget (on the demo's lift, the
trained task's widths were 0.8-20 times the bound's). Where trained tasks of the fit's own motion measure candidates of
its family, the design also computes the bound there for all of them and scales the other motions' bounds by the
median ratio (:func:`efficiency_factor`), the estimator's efficiency carried to the motions it was not trained on; without
one, the bound stands as it is and the words say it is optimistic.

Ranked: most undecided candidates informed first, then the smallest summed width ratio. The advice names the best
motion other than the fit's own that informs a candidate the fit's own does not.
"""
from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from softsbi.core.errors import SoftsbiError
from softsbi.core.results import Diagnosis, check_result_path, read_result, write_result
from softsbi.core.results.design import LINEAR, TRAINED, Design, MotionEffect, undecided_candidates
from softsbi.core.types import ParamSpace, Scenario
from softsbi.plugins import registry
from softsbi.scenarios.catalog import builtin_files, load_scenario
from softsbi.workflows.criticism.check import loaded, reused, stored_result
from softsbi.workflows.criticism.joint import JOINT_FILE, load_joint_diagnosis
from softsbi.workflows.criticism.screening import (EFFECT_STEP, UNIT_STEP, default_candidates, inward_step,
                                                   is_generic, object_kind, sensitivity_jobs)
from softsbi.workflows.criticism.statistics import FEATURE_NAMES, summary_floor
from softsbi.workflows.criticism.stats import summarising
from softsbi.workflows.fit.config import fit_param_space
from softsbi.workflows.fit.jobs import JobItem, run_jobs
from softsbi.workflows.fit.runs import RunView
from softsbi.workflows.fit.task_store import StoredTask, task_store_of

#: seeds of each finite-difference simulation of the linear estimate (common random numbers: the step and its
#: reference share each seed, so the difference is the parameter's and the seeds average the rest)
FD_SEEDS = 2
#: seeds of the base simulation (the fit's cloth), whose spread is the summaries' noise: 31 degrees of freedom for
#: each frame's 14 summaries, whose precision matrix is then estimated without bias (:func:`noise_precision`)
NOISE_SEEDS = 32
#: a width ratio at which a posterior is taken as the prior's (the uniform's 90% interval is 0.9 of its width)
SATURATED = 0.9
#: the unit-cube prior's precision in the Laplace approximation: the inverse variance of a uniform on [0, 1]
PRIOR_PRECISION = 12.0
#: the two-sided 90% interval of a Gaussian in standard deviations
Z90 = 2 * 1.6448536269514722
#: the file ``design`` writes, in the run directory or ``--out``
DESIGN_FILE = "design.json"


def candidate_motions(run: RunView, scenarios: Sequence[str | Path | Scenario] = ()) -> list[Scenario]:
    """The motions to weigh: the fit's own, every built-in scenario the simulator runs whose object is the fit's
    (cloth or rope), and ``scenarios`` (names or scenario files), once each by name.

    Raises:
        DataError: an unknown scenario name or an invalid file (:func:`~softsbi.scenarios.catalog.load_scenario`).
        SoftsbiError: a given scenario the simulator cannot run or whose object differs from the fit's.
    """
    own = Scenario.from_json(run.record.scenario)
    sim = registry().simulator(run.config.backend)
    supported = tuple(getattr(sim, "scenarios", ()) or ())
    kind = object_kind(own)
    out = {own.name: own}
    for name in builtin_files():
        if name in supported and name not in out:
            s = load_scenario(name)
            if object_kind(s) == kind:
                out[name] = s
    for given in scenarios:
        s = load_scenario(given)
        if supported and s.name not in supported:
            raise SoftsbiError(f"--scenario {given}: {run.config.backend} cannot run scenario '{s.name}' (it runs "
                               f"{list(supported)})")
        if object_kind(s) != kind:
            raise SoftsbiError(f"--scenario {given}: its object is a {object_kind(s)}, the fit's a {kind}; a design "
                               f"weighs motions of the same object")
        out[s.name] = s
    return list(out.values())


def trained_width(tasks: Sequence[StoredTask], backend: str, motion: str, effect: str) -> float | None:
    """The smallest median 90% width ratio of ``effect``'s parameters on the trained task of ``motion`` with the
    nominal model plus ``effect`` among ``tasks`` (a simulation bank's stored tasks; ``task train``'s report: its
    held-out prior simulations), the one trained on the most prior simulations; None when none with a report."""
    own = {p.name for p in registry().effect(effect)().param_space()}
    best = None
    for t in tasks:
        idy = t.identity
        if (t.report is None or idy.get("backend") != backend or (idy.get("scenario") or {}).get("name") != motion
                or list(idy.get("effects") or ()) != [effect]):
            continue
        ratios = [c.width_ratio for n, c in t.report.contraction.items() if n in own and c.width_ratio is not None]
        if ratios and (best is None or t.n_prior > best[0]):
            best = (t.n_prior, float(min(ratios)))
    return None if best is None else best[1]


def linear_widths(run: RunView, motion: Scenario, effects: Sequence[str], workers: int | None = None
                  ) -> tuple[dict[str, float | None], int, dict[str, str]]:
    """The linear estimate (module docstring) of each of ``effects``' smallest 90% width ratio on one recording of
    ``motion``, at ``run``'s cloth and sensor model. Returns the ratios by effect (None: not estimated), the
    simulations spent and, by effect, why it could not be estimated."""
    nominal_space: ParamSpace = fit_param_space(replace(run.config, effects=list(run.effects)), motion)[1]
    median = dict(zip(run.space.names, np.median(run.post_theta, axis=0)))
    mid = nominal_space.midpoint()
    base = {n: float(median.get(n, mid[n])) for n in nominal_space.names}
    base.update(run.fixed)
    cands = [registry().effect(e)() for e in effects]
    jobs, cols, n = sensitivity_jobs(base, nominal_space, run.effects, cands, UNIT_STEP, EFFECT_STEP)
    own = Scenario.from_json(run.record.scenario)
    min_z = None if run.metric_min_z is None else motion.table_z + (run.metric_min_z - own.table_z)
    ctx = summarising(replace(run.sim_context(keep_rollout=False), scenario=motion.to_json(),
                              param_names=list(nominal_space.names), dense=None),
                      run.dense.shape[1], min_z, None, None)
    items = [JobItem(j.theta, k, effects=j.effects, summary_seed=k) for k in range(FD_SEEDS) for j in jobs]
    items += [JobItem(jobs[0].theta, k, effects=jobs[0].effects, summary_seed=k)
              for k in range(FD_SEEDS, NOISE_SEEDS)]
    results = run_jobs(ctx, items, workers, label=f"design: {motion.name}'s finite differences")
    feat = [r.features if r.ok and r.features is not None else None for r in results]
    fd = [feat[k * n:(k + 1) * n] for k in range(FD_SEEDS)]
    noise = [f for f in [feat[k * n] for k in range(FD_SEEDS)] + feat[FD_SEEDS * n:] if f is not None]
    if len(noise) < NOISE_SEEDS // 2:
        reason = next((r.reason for r in results if not r.ok), "its base simulations failed")
        return {e: None for e in effects}, len(items), {e: f"{motion.name}: {reason}" for e in effects}
    precision = noise_precision(np.stack(noise))
    d = nominal_space.dim

    def slope(i_step: int, i_ref: int, step: float) -> np.ndarray | None:
        diffs = [(f[i_step] - f[i_ref]) / step for f in fd if f[i_step] is not None and f[i_ref] is not None]
        return np.mean(diffs, axis=0) if diffs else None

    u_hat = np.clip(nominal_space.to_unit(nominal_space.as_array({k: base[k] for k in nominal_space.names})), 0, 1)
    nom_cols = [slope(1 + j, 0, inward_step(u_hat[j], UNIT_STEP)) for j in range(d)]
    zero = np.zeros(precision.shape[0])
    out: dict[str, float | None] = {}
    why: dict[str, str] = {}
    for eff in cands:
        es, nom = eff.param_space(), eff.nominal()
        eff_cols = []
        for (e, p, i_step, i_nom) in cols:
            if e is eff:
                u0 = es.subset([p]).to_unit(np.array([nom[p]]))[0]
                eff_cols.append(slope(i_step, i_nom, inward_step(u0, EFFECT_STEP)))
        if not eff_cols or any(c is None for c in eff_cols):
            out[eff.name], why[eff.name] = None, f"{motion.name}: the effect's simulations failed"
            continue
        J = np.column_stack([zero if c is None else c for c in nom_cols] + eff_cols)
        # posterior precision: the Fisher information plus the uniform prior's (a Gaussian of its variance, 1/12
        # in the unit cube), so that a direction the data do not inform keeps the prior's width
        cov = np.linalg.inv(J.T @ precision @ J + PRIOR_PRECISION * np.eye(J.shape[1]))
        sd = np.sqrt(np.clip(np.diag(cov)[d:], 0, None))
        out[eff.name] = float(min(1.0, Z90 * sd.min()))
    return out, len(items), why


def efficiency_factor(trained: Mapping[str, float], bounds: Mapping[str, float | None]) -> float | None:
    """How much wider a trained task's posterior is than the linear estimate's bound on the same motion: the median
    over the candidates both measure, neither at the prior's width (trained below :data:`SATURATED`), of trained
    width over bound, at least 1; None when there are none. On the fit's own motion this is the trained estimator's
    efficiency at its simulation budget, and the design carries it to the motions only the bound estimates
    (the assumption: the estimator is as efficient there)."""
    r = [trained[e] / b for e, b in bounds.items() if e in trained and b and trained[e] < SATURATED and b < SATURATED]
    return max(1.0, float(np.median(r))) if r else None


def noise_precision(noise: np.ndarray) -> np.ndarray:
    """The summaries' noise precision ``(F, F)`` from ``noise`` ``(K, F)``, the summaries of one simulation point at
    ``K`` seeds: frame by frame (each frame's :data:`~softsbi.workflows.criticism.statistics.FEATURE_NAMES` block;
    frames independent, as the sensor samples each anew), the sample covariance plus the check's floors on the
    diagonal, inverted and scaled by ``(K - p - 2) / (K - 1)`` (``p`` summaries per frame), which makes the inverse of
    a Wishart sample covariance unbiased for the precision (Anderson 2003, section 7.2). A cloud's summaries move
    together (a shifted cloud moves its mean, quantiles and extent alike), so treating them as independent would count
    one measurement many times.

    Raises:
        ValueError: fewer seeds than a frame's summaries plus 3 (no unbiased inverse)."""
    k, n_f = noise.shape
    p = len(FEATURE_NAMES) if n_f % len(FEATURE_NAMES) == 0 else n_f
    if k < p + 3:
        raise ValueError(f"{k} seeds cannot estimate the precision of {p} summaries (at least {p + 3})")
    floor = np.square(np.broadcast_to(summary_floor(n_f), (n_f,)))
    out = np.zeros((n_f, n_f))
    for lo in range(0, n_f, p):
        blk = slice(lo, lo + p)
        cov = np.cov(noise[:, blk], rowvar=False) + np.diag(floor[blk])
        out[blk, blk] = np.linalg.inv(cov) * (k - p - 2) / (k - 1)
    return out


def design_run(run_dir: str | Path, scenarios: Sequence[str | Path] = (), effects: Sequence[str] | None = None, *,
               workers: int | None = None, out_dir: str | Path | None = None,
               recompute: bool = False, progress: Callable[[str], None] | None = None) -> Design:
    """Which motion to record next so that the candidates ``run_dir``'s diagnosis left undecided can be decided
    (module docstring). Writes ``design.json`` to ``out_dir`` (default: the run directory).

    Args:
        run_dir: a finished fit; its ``diagnosis.json`` (if any) says which candidates are undecided
            (:func:`undecided_candidates`), else every candidate of the family. Or the folder of a diagnosis across
            several recordings (``joint-diagnosis.json``, ``diagnose RUN RUN ... --out DIR``): its set's verdict
            says which are undecided, its recordings' motions are the ones recorded (the advice is a motion none
            of them is), and the linear estimate is made at its first recording's fit.
        scenarios: further motions to weigh (scenario names or files) beside the built-in ones the simulator runs.
        effects: the candidates to weigh instead of the undecided ones.
        workers: simulation worker processes (None: one per core).
        out_dir: where ``design.json`` goes.
        recompute: compute again even when ``design.json`` holds the result for the same settings.
        progress: told each step.

    Returns:
        the :class:`~softsbi.core.results.design.Design`.

    Raises:
        SoftsbiError: an effect the simulator cannot apply; a scenario it cannot run
            (:func:`candidate_motions`); the run is not a finished fit. DataError: an unknown scenario.
    """
    t0 = time.perf_counter()
    say = progress or (lambda _: None)
    joint = load_joint_diagnosis(run_dir) if (Path(run_dir) / JOINT_FILE).is_file() else None
    run = loaded(joint.runs[0] if joint is not None else run_dir)
    sim = registry().simulator(run.config.backend)
    family = [c.name for c in default_candidates(run.config.backend, Scenario.from_json(run.record.scenario),
                                                 run.effects) if not is_generic(c)]
    if effects is not None:
        bad = [e for e in effects if sim.supports(registry().effect(e)) is not None]
        if bad:
            raise SoftsbiError(f"--effect {bad[0]}: {sim.supports(registry().effect(bad[0]))}")
        undecided = {e: "named with --effect" for e in effects}
    elif joint is not None:
        undecided = undecided_candidates(joint, family)
    else:
        d = None
        path = Path(out_dir or run.path) / "diagnosis.json"
        if path.exists():
            d = read_result(path, Diagnosis, "diagnosis", "a diagnosis", f"`softsbi diagnose {run.path}`")
        undecided = undecided_candidates(d, family)
    rig = [Scenario.from_json(loaded(r).record.scenario) for r in joint.runs[1:]] if joint is not None else []
    motions = candidate_motions(run, [*rig, *scenarios])
    recorded = tuple(dict.fromkeys(joint.scenarios)) if joint is not None and joint.rig else ()
    home = Path(run_dir) if joint is not None else run.path
    out = Path(out_dir or home)
    out.mkdir(parents=True, exist_ok=True)
    json_path = check_result_path(out / DESIGN_FILE)
    key = {"run": str(home.resolve()), "undecided": dict(undecided), "motions": [m.name for m in motions],
           "seeds": [FD_SEEDS, NOISE_SEEDS]}
    stored = None if recompute else stored_result(json_path, Design, key, say)
    if stored is not None:
        say(reused(json_path))
        return stored
    store = task_store_of(run.config.sim_bank)
    tasks = store.list() if store is not None else []
    own = motions[0].name
    # on the fit's own motion every candidate of the family a trained task measured: the efficiency below
    own_trained = {e: w for e in dict.fromkeys([*family, *undecided])
                   if (w := trained_width(tasks, run.config.backend, own, e)) is not None}
    trained = {m.name: {e: w for e in undecided if (w := own_trained.get(e) if m.name == own else
                                                    trained_width(tasks, run.config.backend, m.name, e)) is not None}
               for m in motions}
    # the bound on the fit's own motion too, for every candidate of the family a trained task measured there, when
    # another motion needs the bound: their ratio is the trained estimator's efficiency (efficiency_factor), from
    # the whole family so that it does not depend on which candidates are undecided
    linear_needed = {m.name: [e for e in undecided if e not in trained[m.name]] for m in motions}
    if own_trained and any(linear_needed[m.name] for m in motions[1:]):
        linear_needed[own] = list(dict.fromkeys([*undecided, *own_trained]))
    say(f"design plan: {len(undecided)} undecided candidate{'s' if len(undecided) != 1 else ''} on "
        f"{len(motions)} motions ({', '.join(m.name for m in motions)}), each from a trained task where one is "
        f"stored, else by the linear estimate: {design_cost(run, motions, linear_needed)} simulations")
    bounds: dict[str, dict[str, float | None]] = {}
    sims = 0
    errors: dict[tuple[str, str], str] = {}
    for m in motions:
        rest = linear_needed[m.name]
        if rest:
            say(f"design: {m.name}: the linear estimate of {len(rest)} candidate{'s' if len(rest) > 1 else ''} "
                f"({FD_SEEDS} seeds per finite difference, {NOISE_SEEDS} for the noise)")
            widths, n, why = linear_widths(run, m, rest, workers)
            sims += n
            bounds[m.name] = widths
            errors.update({(m.name, e): w for e, w in why.items()})
    factor = efficiency_factor(own_trained, bounds.get(own, {}))
    cells: list[MotionEffect] = []
    for m in motions:
        for e in undecided:
            b = bounds.get(m.name, {}).get(e)
            if e in trained[m.name]:
                cells.append(MotionEffect(motion=m.name, effect=e, width_ratio=trained[m.name][e], source=TRAINED,
                                          bound=b))
            else:
                cells.append(MotionEffect(motion=m.name, effect=e, source=LINEAR, bound=b,
                                          width_ratio=None if b is None else min(1.0, b * (factor or 1.0)),
                                          error=errors.get((m.name, e))))

    def rank(name: str) -> tuple[int, float]:
        mine = [c for c in cells if c.motion == name]
        return (-sum(c.informs for c in mine), sum(1.0 if c.width_ratio is None else c.width_ratio for c in mine))
    order = sorted((m.name for m in motions), key=rank)
    result = Design(run=str(home), motion=motions[0].name, recorded=recorded, undecided=dict(undecided), cells=tuple(
        sorted(cells, key=lambda c: (order.index(c.motion), list(undecided).index(c.effect)))),
        motions=tuple(order), simulations=sims, efficiency=factor, key=key, seconds=time.perf_counter() - t0)
    write_result(json_path, result)
    say(f"wrote {json_path}")
    return result


def design_cost(run: RunView, motions: Sequence[Scenario], effects: Mapping[str, Sequence[str]]) -> int:
    """The simulations of the linear estimates of ``effects[motion]`` on each of ``motions``:
    ``NOISE_SEEDS + FD_SEEDS x (D + sum_e (1 + D_e))`` per motion with any, ``D`` the motion's inferred parameters."""
    total = 0
    for m in motions:
        mine = effects.get(m.name) or ()
        if mine:
            d = fit_param_space(replace(run.config, effects=list(run.effects)), m)[1].dim
            total += NOISE_SEEDS + FD_SEEDS * (d + sum(1 + registry().effect(e)().param_space().dim for e in mine))
    return total


__all__ = ["FD_SEEDS", "NOISE_SEEDS", "candidate_motions", "design_cost", "design_run", "linear_widths",
           "noise_precision", "trained_width", "undecided_candidates"]
