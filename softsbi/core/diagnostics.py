"""Model-error workflow: posterior predictive checks and missing-effect screening.

* :func:`check_run` - posterior predictive check (Gelman et al., *Bayesian Data Analysis*,
  ch. 6): rollouts at posterior samples against the measurement; Chamfer error per frame,
  per region of the object and per phase of the motion; a misspecification test (is the
  measurement's summary vector inside the distribution of posterior-predictive summaries?)
  with a simulation-based p-value.
* :func:`diagnose_run` - rank candidate effects by how much of the residual each explains.
  A linearised score / added-variable test: with summaries ``s``, the residual
  ``r = s_obs - s(theta_hat)`` is regressed on the sensitivities of the nominal parameters
  ``J_theta`` and of the effect ``J_E`` (finite differences at the posterior median, one
  simulation per direction; the engines are deterministic). The statistic is the drop of
  the weighted residual sum of squares when ``J_E`` joins ``J_theta`` (effect parameters
  kept inside their prior range); its null distribution comes from posterior-predictive
  simulations of the nominal model treated as if they were the measurement (a Gamma fit of
  that null gives the p-value). Candidates are ranked, and selected forward, by that p-value,
  since raw residual drops are not comparable across effects with different parameters. Top
  candidates are then confirmed by a short refit with the effect switched on.

Summaries are per-frame statistics of the point cloud (centroid, spread, height quantiles,
horizontal extent), which both simulated surfaces and real partial clouds have.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from scipy import stats
from scipy.optimize import lsq_linear
from scipy.spatial import cKDTree

from .errors import SoftsbiError
from .types import STATUS_OK, ParamSpace, Scenario

#: names of the per-frame summary statistics
FEATURE_NAMES = ("mean_x", "mean_y", "mean_z", "std_x", "std_y", "std_z", "z_q10", "z_q50", "z_q90",
                 "x_q05", "x_q95", "y_q05", "y_q95")
#: floor of a summary's standard deviation (m): sensor resolution, keeps weights finite
FEATURE_FLOOR = 0.003


def cloud_features(points: np.ndarray) -> np.ndarray:
    """Summary statistics ``(13,)`` (m) of one point set ``(P, 3)``; see :data:`FEATURE_NAMES`."""
    p = np.asarray(points, float)
    q = np.quantile(p, [0.05, 0.95], axis=0)
    return np.concatenate([p.mean(0), p.std(0), np.quantile(p[:, 2], [0.1, 0.5, 0.9]),
                           [q[0, 0], q[1, 0], q[0, 1], q[1, 1]]])


def trajectory_features(clouds: Sequence[np.ndarray]) -> np.ndarray:
    """``(T * 13,)`` summaries of a sequence of point sets."""
    return np.concatenate([cloud_features(c) for c in clouds])


def sampled_points(vertices: np.ndarray, faces: np.ndarray, n: int, seed: int) -> np.ndarray:
    """``(T, n, 3)`` area-weighted surface samples, drawn exactly like the measurement's dense
    clouds so that summaries compare like with like (the same ``seed`` gives common random
    numbers across finite-difference simulations of the same mesh)."""
    from ..perception.pointcloud import sample_surface
    out = []
    for t, v in enumerate(vertices):
        out.append(sample_surface(v, faces, n, np.random.default_rng([seed, t])))
    return np.stack(out)


def surface_points(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Deterministic surface points ``(T, N + F, 3)``: vertices and face centroids."""
    if len(faces) == 0:
        return vertices
    return np.concatenate([vertices, vertices[:, faces].mean(2)], axis=1)


# ----------------------------------------------------------------------------------------
# simulation jobs returning vertices


@dataclass
class RolloutContext:
    """What a worker needs to rebuild the simulator and scenario of a run (picklable)."""
    backend: str
    backend_options: dict[str, Any]
    scenario: dict[str, Any]


_CACHE: dict[str, Any] = {}


def rollout_job(ctx: RolloutContext, item: tuple[dict[str, float], tuple[str, ...], int]) -> dict[str, Any]:
    """Simulate ``(values, effects, seed)``; return status, vertices ``(T, N, 3)``, faces, gripper."""
    from ..plugins import registry
    key = json.dumps([ctx.backend, ctx.backend_options, ctx.scenario], sort_keys=True, default=str)
    if key not in _CACHE:
        _CACHE.clear()
        _CACHE[key] = (registry().simulator(ctx.backend)(**ctx.backend_options), Scenario.from_json(ctx.scenario))
    sim, sc = _CACHE[key]
    values, effects, seed = item
    ro = sim.simulate(sc, values, effects=list(effects), seed=int(seed))
    return {"status": int(ro.status), "reason": ro.reason, "vertices": ro.vertices, "faces": ro.faces,
            "gripper": ro.gripper}


