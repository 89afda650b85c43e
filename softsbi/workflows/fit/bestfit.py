"""The best fit beside the posterior: the parameters of a fit that came closest to the measurement.

A posterior and a best fit answer two questions. The posterior says which parameters are plausible given
the measurement and the model's noise (a calibrated posterior's centre sits about one posterior standard
deviation from the truth); a best fit is one parameter set whose rollout is closest to the measurement,
for a user who wants to put a single set into their own simulator.

* :func:`best_stored`: the simulation with the lowest metric (the fit's headline: the mean per-frame Chamfer
  over the fit's frames, :func:`~softsbi.workflows.fit.run.chamfer_stats`) among every simulation the fit stored:
  its rounds, its posterior-predictive rollouts and its refinement.
* :func:`refine` (``fit --refine N``): N more simulations spent by CMA-ES (Hansen's ``cma`` library; Hansen &
  Ostermeier 2001) on the metric, in the unit cube of the prior, started at the posterior's mean with the
  posterior's covariance (so its first generation samples where the posterior puts its mass) and kept inside
  the prior box (``cma``'s bound handling). Stored in the run's ``refine`` group row by row as the
  simulations finish; a killed refinement resumes: CMA-ES is replayed from the stored generations (each
  generation's draws seeded, so the replay asks the stored candidates again) and only the missing
  simulations are run. Refining leaves the posterior as it was (nothing of the rounds is touched).
* :func:`store_best_fit`: the best fit's rollout (re-simulated once with its own seed, which reproduces its
  metric: :mod:`~softsbi.workflows.fit.jobs`) in the run's ``best_fit`` group, for ``clouds.png``, ``view`` and
  :func:`read_best_fit` (``softsbi.open_run(RUN).best_fit``).
"""
from __future__ import annotations

import contextlib
from dataclasses import dataclass, replace
from typing import Any, Callable, Iterator

import numpy as np

from softsbi.core.errors import SoftsbiError
from softsbi.core.store import RunStore
from softsbi.core.store.groups import holds
from softsbi.core.types import STATUS_ERROR, STATUS_OK, STATUS_PENDING, ParamSpace
from softsbi.workflows.fit.jobs import JobItem, SimContext, map_simulations, simulate_job, stored_evaluation_seeds
from softsbi.workflows.fit.config import RunRecord

__all__ = ["BestFit", "REFINE", "BEST", "best_stored", "refine", "store_best_fit", "read_best_fit", "scores"]

#: run-store groups of the refinement's simulations and of the best fit's rollout
REFINE, BEST = "refine", "best_fit"


def scores(chamfer: np.ndarray, status: np.ndarray, frames: list[int] | None) -> np.ndarray:
    """``(N,)`` the fit's headline metric of ``N`` simulations (mean of the per-frame ``chamfer (N, T)`` over
    ``frames``, None = all; as :func:`~softsbi.workflows.fit.run.chamfer_stats`), ``inf`` for a failed one."""
    chamfer = np.asarray(chamfer, float)
    chamfer = chamfer.reshape(len(status), int(np.prod(chamfer.shape[1:])) if chamfer.ndim > 1 else -1)
    fr = slice(None) if frames is None else list(frames)
    ok = (np.asarray(status) == STATUS_OK) & np.all(np.isfinite(chamfer), axis=1)
    out = np.full(len(status), np.inf)
    if ok.any():
        out[ok] = chamfer[ok][:, fr].mean(1)
    return out


def _candidates(store: RunStore, rounds: int, seed: int, n_refine: int) -> Iterator[dict[str, Any]]:
    """Every stored simulation source of a fit: its first ``rounds`` rounds, its evaluation, the first
    ``n_refine`` refinement simulations; each as ``{"source", "theta", "u", "seed", "status", "chamfer"}``."""
    for r in range(rounds):
        if not store.is_begun(r):
            continue
        d = store.round_data(r, ("theta", "u", "seed", "status", "chamfer"))
        yield {"source": f"round {r + 1}", **d}
    if store.has("evaluation"):
        ev, attrs = store.read_group("evaluation")
        yield {"source": "posterior predictive rollout", "theta": ev["theta"], "u": ev["u"], "status": ev["status"],
               "chamfer": ev["chamfer"],
               "seed": stored_evaluation_seeds(seed, attrs, rounds, len(ev["theta"]))}
    if n_refine > 0 and store.has(REFINE):
        rf, _ = store.read_rows(REFINE)
        yield {"source": "refinement (CMA-ES)", **{k: rf[k][:n_refine] for k in
                                                   ("theta", "u", "seed", "status", "chamfer")}}


