"""``softsbi calibrate RUN``: is this run's posterior estimator calibrated where its posterior lives?

Simulation-based calibration (Talts et al. 2018; expected coverage as in Hermans et al. 2022,
"A trust crisis in simulation-based inference?"; TARP, Lemos et al. 2023) of the run's final
estimator, on fresh simulations from the run's own proposals:

1. The final round's estimator is trained again exactly as the fit trained it (same stored
   simulations, options and seed; a mixture's run keeps ``q`` at the measurement only, and every
   estimator is retrained alike), and compared with the run's own final ``q``.
2. ``n_test`` test parameters are drawn from the distribution the training simulations came from:
   the run's proposals, each round's with the weight of its usable simulations (round 1: the
   prior; later rounds: the previous round's posterior, or the truncated prior of TSNPE). The
   last proposal is the largest part of it in a sequential run, so the test covers the region of
   the run's posterior; drawing from the *same* mixture the estimator was trained on is what makes
   ``q(theta | x)`` the reference posterior of every test pair (drawing from the last proposal
   alone would need an importance correction by ``p~_last / p~_mix``).
3. They are simulated and observed with the fit's simulator, observer and seeds scheme, and stored
   in the run store's ``calibration`` group (a re-run resumes; more ``n_test`` adds to them). The
   test simulations are never used in training.
4. Per test pair, ``n_draws`` draws of ``q(. | x_i)`` restricted to the prior box give the HPD
   expected coverage at every level (with the binomial band of a calibrated estimator), SBC rank
   histograms per parameter, and TARP (:mod:`softsbi.inference.calibration`).
5. One verdict reads all three (:func:`softsbi.inference.calibration.verdict`: family-wise level 0.05,
   Bonferroni over the diagnostics and, within SBC, over the parameters): "calibrated" only when none
   rejects, else what rejects, naming the parameters whose marginals are too narrow, too wide or biased.

Outputs ``RUN/calibration.json`` and ``RUN/calibration.png``. All coordinates are the unit cube of
the inferred parameters (log scale for log-scaled parameters).
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from softsbi.core.distributions import PosteriorChain, TruncatedPrior
from softsbi.core.errors import PosteriorError, SoftsbiError
from softsbi.core.results.fitreport import CalibrationResult
from softsbi.core.results import check_result_path, write_json_atomic
from softsbi.core.store import RunStore
from softsbi.core.store.groups import holds
from softsbi.core.types import STATUS_OK, STATUS_PENDING, ParamSpace
from softsbi.inference import calibration as cal
from softsbi.plugins import registry
from softsbi.report.calibration_figures import plot_calibration
from softsbi.core import defaults
from softsbi.workflows import pools
from softsbi.workflows.fit.config import FitConfig, RunRecord, estimator_options as fit_estimator_options
from softsbi.workflows.fit.resume import observed_data
from softsbi.workflows.fit.rounds import round_posterior, usable_simulations
from softsbi.workflows.fit.task_store import served_by_task, task_store_of
from softsbi.workflows.fit.jobs import JobItem, SimContext, run_jobs
from softsbi.workflows.lock import run_lock
from softsbi.workflows.fit.prior_widening import MappedProposal, map_mixture, round_spaces, unit_map

__all__ = ["calibrate_run"]

GROUP = "calibration"
#: test simulations are drawn in blocks of this size, each from its own seed, so a larger ``n_test``
#: later extends the stored ones instead of replacing them
BLOCK = 50


#: calibrate's hold on the run directory: it writes into the run it is given (no --out to choose another folder)
_LOCK: dict[str, Any] = {"command": "calibrate", "busy": "wait for it to finish, then re-run the same command",
                         "out_flag": None}


def _proposals(store: RunStore, cfg: FitConfig, space: ParamSpace, last: int,
               counts: list[int]) -> list[tuple[Any, str]]:
    """Each round's proposal up to ``last`` (None = the prior) as the fit drew it, with a description; a round
    before a ``--widen`` widening drew in the narrower prior, sampled in the prior of record's unit cube
    (:class:`~softsbi.workflows.fit.prior_widening.MappedProposal`)."""
    est_cls = registry().estimator(cfg.estimator)
    sequential = bool(getattr(est_cls, "sequential", True))
    truncated = sequential and cfg.proposal == "truncated"
    chain = PosteriorChain(space.dim, seed=cfg.seed)
    spaces = round_spaces(space, store.config, last)
    out: list[tuple[Any, str]] = []
    for r in range(last + 1):
        def to_record(p: Any, r: int = r) -> Any:
            return p if spaces[r] == space else MappedProposal(p, *unit_map(spaces[r], space))

        if r == 0 or not sequential:
            out.append((to_record(None), "prior" if spaces[r] == space else "prior before its widening"))
            continue
        if truncated:
            ch = PosteriorChain(space.dim, seed=cfg.seed)
            ch.add_round(map_mixture(round_posterior(store, r - 1, cfg), *unit_map(spaces[r - 1], spaces[r])),
                         sum(counts[:r]))
            out.append((to_record(TruncatedPrior(ch.posterior(0), eps=cfg.truncation_eps, seed=cfg.seed + r)),
                        f"prior truncated to round {r}'s posterior"))
        else:
            chain.add_round(round_posterior(store, r - 1, cfg), counts[r - 1])
            out.append((chain.posterior(r - 1), f"posterior of round {r}"))
    return out


def _draw_block(b: int, proposals: list[tuple[Any, str]], counts: list[int], seed: int, last: int,
                dim: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Block ``b`` of test draws: ``(u (BLOCK, D), round (BLOCK,), seeds (BLOCK,))``."""
    rng = np.random.default_rng([seed, 16016, last, b])
    w = np.asarray(counts, float)
    which = np.sort(rng.choice(len(proposals), size=BLOCK, p=w / w.sum()))
    u = np.empty((BLOCK, dim))
    for r in np.unique(which):
        idx = np.nonzero(which == r)[0]
        prop = proposals[r][0]
        u[idx] = rng.random((len(idx), dim)) if prop is None else prop.sample(len(idx), rng)
    seeds = rng.integers(0, 2**31 - 1, size=BLOCK)
    return u, which, seeds