def _run_jobs(ctx: Any, items: list, workers: int | None, executor: str = "local", job: Any = None) -> list[dict]:
    """Run ``job`` (default :func:`rollout_job`) over ``items``; results in item order. A worker's
    SoftsbiError (e.g. an environment fault) is raised; other exceptions become failed results."""
    from ..plugins import registry
    exe = registry().executor(executor)(workers=workers)
    out: list[dict | None] = [None] * len(items)
    try:
        for i, res in exe.map_unordered(job or rollout_job, items, context=ctx):
            if isinstance(res, BaseException):
                if isinstance(res, SoftsbiError):
                    raise res
                res = {"status": 3, "reason": f"{type(res).__name__}: {res}", "vertices": None}
            out[i] = res
    finally:
        exe.close()
    return out  # type: ignore[return-value]


# ----------------------------------------------------------------------------------------
# loading a run


@dataclass
class RunView:
    """What the diagnostics need from a finished run."""

    path: Path
    config: dict[str, Any]
    space: ParamSpace
    scenario: Scenario
    dense: np.ndarray
    x_obs: np.ndarray
    report: dict[str, Any]
    post_theta: np.ndarray  # (S, D) posterior samples (inferred params), physical units
    post_seeds: np.ndarray | None = None  # (S,) their simulation seeds in the fit's evaluation

    def sim_context(self, keep_rollout: bool = True) -> Any:
        """The fit's own worker context (:class:`~softsbi.core.loop.SimContext`): same simulator,
        observer and metric, so re-simulating the fit's evaluation samples reproduces its Chamfer."""
        from .loop import SimContext
        c = self.config
        return SimContext(backend=c["backend"], backend_options=dict(c.get("backend_options") or {}),
                          scenario=c["scenario"], effects=list(self.effects), observer=c["observer"],
                          observer_options=dict(c.get("observer_options") or {}), param_names=self.space.names,
                          fixed=self.fixed, dense=self.dense, n_dense=int(c.get("n_dense", 600)),
                          keep_rollout=keep_rollout)

    @property
    def fixed(self) -> dict[str, float]:
        """Parameters held fixed in the fit ``{name: value}``."""
        return dict(self.config.get("fixed") or {})

    @property
    def effects(self) -> list[str]:
        """Effects the fit switched on."""
        return list(self.config.get("effects") or [])

    def values(self, row: np.ndarray) -> dict[str, float]:
        """Inferred parameters ``(D,)`` plus the fixed ones as a ``{name: value}`` mapping."""
        v = self.space.as_dict(row)
        v.update(self.fixed)
        return v

    def median(self) -> dict[str, float]:
        """Posterior median (physical units) plus the fixed parameters."""
        v = {k: float(x) for k, x in self.report["posterior_median"].items()}
        v.update(self.fixed)
        return v

    def context(self) -> RolloutContext:
        """The :class:`RolloutContext` of this run."""
        return RolloutContext(self.config["backend"], dict(self.config.get("backend_options") or {}),
                              self.config["scenario"])


def load_run(run_dir: str | Path, n_samples: int = 30, seed: int = 0) -> RunView:
    """Open a finished fit (``run.zarr`` + ``report.json``) for checking.

    Raises:
        SchemaError: not a run; SoftsbiError: the fit has not finished (no report.json).
    """
    from .store import RunStore
    run_dir = Path(run_dir)
    store = RunStore.open(run_dir / "run.zarr")
    rep_path = run_dir / "report.json"
    if not rep_path.exists():
        raise SoftsbiError(f"'{run_dir}' has no report.json: the fit has not finished; resume it with the same "
                           f"`softsbi fit ... --out {run_dir}` command first")
    report = json.loads(rep_path.read_text())
    cfg = store.config
    if cfg.get("metric") == "mask_chamfer_px" or "dense" not in store.read_observed():
        raise SoftsbiError(f"'{run_dir}' is an image fit (observer '{cfg.get('observer')}'): check, diagnose and "
                           f"compare work on point-cloud fits, which carry 3-D clouds to localise the error; "
                           f"its report.json holds the mask Chamfer of prior and posterior rollouts")
    space = ParamSpace.from_json(cfg["param_space"])
    obs = store.read_observed()
    if store.has("evaluation"):
        from .loop import evaluation_seeds
        ev, ev_attrs = store.read_group("evaluation")
        theta = ev["theta"][:n_samples]
        seeds = evaluation_seeds(int(cfg.get("seed", 0)), int(ev_attrs.get("rounds", cfg["rounds"])),
                                 len(ev["theta"]))[:n_samples]
    else:  # fall back on the last round's draws (samples of the previous posterior)
        last = store.round_ids()[-1]
        d = store.round_data(last)
        theta, seeds = d["theta"][:n_samples], d["seed"][:n_samples]
    return RunView(run_dir, cfg, space, Scenario.from_json(cfg["scenario"]), obs["dense"], obs["x"], report, theta,
                   np.asarray(seeds))


# ----------------------------------------------------------------------------------------
# per-region errors