def best_stored(store: RunStore, rounds: int, seed: int, frames: list[int] | None,
                n_refine: int = 0) -> dict[str, Any] | None:
    """The stored simulation with the lowest metric (:func:`scores`) among the fit's rounds, its evaluation
    and its first ``n_refine`` refinement simulations (module docstring).

    Returns:
        ``{"source", "index", "theta" (D,) physical, "u" (D,), "seed", "score", "chamfer" (T,), "simulations"}``
        (``simulations``: how many were searched), or None when no simulation has a finite metric.
    """
    best, n = None, 0
    for c in _candidates(store, rounds, seed, n_refine):
        sc = scores(c["chamfer"], c["status"], frames)
        n += len(sc)
        i = int(np.argmin(sc)) if len(sc) else 0
        if len(sc) and np.isfinite(sc[i]) and (best is None or sc[i] < best["score"]):
            best = {"source": c["source"], "index": i, "theta": np.asarray(c["theta"][i], float),
                    "u": np.asarray(c["u"][i], float), "seed": int(c["seed"][i]), "score": float(sc[i]),
                    "chamfer": np.asarray(c["chamfer"][i], float)}
    if best is not None:
        best["simulations"] = n
    return best


@contextlib.contextmanager
def _numpy_seed(seed: list[int]) -> Iterator[None]:
    """NumPy's global generator seeded with ``seed`` inside the block, restored after it: ``cma`` draws its
    candidates from it, so each generation's draws depend on the generation alone (the replay of a resume)."""
    state = np.random.get_state()
    try:
        np.random.seed(np.random.SeedSequence(seed).generate_state(4))
        yield
    finally:
        np.random.set_state(state)


def _strategy(mean: np.ndarray, cov: np.ndarray) -> Any:
    """A CMA-ES (``cma``) in the unit cube started at ``mean (D,)`` with covariance ``cov (D, D)``: step size
    ``sigma0 = sqrt(trace(cov) / D)``, covariance matrix ``cov / sigma0^2``, bounds ``[0, 1]``."""
    import cma  # heavy to import (seconds); only --refine needs it
    D = len(mean)
    cov = np.atleast_2d(np.asarray(cov, float))
    cov = (cov + cov.T) / 2 + 1e-12 * np.eye(D)
    sigma0 = float(np.sqrt(np.trace(cov) / D))
    x0 = np.clip(np.asarray(mean, float), 1e-6, 1 - 1e-6)
    es = cma.CMAEvolutionStrategy(x0, sigma0, {"bounds": [0, 1], "seed": np.nan, "verbose": -9})
    if hasattr(es.sm, "C"):  # the full-covariance sampler (CMA_diagonal off, the default for these dimensions)
        es.sm.C = cov / sigma0 ** 2
        es.sm.update_now(-1)
    return es