def _sim_context(store: RunStore, cfg: FitConfig) -> SimContext:
    """The run's simulations without a metric (the test simulations need observations only)."""
    rec = RunRecord.from_run_config(store.config)
    return SimContext(backend=cfg.backend, backend_options=dict(cfg.backend_options), scenario=rec.scenario,
                      effects=list(cfg.effects), observer=cfg.observer, observer_options=dict(rec.observer_options),
                      param_names=[p["name"] for p in rec.param_space], fixed=dict(cfg.fixed), dense=None,
                      n_dense=int(cfg.n_dense))


def _test_simulations(store: RunStore, cfg: FitConfig, space: ParamSpace, last: int, counts: list[int],
                      n_test: int, workers: int | None, message: Callable[[str], None]) -> dict[str, np.ndarray]:
    """The stored test simulations, simulating the missing ones block by block (stored after each)."""
    n_blocks = -(-n_test // BLOCK)
    key = {"last_round": last, "seed": cfg.seed, "counts": counts}
    data: dict[str, np.ndarray] | None = None
    if store.has(GROUP):
        arrays, attrs = store.read_group(GROUP)
        if holds(attrs, key):
            data = arrays
        else:
            message("the run has changed since its last calibration: drawing new test simulations")
    x_shape = observed_data(store)["x"].shape
    if data is None:
        data = {"u": np.zeros((0, space.dim)), "round": np.zeros(0, int), "seed": np.zeros(0, np.int64),
                "status": np.zeros(0, np.uint8), "x": np.zeros((0,) + x_shape, np.float32)}
    proposals = _proposals(store, cfg, space, last, counts)
    ctx = _sim_context(store, cfg)
    have = len(data["status"]) // BLOCK
    for b in range(n_blocks):
        if b < have and not (data["status"][b * BLOCK:(b + 1) * BLOCK] == STATUS_PENDING).any():
            continue
        u, which, seeds = _draw_block(b, proposals, counts, cfg.seed, last, space.dim)
        theta = space.from_unit(u)
        message(f"test simulations {b * BLOCK + 1}-{(b + 1) * BLOCK} of {n_blocks * BLOCK}")
        res = run_jobs(ctx, [JobItem(t, s) for t, s in zip(theta, seeds)], workers, cfg.executor,
                       cfg.executor_options, label="calibration test simulations")
        status = np.array([r.status for r in res], np.uint8)
        x = np.full((BLOCK,) + x_shape, np.nan, np.float32)
        for i, r in enumerate(res):
            if r.ok and r.x is not None:
                x[i] = r.x
        sl = slice(b * BLOCK, (b + 1) * BLOCK)
        new = {"u": u, "round": which, "seed": seeds, "status": status, "x": x}
        if b < len(data["status"]) // BLOCK:
            for k in data:
                data[k][sl] = new[k]
        else:
            data = {k: np.concatenate([data[k], new[k].astype(data[k].dtype)]) for k in data}
        store.write_group(GROUP, data, attrs={**key, "what": "calibration test simulations from the run's "
                                              "proposals (never used in training)",
                                              "proposals": [p[1] for p in proposals]},
                          units={"x": "m"})
    return {k: v[: n_blocks * BLOCK] for k, v in data.items()}


@pools.shared_executors()
def calibrate_run(run_dir: str | Path, n_test: int = defaults.N_TEST, n_draws: int = defaults.N_DRAWS,
                  workers: int | None = None,
                  estimator: str | None = None, estimator_options: Mapping[str, Any] | None = None,
                  n_bins: int = defaults.N_BINS, write: bool = True,
                  message: Callable[[str], None] | None = None) -> CalibrationResult:
    """Simulation-based calibration of a finished run's final estimator (module docstring).

    Args:
        run_dir: a fit's run directory (at least one finished round).
        n_test: test simulations (rounded up to blocks of 50); >= 200 resolves a coverage error of
            0.05 at 90 % (binomial s.e. 0.02).
        n_draws: posterior draws per test case.
        workers: simulation worker processes (None: one per core).
        estimator, estimator_options: calibrate another estimator (with ``estimator_options`` only) or
            the run's estimator with its options updated by ``estimator_options`` (e.g.
            ``{"ensemble": 1}``), trained on the same stored simulations; the stored test simulations
            are shared (they depend on the run's proposals only). The estimator's defaults are those
            of the installed version: a run fitted under other defaults is reported with a notice and
            ``refit_max_mean_difference`` > 0.
        n_bins: bins of the rank histograms.
        write: write ``calibration.json`` and ``calibration.png`` into ``run_dir``.
        message: progress notices.

    Returns:
        The :class:`~softsbi.core.results.fitreport.CalibrationResult` (``calibration.json`` is its
        :meth:`~softsbi.core.results.fitreport.CalibrationResult.to_json`): ``coverage`` (``levels``, ``hpd``, ``band_lo``/``band_hi`` (pointwise
        95 %), ``band_simultaneous_lo``/``_hi`` (the whole curve's band at the verdict's level, Bonferroni over
        the levels), ``outside_pointwise`` (levels), ``inside_simultaneous``, ``at_50``, ``at_90``, ``band_50``,
        ``band_90`` (the verdict's band at those levels)), ``verdict_50``, ``verdict_90``, ``verdict``,
        ``calibrated``, ``too_narrow``/``too_wide``/``biased`` (parameter names), ``diagnostics`` (each
        diagnostic's test, :func:`softsbi.inference.calibration.verdict`), ``sbc`` (per-parameter rank
        histograms, ``band`` (the verdict's band of one bin), ``shapes``, ``rejects``, ``ks_pvalue``,
        ``chi2_pvalue``), ``tarp``, counts and timings.

    Raises:
        SchemaError: not a run directory. SoftsbiError: no finished round, ``n_test`` < 20 or ``n_draws`` < ``n_bins``.
        RunLocked: another process writes the run.
    """
    msg = message or (lambda s: None)
    run_dir = Path(run_dir)
    if n_test < defaults.MIN_TEST:
        raise SoftsbiError(f"--n-test must be >= {defaults.MIN_TEST} (got {n_test}); 200 or more resolves the 90% "
                           f"coverage")
    if n_draws < max(defaults.MIN_DRAWS, n_bins):
        raise SoftsbiError(f"--n-draws must be >= {max(defaults.MIN_DRAWS, n_bins)} (got {n_draws}): one posterior "
                           f"draw per bin of the {n_bins}-bin SBC rank histogram, and HPD levels (coverage, TARP) "
                           f"resolved to 1/{n_bins}")
    store = RunStore.open(run_dir / "run.zarr")
    if write:
        check_result_path(run_dir / "calibration.json")
        check_result_path(run_dir / "calibration.png")
    cfg = FitConfig.from_run_config(store.config)
    space = ParamSpace.from_json(store.config["param_space"])
    rounds = store.completed_rounds()
    if not rounds:
        raise SoftsbiError(f"'{run_dir}' holds no finished round yet; resume the fit with the same `softsbi fit` "
                           f"command first")
    last = rounds[-1]
    task_line = trained_task_line(store.round_record(0).info, cfg.sim_bank)
    if task_line:
        msg(task_line)
    U, X, counts = usable_simulations(store, last)
    if not len(U):  # a fit of the stored task's posterior alone (run_fit's task_only): nothing of its own to train on
        raise SoftsbiError(f"'{run_dir}' holds no simulations of its own: its posterior is a stored task's, whose "
                           f"calibration was measured when it was trained (`softsbi task show "
                           f"{store.round_record(0).task or 'KEY'}`)")
    t0 = time.perf_counter()
    with run_lock(run_dir, **_LOCK):  # only the writes need the lock: training and evaluating read the store
        data = _test_simulations(store, cfg, space, last, counts, n_test, workers, msg)
    sim_s = time.perf_counter() - t0
    ok = (data["status"] == STATUS_OK) & np.all(np.isfinite(data["x"].reshape(len(data["x"]), -1)), axis=1)
    name = estimator or cfg.estimator
    est_cls = registry().estimator(name)
    # the run's own estimator as its fit trained it: the options its effects asked for, under the user's
    opts = fit_estimator_options(cfg, est_cls) if estimator is None else {}
    opts.update(dict(estimator_options or {}))
    est = est_cls(**opts)
    fr = slice(None) if cfg.frames is None else list(cfg.frames)
    msg(f"training '{name}' on the run's {len(U)} stored simulations (as the fit's round {last + 1})")
    t1 = time.perf_counter()
    est.fit(U.astype(np.float64), X[:, fr].astype(np.float64), seed=cfg.seed + last)
    train_s = time.perf_counter() - t1
    x_obs = observed_data(store)["x"]
    refit = None
    if estimator is None and estimator_options is None:  # does the re-trained estimator reproduce the run?
        q_run, q_new = round_posterior(store, last, cfg), est.posterior_at(x_obs[fr])
        refit = float(np.abs(q_run.mean() - q_new.mean()).max())
        if refit > 1e-3:
            msg(f"the estimator trained now differs from the run's final one (posterior means {refit:.3g} apart in "
                f"unit coordinates): the run was fitted with another softsbi version or other estimator defaults; "
                f"the calibration describes the estimator as trained now")
    u_test, x_test = data["u"][ok], data["x"][ok]
    st = calibration_stats(est, u_test, x_test[:, fr], space.names, n_draws, n_bins, cfg.seed)
    n, n_nomass, ver, tarp = st["n"], st["n_no_mass_in_box"], st["ver"], st["tarp"]
    vc = ver["coverage"]
    out = {
        "run": str(run_dir), "estimator": name, "estimator_options": opts,
        "n_test": int(n), "n_test_failed": int((~ok).sum()), "n_no_mass_in_box": int(n_nomass),
        "n_train": int(len(U)), "n_draws": int(n_draws), "rounds": int(last + 1),
        "test_proposal": "the run's proposals weighted by their usable simulations: " + ", ".join(
            f"{p} ({c})" for p, c in zip([p[1] for p in _proposals(store, cfg, space, last, counts)], counts)),
        "coordinates": "unit cube of the inferred parameters (log scale for log-scaled ones)",
        "parameters": space.names,
        "coverage": coverage_json(st),
        "verdict_50": vc["at_50"]["verdict"], "verdict_90": vc["at_90"]["verdict"], "verdict": ver["verdict"],
        "calibrated": ver["calibrated"], "alpha": ver["alpha"],
        "too_narrow": ver["too_narrow"], "too_wide": ver["too_wide"], "biased": ver["biased"],
        "diagnostics": {"coverage": {k: vc[k] for k in ("rejects", "direction", "outside", "confidence")},
                        "tarp": ver["tarp"], "sbc": ver["sbc"]},
        "sbc": rank_histograms_json(st, n_bins),
        "tarp": tarp,
        "train_seconds": train_s, "simulation_seconds": sim_s,
        "estimator_fit": {k: v for k, v in dict(getattr(est, "fit_info", {}) or {}).items()
                          if k in ("epochs", "best_epoch", "val_loss", "ensemble", "recalibration")},
        "refit_max_mean_difference": refit,
    }
    result = CalibrationResult.from_json(out, run_dir / "calibration.json")
    if write:
        with run_lock(run_dir, **_LOCK):
            write_json_atomic(run_dir / "calibration.json", result.to_json())
            plot_calibration(run_dir / "calibration.png", result)
    return result


def coverage_json(st: Mapping[str, Any]) -> dict[str, Any]:
    """The expected coverage of :func:`calibration_stats`' result ``st`` in the JSON form of
    :class:`~softsbi.core.results.fitreport.Coverage` (``calibration.json``'s and a stored task's training report's)."""
    levels, cov, lo, hi, at, vc = st["levels"], st["cov"], st["lo"], st["hi"], st["at"], st["ver"]["coverage"]
    return {"levels": levels.tolist(), "hpd": cov.tolist(), "band_lo": lo.tolist(), "band_hi": hi.tolist(),
            "band_confidence": 0.95, "at_50": at[0.5], "at_90": at[0.9],
            # the verdict judges the whole curve with the simultaneous band (Bonferroni over the levels)
            "band_simultaneous_lo": vc["band_lo"], "band_simultaneous_hi": vc["band_hi"],
            "band_simultaneous_confidence": vc["confidence"],
            "outside_pointwise": [float(levels[i]) for i in cal.curve_outside(cov, lo, hi)],
            "inside_simultaneous": not vc["rejects"],
            "band_50": vc["at_50"]["band"], "band_90": vc["at_90"]["band"]}


def rank_histograms_json(st: Mapping[str, Any], n_bins: int) -> dict[str, Any]:
    """The SBC rank histograms of :func:`calibration_stats`' result ``st`` (``n_bins`` bins) in the JSON form of
    :class:`~softsbi.core.results.fitreport.RankHistograms`."""
    sbc = st["ver"]["sbc"]
    return {"n_bins": n_bins, "histograms": st["hist"], "band": sbc["band"], "band_level": sbc["level"],
            "shapes": [p["shapes"] for p in sbc["parameters"]], "rejects": [p["rejects"] for p in sbc["parameters"]],
            **st["tests"]}


def calibration_stats(est: Any, u_test: np.ndarray, x_test: np.ndarray, names: list[str], n_draws: int, n_bins: int,
                      seed: int) -> dict[str, Any]:
    """Expected coverage, SBC ranks and TARP of a trained estimator on test pairs (Talts et al. 2018; Hermans et
    al. 2022; Lemos et al. 2023), and the one verdict over them (:func:`softsbi.inference.calibration.verdict`).

    Args:
        est: a fitted estimator (``posterior_at``, or ``posteriors_at`` for a batch).
        u_test: ``(n, D)`` test parameters (unit cube) drawn from the distribution the estimator was trained on.
        x_test: ``(n, ...)`` their observations, at the frames the estimator was trained on.
        names: the ``D`` parameters' names. n_draws: posterior draws per test pair. n_bins: rank-histogram bins.
        seed: of the draws.

    Returns:
        ``{"n", "n_no_mass_in_box", "levels", "cov" (expected HPD coverage per level), "lo"/"hi" (pointwise 95%
        band), "at" ({0.5, 0.9}: coverage), "ranks" (n, D), "tests" (rank tests), "hist" (per-parameter rank
        histograms), "tarp", "ver" (the verdict), "draws" (m, n_draws, D): the draws of the m test pairs whose posterior
        has mass in the box}``; a test pair whose posterior has no mass in the prior box
        covers nothing (HPD level 1).

    Raises:
        PosteriorError: no posterior of any test pair has mass in the prior box.
    """
    qs = cal.posteriors_at(est, x_test)
    rng = np.random.default_rng([seed, 16016, 1])
    draws, lq_true, lq_draws, keep = [], [], [], []
    for i, q in enumerate(qs):
        try:
            s = cal.draws_in_box(q, n_draws, rng)
        except PosteriorError:  # no mass in the box: the truth lies outside every region
            continue
        keep.append(i)
        draws.append(s)
        lq_draws.append(q.log_prob(s))
        lq_true.append(float(q.log_prob(u_test[i][None])[0]))
    n_nomass = len(qs) - len(keep)
    if not keep:
        raise PosteriorError(f"the estimator's posterior has (almost) no mass in the prior box at any of the {len(qs)} "
                             f"test simulations; it cannot be calibrated (too few training simulations?)")
    draws_a = np.stack(draws)
    hpd = cal.hpd_levels(np.array(lq_true), np.array(lq_draws).reshape(len(keep), n_draws))
    hpd = np.concatenate([hpd, np.ones(n_nomass)])  # a posterior with no mass in the box covers nothing
    n, levels = len(hpd), cal.LEVELS
    cov = cal.expected_coverage(hpd, levels)
    lo, hi = cal.coverage_band(n, levels)
    ranks = cal.sbc_ranks(u_test[keep], draws_a)
    tarp = cal.tarp_coverage(u_test[keep], draws_a, np.random.default_rng([seed, 16016, 2]), levels)
    return {"n": n, "n_no_mass_in_box": n_nomass, "levels": levels, "cov": cov, "lo": lo, "hi": hi,
            "at": {g: float(cal.expected_coverage(hpd, [g])[0]) for g in (0.5, 0.9)}, "ranks": ranks,
            "tests": cal.rank_tests(ranks, n_draws, n_bins),
            "hist": [np.histogram(ranks[:, d], bins=n_bins, range=(0, n_draws + 1))[0].tolist()
                     for d in range(len(names))],
            "tarp": tarp, "ver": cal.verdict(cov, n, tarp, ranks, n_draws, n_bins, names, levels),
            "draws": draws_a}


def trained_task_line(info: Mapping[str, Any], sim_bank: str) -> str | None:
    """The sentence that gives the training report of the stored task that served a run's first round (``info``:
    the round's stored training info; ``sim_bank`` the run's setting), or None when no trained task served it."""
    if not served_by_task(info):
        return None
    store = task_store_of(sim_bank)
    task = None if store is None else store.get(str(info["task"]))
    if task is None or task.report is None:
        return None
    r = task.report
    return (f"round 1's posterior is stored task {task.digest[:12]}'s, measured when it was trained on "
            f"{r.n_test} held-out prior simulations: coverage {r.coverage.at_50:.2f} at 50%, "
            f"{r.coverage.at_90:.2f} at 90%; {r.verdict} (`softsbi task show {task.digest[:12]}`)")