def material_regions(vertices0: np.ndarray, grasp: np.ndarray, n_side: int = 3) -> tuple[np.ndarray, list[str]]:
    """Partition the object into ``n_side x n_side`` regions in its rest configuration.

    Args:
        vertices0: ``(N, 3)`` vertex positions at frame 0 (material coordinates).
        grasp: ``(3,)`` gripper position at frame 0.

    Returns:
        ``labels (N,)`` int region of each vertex, and region names ordered by the distance of
        the region's centre from the grasp point ("R1 at the grasp" ... "R9 farthest").
    """
    v = vertices0 - vertices0.mean(0)
    _, _, vt = np.linalg.svd(v, full_matrices=False)
    uv = v @ vt[:2].T
    bins = []
    for k in range(2):
        edges = np.quantile(uv[:, k], np.linspace(0, 1, n_side + 1)[1:-1])
        bins.append(np.searchsorted(edges, uv[:, k], side="right"))
    raw = bins[0] * n_side + bins[1]
    centres = np.array([vertices0[raw == r].mean(0) if (raw == r).any() else np.full(3, np.inf)
                        for r in range(n_side * n_side)])
    order = np.argsort(np.linalg.norm(centres - grasp, axis=1))
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    labels = rank[raw]
    names = []
    for r in range(n_side * n_side):
        tag = " (at the grasp)" if r == 0 else (" (farthest from the grasp)" if r == n_side * n_side - 1 else "")
        names.append(f"R{r + 1}{tag}")
    return labels, names


def region_errors(vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray, dense: np.ndarray,
                  n_regions: int | None = None) -> np.ndarray:
    """Bidirectional nearest-neighbour error ``(T, R)`` (m) per frame and region.

    Simulated points of a region (its vertices and the centroids of faces whose first vertex
    is in it) contribute their distance to the nearest measured point; measured points are
    assigned to the region of their nearest simulated point and contribute that distance.
    """
    R = n_regions or int(labels.max()) + 1
    pts = surface_points(vertices, faces)
    lab = labels if len(faces) == 0 else np.concatenate([labels, labels[faces[:, 0]]])
    out = np.full((len(vertices), R), np.nan)
    for t in range(len(vertices)):
        d_sr, _ = cKDTree(dense[t]).query(pts[t])
        d_rs, idx = cKDTree(pts[t]).query(dense[t])
        lr = lab[idx]
        for r in range(R):
            parts = [d_sr[lab == r].mean()] if (lab == r).any() else []
            if (lr == r).any():
                parts.append(d_rs[lr == r].mean())
            out[t, r] = np.mean(parts) if parts else np.nan
    return out


def motion_phases(scenario: Scenario) -> list[dict[str, Any]]:
    """Split the frames into three phases of equal duration, with the gripper's height."""
    T = scenario.n_frames
    cuts = np.linspace(0, T, 4).round().astype(int)
    names = ("early", "middle", "late")
    out = []
    for k in range(3):
        idx = list(range(cuts[k], cuts[k + 1]))
        if not idx:
            continue
        h = scenario.gripper[idx, 2] - scenario.table_z
        out.append({"phase": names[k], "frames": [idx[0], idx[-1]],
                    "t_s": [float(scenario.times[idx[0]]), float(scenario.times[idx[-1]])],
                    "gripper_height_m": [float(h.min()), float(h.max())]})
    return out


# ----------------------------------------------------------------------------------------
# check


def misspecification_test(f_obs: np.ndarray, f_sims: np.ndarray) -> dict[str, float]:
    """Is ``f_obs (F,)`` inside the distribution of ``f_sims (S, F)``?

    Statistic: mean squared standardised deviation (per-summary standard deviation from the
    simulations, floored at :data:`FEATURE_FLOOR`). Null: each simulation against the others
    (leave-one-out). p-value: ``(1 + #{null >= observed}) / (S + 1)``; also a Gamma fit of
    the null for p-values below ``1 / (S + 1)``.
    """
    S = len(f_sims)
    if S < 5:
        raise SoftsbiError(f"the misspecification test needs at least 5 successful posterior rollouts (got {S})")

    def stat(f, others):
        sd = np.maximum(others.std(0), FEATURE_FLOOR)
        return float((((f - others.mean(0)) / sd) ** 2).mean())

    d_obs = stat(f_obs, f_sims)
    null = np.array([stat(f_sims[i], np.delete(f_sims, i, axis=0)) for i in range(S)])
    p_emp = (1 + (null >= d_obs).sum()) / (S + 1)
    a, loc, scale = stats.gamma.fit(null, floc=0)
    p_gamma = float(stats.gamma.sf(d_obs, a, loc=loc, scale=scale))
    return {"statistic": d_obs, "null_mean": float(null.mean()), "null_q95": float(np.quantile(null, 0.95)),
            "p_value": float(p_emp), "p_value_gamma": p_gamma, "n_simulations": S}