def refine(store: RunStore, space: ParamSpace, mean: np.ndarray, cov: np.ndarray, ctx: SimContext, executor: Any,
           n: int, seed: int, rounds: int, frames: list[int] | None,
           progress: Callable[[int, int], None] | None = None,
           message: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Spend ``n`` simulations on CMA-ES from the posterior (module docstring), storing each in the run's
    ``refine`` group; resumes a stored refinement of the same posterior (same ``rounds`` and start), and
    replaces one of another.

    Args:
        mean, cov: the posterior's mean ``(D,)`` and covariance ``(D, D)`` in the unit cube.
        ctx, executor: the fit's simulation context and executor.
        n: simulations (>= 1); a stored refinement with more keeps them (only the first ``n`` count).
        seed, rounds: the fit's seed and rounds (they seed the candidates and simulations).
        frames: the metric's frames (:func:`scores`).
        progress: ``progress(done, n)`` after each stored simulation. message: notices.

    Returns:
        ``{"simulations", "generations", "popsize", "stopped"}``: simulations stored (at most ``n``),
        generations, CMA-ES's population size and why it stopped (``"budget"`` or ``cma``'s termination).

    Raises:
        SoftsbiError: an environment fault in a worker (nothing stored as failed).
    """
    say = message or (lambda s: None)
    key = {"rounds": int(rounds), "seed": int(seed), "start_mean": [float(v) for v in mean],
           "start_cov": [[float(v) for v in row] for row in np.atleast_2d(cov)]}
    if store.has(REFINE):
        _, attrs = store.read_rows(REFINE)
        if not holds(attrs, key):
            say("the posterior has changed since the stored refinement: refining from the new one")
            store.remove_group(REFINE)
    rows, _ = store.read_rows(REFINE) if store.has(REFINE) else ({"generation": np.zeros(0, int)}, {})
    es = _strategy(np.asarray(key["start_mean"]), np.asarray(key["start_cov"]))
    lam = int(es.popsize)
    T = len(ctx.scenario["times"])
    total = len(rows["generation"])
    done = int((rows["status"] != STATUS_PENDING).sum()) if total else 0  # read_rows: a stored group has status
    g, stopped, warned, partial = 0, "budget", False, False
    while True:
        # the rows of generation g among the first n (a stored refinement may hold more than this one asks for)
        have = np.flatnonzero((rows["generation"] == g) & (np.arange(len(rows["generation"])) < n))
        if len(have) == 0 and total >= n:
            break
        with _numpy_seed([seed, 20_000 + rounds, 2, g]):
            xs = np.asarray(es.ask())
        if len(have) and not np.allclose(rows["u"][have], xs[:len(have)]) and not warned:
            say("the stored refinement's candidates differ from the replayed ones (another cma version?): "
                "continuing from the stored ones")
            warned = True
        add = min(lam - len(have), n - total) if len(have) < lam else 0
        if add > 0:
            u = xs[len(have):len(have) + add]
            idx = np.arange(total, total + add)
            new = {"u": u, "theta": space.from_unit(u), "generation": np.full(add, g, np.int64),
                   "seed": np.array([int(np.random.default_rng([seed, 20_000 + rounds, 1, int(i)]).integers(2**31 - 1))
                                     for i in idx], np.int64),
                   "chamfer": np.full((add, T), np.nan), "status": np.full(add, STATUS_PENDING, np.uint8)}
            store.append_rows(REFINE, new, attrs={**key, "popsize": lam,
                                                  "what": "CMA-ES refinement of the best fit, started at the "
                                                          "posterior (unit cube)"},
                              units={"theta": "physical (see param_space)", "u": "unit cube", "chamfer": "m"})
            total += add
            rows, _ = store.read_rows(REFINE)
            have = np.flatnonzero((rows["generation"] == g) & (np.arange(len(rows["generation"])) < n))
        pend = [int(i) for i in have if rows["status"][i] == STATUS_PENDING]
        if pend:
            items = [JobItem(rows["theta"][i], int(rows["seed"][i])) for i in pend]
            for j, res in map_simulations(executor, ctx, items):
                i = pend[j]
                if isinstance(res, SoftsbiError):
                    raise res
                ok = not isinstance(res, BaseException) and res.chamfer is not None
                store.write_rows(REFINE, i, {"chamfer": np.asarray(res.chamfer, float)[None] if ok else
                                             np.full((1, T), np.nan),
                                             "status": np.array([res.status if not isinstance(res, BaseException)
                                                                 else STATUS_ERROR], np.uint8)})
                done += 1
                if progress is not None:
                    progress(min(done, n), n)
            rows, _ = store.read_rows(REFINE)
        if len(have) < lam:
            partial = len(have) > 0
            break  # the budget ends inside this generation
        f = scores(rows["chamfer"][have], rows["status"][have], frames)
        with _numpy_seed([seed, 20_000 + rounds, 3, g]):
            es.tell([np.asarray(x) for x in rows["u"][have]], f.tolist())
        g += 1
        if es.stop():
            stopped = ", ".join(f"{k}={v}" for k, v in es.stop().items())
            break
    return {"simulations": int(min(total, n)), "generations": int(g + partial), "popsize": lam, "stopped": stopped}


@dataclass
class BestFit:
    """The best fit of a finished run (:func:`read_best_fit`; ``softsbi.open_run(RUN).best_fit``).

    Attributes:
        theta: the inferred parameters ``{name: value}`` in physical units (with the fit's fixed ones).
        value: the fit's metric at them: mean per-frame Chamfer over the fit's frames (m; ``unit``).
        per_frame: ``(T,)`` the metric per frame.
        source: which of the fit's simulations it is (``"round 3"``, ``"refinement (CMA-ES)"``, ...).
        seed: its simulation seed (:func:`softsbi.simulate` with it repeats the rollout).
        vertices, faces, gripper: its rollout, ``(T, N, 3)`` m, ``(F, 3)``, ``(T, 3)`` m; None when not stored.
        unit: ``"m"`` (Chamfer) or ``"px"`` (the mask Chamfer of image fits).
    """

    theta: dict[str, float]
    value: float
    per_frame: np.ndarray
    source: str
    seed: int
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None
    gripper: np.ndarray | None = None
    unit: str = "m"


def store_best_fit(store: RunStore, best: dict[str, Any], space: ParamSpace, ctx: SimContext, executor: Any,
                   fixed: dict[str, float] | None = None) -> bool:
    """Re-simulate ``best`` (:func:`best_stored`) with its seed, keeping its rollout, and write the run's
    ``best_fit`` group (theta, u, the metric per frame, vertices, faces, gripper; attributes: source, seed,
    score). Kept as is when the stored group already holds this simulation.

    Returns:
        Whether the rollout is stored (False: the re-simulation failed; the group then holds no rollout).

    Raises:
        SoftsbiError: an environment fault in the worker.
    """
    key = {"source": best["source"], "index": best["index"], "seed": best["seed"], "score": best["score"]}
    if store.has(BEST):
        arrays, attrs = store.read_group(BEST)
        if holds(attrs, key):
            return "vertices" in arrays
    res = next(iter(executor.map_unordered(simulate_job, [JobItem(best["theta"], best["seed"])],
                                           context=replace(ctx, keep_rollout=True))))[1]
    if isinstance(res, SoftsbiError):
        raise res
    arrays = {"theta": best["theta"], "u": best["u"], "chamfer": best["chamfer"]}
    ok = not isinstance(res, BaseException) and res.vertices is not None
    if ok:
        arrays.update(vertices=np.asarray(res.vertices, np.float32), gripper=np.asarray(res.gripper, float),
                      faces=np.asarray(res.faces if res.faces is not None else np.zeros((0, 3)), np.int64))
    store.write_group(BEST, arrays, attrs={**key, "names": space.names, "fixed": dict(fixed or {}),
                                           "what": "the fit's best simulation and its rollout"},
                      units={"theta": "physical (see param_space)", "u": "unit cube", "chamfer": "m",
                             "vertices": "m", "gripper": "m"})
    return ok


def read_best_fit(store: RunStore) -> BestFit | None:
    """The run's stored best fit (:func:`store_best_fit`), or None when the fit stored none."""
    if not store.has(BEST):
        return None
    arrays, attrs = store.read_group(BEST)
    theta = {n: float(v) for n, v in zip(attrs["names"], arrays["theta"])}
    theta.update({k: float(v) for k, v in attrs["fixed"].items()})  # stored with it
    unit = "px" if RunRecord.from_run_config(store.config).image_fit else "m"
    return BestFit(theta=theta, value=float(attrs["score"]), per_frame=arrays["chamfer"], source=str(attrs["source"]),
                   seed=int(attrs["seed"]), unit=unit,
                   # the rollout's arrays: absent when its re-simulation failed
                   **{k: arrays.get(k) for k in ("vertices", "faces", "gripper")})