def check_run(run_dir: str | Path, n_samples: int = 30, workers: int | None = None, plot: bool = True,
              seed: int = 0) -> dict[str, Any]:
    """Posterior predictive check of a finished fit; writes ``check.json`` and ``check.png``.

    Returns:
        dict with ``chamfer_per_frame_m`` (mean and 5/95% band over posterior rollouts),
        ``region_error_m`` (T x R mean), ``regions``, ``phases`` (mean error per phase),
        ``worst_frames``, ``worst_regions``, ``misspecification`` and a ``summary`` sentence.
    """
    t0 = time.perf_counter()
    run = load_run(run_dir, n_samples, seed)
    from .loop import simulate_job
    # the fit's own job, samples and seeds: the per-frame Chamfer is the fit's metric, so the mean
    # equals report.json's chamfer_posterior_m when all of the fit's evaluation samples are used
    items = list(zip(run.post_theta, run.post_seeds))
    res = _run_jobs(run.sim_context(keep_rollout=True), items, workers, job=simulate_job)
    ok = [r for r in res if r["status"] == STATUS_OK and r.get("vertices") is not None]
    if len(ok) < 5:
        raise SoftsbiError(f"only {len(ok)} of {len(res)} posterior rollouts succeeded; cannot check the fit")
    dense = run.dense
    T = len(dense)
    ch = np.array([r["chamfer"] for r in ok])
    labels, names = material_regions(ok[0]["vertices"][0], run.scenario.gripper[0])
    reg = np.zeros((len(ok), T, len(names)))
    f_sims = []
    for k, r in enumerate(ok):
        reg[k] = region_errors(r["vertices"], r["faces"], labels, dense, len(names))
        f_sims.append(trajectory_features(sampled_points(r["vertices"], r["faces"], dense.shape[1], 1000 + k)))
    f_obs = trajectory_features(dense)
    mis = misspecification_test(f_obs, np.array(f_sims))
    import warnings
    warnings.filterwarnings("ignore", "Mean of empty slice", RuntimeWarning)  # regions a small mesh lacks
    reg_mean = np.nanmean(reg, axis=0)
    phases = motion_phases(run.scenario)
    mean_t = ch.mean(0)
    for ph in phases:
        a, b = ph["frames"]
        ph["chamfer_m"] = float(mean_t[a:b + 1].mean())
        ph["worst_region"] = names[int(np.nanargmax(np.nanmean(reg_mean[a:b + 1], axis=0)))]
    worst_frames = [int(i) for i in np.argsort(mean_t)[::-1][:3]]
    reg_avg = np.nanmean(reg_mean, axis=0)
    worst_regions = [names[int(i)] for i in np.argsort(reg_avg)[::-1][:2]]
    worst_phase = max(phases, key=lambda p: p["chamfer_m"])
    verdict = ("the measurement is NOT explained by the model (p = {:.3g})" if mis["p_value_gamma"] < 0.01
               else "no evidence of misspecification (p = {:.3g})").format(mis["p_value_gamma"])
    summary = (f"Posterior rollouts miss the measurement by {mean_t.mean() * 100:.2f} cm on average (Chamfer); "
               f"worst in the {worst_phase['phase']} phase (t {worst_phase['t_s'][0]:.2f}-"
               f"{worst_phase['t_s'][1]:.2f} s, {worst_phase['chamfer_m'] * 100:.2f} cm) and in region "
               f"{worst_regions[0]}; {verdict}.")
    out = {"run": str(run.path), "n_rollouts": len(ok), "failed_rollouts": len(res) - len(ok),
           "times_s": run.scenario.times.tolist(),
           "chamfer_per_frame_m": {"mean": mean_t.tolist(), "q05": np.quantile(ch, 0.05, 0).tolist(),
                                   "q95": np.quantile(ch, 0.95, 0).tolist()},
           "chamfer_mean_m": float(mean_t.mean()),
           "regions": names, "region_error_m": np.nan_to_num(reg_mean).tolist(),
           "region_mean_m": dict(zip(names, np.nan_to_num(reg_avg).tolist())),
           "phases": phases, "worst_frames": worst_frames, "worst_regions": worst_regions,
           "misspecification": mis, "summary": summary, "seconds": time.perf_counter() - t0}
    run_dir = Path(run_dir)
    (run_dir / "check.json").write_text(json.dumps(out, indent=2))
    if plot:
        from ..report import plot_check
        plot_check(run_dir / "check.png", out, ch)
    return out


# ----------------------------------------------------------------------------------------
# diagnose


def _candidate_effects(run: RunView, names: Sequence[str] | None) -> list[Any]:
    from ..plugins import registry
    reg = registry()
    sim_cls = reg.simulator(run.config["backend"])
    if names:
        cands = [reg.effect(n) for n in names]
        bad = [c.name for c in cands if c.name not in sim_cls.effects]
        if bad:
            raise SoftsbiError(f"backend '{sim_cls.name}' cannot apply {bad}; it supports {list(sim_cls.effects)}")
    else:
        cands = [reg.effect(n) for n in sim_cls.effects if n in reg.tables["effect"]]
    return [c() for c in cands if c.name not in run.effects]


def diagnose_run(run_dir: str | Path, effects: Sequence[str] | None = None, n_null: int = 30,
                 unit_step: float = 0.05, effect_step: float = 0.25, alpha: float = 0.01,
                 workers: int | None = None, confirm: int = 2, confirm_budget: dict[str, int] | None = None,
                 seed: int = 0) -> dict[str, Any]:
    """Rank installed effects by how much of the residual each explains; writes ``diagnosis.json``.

    Args:
        run_dir: a finished fit of the nominal model.
        effects: candidate effect names (default: every installed effect the backend supports
            and the run does not already include).
        n_null: posterior-predictive simulations forming the null distribution.
        unit_step: finite-difference step of the nominal parameters (unit-cube units).
        effect_step: finite-difference step of each effect parameter (fraction of its range).
        alpha: family-wise significance level (Bonferroni over candidates).
        confirm: refit the top ``confirm`` candidates (:func:`candidates_to_confirm`) with the
            effect switched on (0 = no refit), report the change in posterior-predictive Chamfer
            and select the effect whose refit lowers it most (:func:`confirm_candidates`).
        confirm_budget: ``{"rounds": r, "sims_per_round": n}`` of the confirmation refits
            (default: the run's own).

    Returns:
        dict with ``ranking`` (effect, explained_fraction, statistic, p_value, log10_p, estimate,
        ...; ordered by evidence, i.e. by the p-value against each effect's own null),
        ``significant`` (names, forward selection), ``confirmed`` (refit results, best first),
        ``selected`` (the effect to add: the best confirmed one, else the first significant one,
        else None), ``final_ranking`` (effect names: refitted ones by error drop, then the
        screening's order) and ``summary`` (plain language).
    """
    t0 = time.perf_counter()
    run = load_run(run_dir, n_null, seed)
    cands = _candidate_effects(run, effects)
    if not cands:
        raise SoftsbiError("no candidate effects: install effect plugins or name them with --effect")
    base = run.median()
    space = run.space
    u_hat = np.clip(space.to_unit(space.as_array({k: base[k] for k in space.names})), 0, 1)
    jobs: list[tuple[dict, tuple, int]] = [(dict(base), tuple(run.effects), 0)]
    for j in range(space.dim):
        s = unit_step if u_hat[j] + unit_step <= 1 else -unit_step
        u = u_hat.copy()
        u[j] += s
        v = dict(base)
        v.update(space.as_dict(space.from_unit(u)))
        jobs.append((v, tuple(run.effects), 0))
    eff_cols: list[tuple[Any, str, int, int]] = []  # (effect, param, job index with, job index nominal)
    for eff in cands:
        es = eff.param_space()
        nom = eff.nominal()
        v0 = dict(base)
        v0.update(nom)
        jobs.append((v0, tuple(run.effects) + (eff.name,), 0))
        i_nom = len(jobs) - 1
        for p in es:
            u0 = es.subset([p.name]).to_unit(np.array([nom[p.name]]))[0]
            s = effect_step if u0 + effect_step <= 1 else -effect_step
            v = dict(v0)
            v[p.name] = float(es.subset([p.name]).from_unit(np.array([u0 + s]))[0])
            jobs.append((v, tuple(run.effects) + (eff.name,), 0))
            eff_cols.append((eff, p.name, len(jobs) - 1, i_nom))
    n_fd = len(jobs)
    for i, th in enumerate(run.post_theta):
        jobs.append((run.values(th), tuple(run.effects), 2000 + i))
    res = _run_jobs(run.context(), jobs, workers)
    n_pts = run.dense.shape[1]
    # finite-difference simulations share one sampling seed (common random numbers); the null
    # simulations each get their own, like the measurement
    feats = [trajectory_features(sampled_points(r["vertices"], r["faces"], n_pts, 0 if i < n_fd else 5000 + i))
             if r["status"] == STATUS_OK else None for i, r in enumerate(res)]
    if feats[0] is None:
        raise SoftsbiError(f"the simulation at the posterior median failed: {res[0]['reason']}")
    f0 = feats[0]
    null_f = np.array([f for f in feats[n_fd:] if f is not None])
    if len(null_f) < 5:
        raise SoftsbiError("too few successful posterior-predictive simulations for the null distribution")
    sd = np.maximum(null_f.std(0), FEATURE_FLOOR)
    J_theta = np.stack([(feats[1 + j] - f0) / sd if feats[1 + j] is not None else np.zeros_like(f0)
                        for j in range(space.dim)], 1)
    r_obs = (trajectory_features(run.dense) - f0) / sd
    r_null = (null_f - f0) / sd

    # design of each candidate: offset (effect switched on at its nominal value, e.g. wind at
    # 0 m/s still adds air), sensitivity columns and the coefficient bounds that keep the
    # effect parameters inside their prior range
    design: dict[str, dict[str, Any]] = {}
    failed: list[dict[str, Any]] = []
    for eff in cands:
        cols = [c for c in eff_cols if c[0] is eff]
        if any(feats[c[2]] is None or feats[c[3]] is None for c in cols) or feats[cols[0][3]] is None:
            failed.append({"effect": eff.name, "error": "a sensitivity simulation failed"})
            continue
        es = eff.param_space()
        lo, hi, steps = [], [], []
        for c in cols:
            ps1 = es.subset([c[1]])
            u0 = ps1.to_unit(np.array([eff.nominal()[c[1]]]))[0]
            step = effect_step if u0 + effect_step <= 1 else -effect_step
            lo.append(min(-u0 / step, (1 - u0) / step))
            hi.append(max(-u0 / step, (1 - u0) / step))
            steps.append((c[1], u0, step))
        design[eff.name] = {"effect": eff, "J": np.stack([(feats[c[2]] - feats[c[3]]) / sd for c in cols], 1),
                            "offset": (feats[cols[0][3]] - f0) / sd, "lo": np.array(lo), "hi": np.array(hi),
                            "steps": steps}

    def sse(r: np.ndarray, names: Sequence[str]) -> tuple[float, np.ndarray]:
        """Weighted residual sum of squares of the best linearised fit with effects ``names``."""
        big = 1e3
        rr = r - sum((design[n]["offset"] for n in names), np.zeros_like(r))
        A = np.concatenate([J_theta] + [design[n]["J"] for n in names], 1)
        lb = np.concatenate([np.full(J_theta.shape[1], -big)] + [design[n]["lo"] for n in names])
        ub = np.concatenate([np.full(J_theta.shape[1], big)] + [design[n]["hi"] for n in names])
        fit = lsq_linear(A, rr, bounds=(lb, ub))
        return float(((rr - A @ fit.x) ** 2).sum()), fit.x[J_theta.shape[1]:]

    def test(name: str, given: list[str]) -> dict[str, Any]:
        base_obs, _ = sse(r_obs, given)
        with_obs, coef = sse(r_obs, given + [name])
        d_obs = base_obs - with_obs
        null = np.array([sse(r, given)[0] - sse(r, given + [name])[0] for r in r_null])
        p_emp = (1 + (null >= d_obs).sum()) / (len(null) + 1)
        pos = null[null > 1e-12]
        if d_obs <= 0:
            log_p = 0.0
        elif len(pos) >= 3:
            ga, _, gscale = stats.gamma.fit(pos, floc=0)
            log_p = _gamma_logsf(d_obs, ga, gscale) + np.log(len(pos) / len(null))
        else:
            log_p = float(np.log(p_emp))
        log_p = min(0.0, log_p)
        p_g = float(np.exp(log_p))
        est = {}
        k = len(coef) - len(design[name]["steps"])
        for (pname, u0, step), cval in zip(design[name]["steps"], coef[k:]):
            ps1 = design[name]["effect"].param_space().subset([pname])
            est[pname] = float(ps1.from_unit(np.array([np.clip(u0 + cval * step, 0, 1)]))[0])
        return {"statistic": float(d_obs), "explained_fraction": float(d_obs / max(base_obs, 1e-12)),
                "null_mean": float(null.mean()), "p_value": float(p_emp), "p_value_gamma": p_g,
                "log10_p": log_p / np.log(10), "estimate": est}

    def evidence(t: dict[str, Any]) -> tuple[float, float]:
        return (t["log10_p"], -t["explained_fraction"])

    ranking = []
    for name, dsg in design.items():
        ranking.append({"effect": name, "description": dsg["effect"].description, **test(name, [])})
    # rank by evidence: each statistic is calibrated by its own null (effects differ in their number
    # of parameters and in how nonlinear they are, so raw residual drops are not comparable)
    ranking.sort(key=evidence)
    ranking += failed
    # forward selection: an effect is significant if it explains residual beyond those already chosen
    thr = alpha / max(len(design), 1)
    significant: list[str] = []
    remaining = [r["effect"] for r in ranking if "statistic" in r]
    steps_log = []
    while remaining:
        tests = {n: (test(n, significant) if significant else next(r for r in ranking if r["effect"] == n))
                 for n in remaining}
        best = min(tests, key=lambda n: evidence(tests[n]))
        t = tests[best]
        steps_log.append({"given": list(significant), "best": best, "p_value_gamma": t["p_value_gamma"],
                          "explained_fraction": t["explained_fraction"]})
        if t["p_value_gamma"] < thr and t["explained_fraction"] > 0.1:
            significant.append(best)
            remaining.remove(best)
        else:
            break
    out = {"run": str(run.path), "candidates": [c.name for c in cands], "ranking": ranking,
           "significance_threshold": thr, "significant": significant, "selection": steps_log,
           "confirmed": [], "selected": significant[0] if significant else None,
           "final_ranking": [r["effect"] for r in ranking],
           "summary": "", "simulations": len(jobs), "seconds": time.perf_counter() - t0}
    out["summary"] = _diagnosis_sentence(run, out)
    if confirm:
        confirm_candidates(run, out, confirm, confirm_budget, workers)
    (Path(run_dir) / "diagnosis.json").write_text(json.dumps(out, indent=2))
    return out


def format_p(test: dict[str, Any]) -> str:
    """A candidate's p-value for people: ``2.1e-19``, or ``1e-1234`` from ``log10_p`` where the
    float underflows to 0."""
    p = test.get("p_value_gamma", float("nan"))
    if p > 0 or not np.isfinite(test.get("log10_p", np.nan)):
        return f"{p:.2g}"
    return f"1e{int(np.floor(test['log10_p']))}"


def _gamma_logsf(x: float, a: float, scale: float) -> float:
    """``log P(X > x)`` for ``X ~ Gamma(a, scale)``, finite far in the tail.

    SciPy's ``logsf`` underflows to ``-inf`` when ``x / scale`` is in the thousands, which would
    tie every strongly significant effect; there the leading term of the asymptotic expansion of
    the upper incomplete gamma function is used (Abramowitz & Stegun 6.5.32):
    ``log Q(a, z) ~ (a - 1) log z - z - log Gamma(a) + log(1 + (a - 1) / z)``.
    """
    lsf = float(stats.gamma.logsf(x, a, scale=scale))
    return lsf if np.isfinite(lsf) else _gamma_logsf_asymptotic(x / scale, a)


def _gamma_logsf_asymptotic(z: float, a: float) -> float:
    """``log Q(a, z)`` for ``z >> a`` (A&S 6.5.32, two terms)."""
    from scipy.special import gammaln
    return float((a - 1) * np.log(z) - z - gammaln(a) + np.log1p((a - 1) / z))


def candidates_to_confirm(out: dict[str, Any], confirm: int) -> list[str]:
    """The top candidates a diagnosis refits: the forward selection's first effect, then the
    other effects that are significant on their own (``p < threshold`` and > 10 % of the
    residual), in ranking order, ``confirm`` at most.

    Near-collinear effects (air drag and extra damping in a fling are both velocity-dependent
    drags) can each explain most of the residual in the linearised screening; only a refit tells
    which one the data prefer.
    """
    names = list(out["significant"][:1])
    for r in out["ranking"]:
        if len(names) >= confirm:
            break
        if "statistic" in r and r["effect"] not in names and r["p_value_gamma"] < out["significance_threshold"] \
                and r["explained_fraction"] > 0.1:
            names.append(r["effect"])
    return names[:confirm]


def confirm_candidates(run: "RunView | str | Path", out: dict[str, Any], confirm: int,
                       budget: dict[str, int] | None = None, workers: int | None = None,
                       progress: Any = None) -> dict[str, Any]:
    """Refit the top ``confirm`` candidates of a diagnosis ``out`` (from :func:`diagnose_run`)
    and select the effect whose refit lowers the posterior-predictive Chamfer most.

    Updates ``out`` in place: ``confirmed`` (one refit result per candidate, ordered by error
    drop), ``selected`` (the effect with the largest drop, or the screening's first choice when
    no refit lowers the error) and ``summary``.

    Args:
        progress: optional ``callable(str)`` told which effect is being refitted.
    """
    view = run if isinstance(run, RunView) else load_run(run)
    for name in candidates_to_confirm(out, confirm):
        if any(c["effect"] == name for c in out["confirmed"]):
            continue
        if progress:
            progress(name)
        out["confirmed"].append(confirm_effect(view, name, budget, workers))
    out["confirmed"].sort(key=lambda c: -(c["drop"] if c.get("drop") is not None else -np.inf))
    best = out["confirmed"][0] if out["confirmed"] else None
    if best is not None and (best.get("drop") or 0) > 0:
        out["selected"] = best["effect"]
    # the diagnosis's final order: refitted candidates by their error drop, then the screening's
    done = [c["effect"] for c in out["confirmed"]]
    out["final_ranking"] = done + [r["effect"] for r in out["ranking"] if r["effect"] not in done]
    out["summary"] = _diagnosis_sentence(view, out)
    return out


def _diagnosis_sentence(run: RunView, out: dict[str, Any]) -> str:
    ranking, significant, thr = out["ranking"], out["significant"], out["significance_threshold"]
    confirmed = out.get("confirmed") or []
    if not significant:
        top = ranking[0] if ranking else None
        extra = (f" (best candidate {top['effect']} explains {top['explained_fraction'] * 100:.0f}% of the "
                 f"residual, p = {format_p(top)} > {thr:.2g})") if top and "statistic" in top else ""
        return "No missing effect detected: no candidate explains the residual beyond what the nominal model's " \
               "own posterior spread produces" + extra + "."
    chosen = out.get("selected") or significant[0]
    top = next(r for r in ranking if r["effect"] == chosen)
    est = ", ".join(f"{k} ~ {v:.3g}" for k, v in top["estimate"].items())
    s = (f"The nominal model misses the measurement; {top['effect']} ({top['description']}) explains "
         f"{top['explained_fraction'] * 100:.0f}% of the residual (p = {format_p(top)}; linearised "
         f"estimate {est}).")
    done = [c for c in confirmed if c.get("chamfer_after_m")]
    for c in done:
        if c["effect"] == chosen:
            s += (f" Refitting with it lowers the posterior-predictive Chamfer from {c['chamfer_before_m'] * 100:.2f} "
                  f"to {c['chamfer_after_m'] * 100:.2f} cm ({c['drop'] * 100:.0f}% lower)")
            others = [o for o in done if o["effect"] != chosen]
            s += ("; " + ", ".join(f"with {o['effect']} instead: {o['chamfer_after_m'] * 100:.2f} cm "
                                   f"({o['drop'] * 100:.0f}% lower)" for o in others) + ", so the data favour "
                  f"{chosen}." if others else ".")
    rest = [n for n in significant if n != chosen]
    if chosen != significant[0]:
        s += (f" (The linearised screening ranked {significant[0]} first; the refits decide between these "
              f"near-collinear candidates.)")
    elif rest:
        s += f" Also needed beyond it: {', '.join(rest)}."
    else:
        s += " No other candidate explains significantly more once it is included."
    return s


def measurement_from_run(run: RunView):
    """Rebuild the :class:`~softsbi.core.loop.Measurement` a run was fitted to."""
    from .loop import Measurement
    return Measurement(scenario=run.scenario, x=run.x_obs, dense=run.dense,
                       source=run.config.get("observed_source", ""), truth=run.config.get("truth"))


def confirm_effect(run: RunView, effect: str, budget: dict[str, int] | None = None,
                   workers: int | None = None) -> dict[str, Any]:
    """Refit ``run``'s measurement with ``effect`` added (into ``RUN/refit-<effect>``)."""
    from .loop import FitConfig, run_fit
    c = run.config
    budget = budget or {}
    cfg = FitConfig(backend=c["backend"], backend_options=c.get("backend_options") or {},
                    effects=list(run.effects) + [effect], observer=c["observer"],
                    n_points=int(c["observer_options"]["n_points"]), estimator=c["estimator"],
                    min_height=c.get("min_height"), frames=c.get("frames"),
                    estimator_options=c.get("estimator_options") or {},
                    rounds=int(budget.get("rounds", c["rounds"])),
                    sims_per_round=int(budget.get("sims_per_round", c["sims_per_round"])), seed=int(c["seed"]),
                    n_eval=int(c.get("n_eval", 30)), n_dense=int(c.get("n_dense", 600)),
                    workers=workers, fixed=run.fixed,
                    bounds={k: tuple(v) for k, v in (c.get("bounds") or {}).items()},
                    proposal=c.get("proposal", "corrected"),
                    truncation_eps=float(c.get("truncation_eps", 1e-3)))
    out = run.path / f"refit-{effect}"
    res = run_fit(out, measurement_from_run(run), cfg)
    before = run.report.get("chamfer_posterior_m")
    after = res.report.get("chamfer_posterior_m")
    return {"effect": effect, "run": str(out), "chamfer_before_m": before, "chamfer_after_m": after,
            "drop": (1 - after / before) if before and after else None,
            "posterior_mean": res.report["posterior_mean"]}


# ----------------------------------------------------------------------------------------
# compare


def compare_runs(run_a: str | Path, run_b: str | Path, out_dir: str | Path, n_samples: int = 30,
                 workers: int | None = None) -> dict[str, Any]:
    """Posterior predictive checks of two runs of the same measurement, side by side.

    Writes ``compare.png`` (Chamfer per frame, error per region) and ``compare.json``.

    Raises:
        SoftsbiError: the runs were fitted to different measurements.
    """
    a = check_run(run_a, n_samples=n_samples, workers=workers, plot=True)
    b = check_run(run_b, n_samples=n_samples, workers=workers, plot=True)
    if len(a["times_s"]) != len(b["times_s"]):
        raise SoftsbiError("the two runs have different frame counts; compare runs of the same measurement")
    ra, rb = load_run(run_a), load_run(run_b)
    if ra.config.get("observed_source") != rb.config.get("observed_source"):
        raise SoftsbiError(f"the runs were fitted to different measurements ({ra.config.get('observed_source')} vs "
                           f"{rb.config.get('observed_source')}); compare runs of the same measurement")
    rows = [{"what": "Chamfer, mean over frames", "a": a["chamfer_mean_m"], "b": b["chamfer_mean_m"]}]
    for pa, pb in zip(a["phases"], b["phases"]):
        rows.append({"what": f"{pa['phase']} phase ({pa['t_s'][0]:.2f}-{pa['t_s'][1]:.2f} s)", "a": pa["chamfer_m"],
                     "b": pb["chamfer_m"]})
    for name in a["regions"]:
        rows.append({"what": f"region {name}", "a": a["region_mean_m"][name], "b": b["region_mean_m"].get(name, np.nan)})
    for r in rows:
        r["change"] = (r["b"] - r["a"]) / r["a"] if r["a"] else 0.0
    la = _label(ra)
    lb = _label(rb)
    drop = -rows[0]["change"]
    summary = (f"{lb} vs {la}: posterior-predictive Chamfer {rows[0]['a'] * 100:.2f} -> {rows[0]['b'] * 100:.2f} cm "
               f"({drop * 100:.0f}% {'lower' if drop >= 0 else 'higher'}); misspecification p "
               f"{a['misspecification']['p_value_gamma']:.2g} -> {b['misspecification']['p_value_gamma']:.2g}.")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    png = out_dir / "compare.png"
    from ..report import plot_compare
    plot_compare(png, a, b, la, lb)
    res = {"run_a": str(run_a), "run_b": str(run_b), "label_a": la, "label_b": lb, "table": rows,
           "summary": summary, "check_a": a, "check_b": b, "png": str(png), "json": str(out_dir / "compare.json")}
    (out_dir / "compare.json").write_text(json.dumps(res, indent=2))
    return res


def _label(run: RunView) -> str:
    eff = run.effects
    return f"{run.config['backend']} + {'+'.join(eff)}" if eff else f"{run.config['backend']} (nominal)"
