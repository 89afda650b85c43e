"""Study: the virtual depth sensor against real DiffCloud lift clouds: overlays and numbers.

Conclusion. The virtual depth sensor (DiffCloud's two calibrated cameras, robot mask and crop, rendered from the
simulated cloth) sees what the fits' height cut sees, give or take: 1 % vs 0 % of the surface in the early frames
(the flat cloth is below the crop on both), 50 % vs 41 % while lifting, 92 % vs 96 % hanging, where folds hide 17-20 %
of the surface on navy and polka. It costs about 2.3 ms per frame (about 20 % on top of a fit's simulations). At the
height-cut fits' posterior means its clouds are not closer to the real ones (one-sided measured -> simulated Chamfer,
mean of the ten recordings: 1.72 vs 1.84 cm lifting, 1.69 vs 1.64 cm hanging); DiffCloud's outlier filter made every
number worse, so it is off by default. Fits through the sensor (``sensor="camera"``) were better than the default
fits on one of three second repeats (navy2) and worse on two (polka2, redblack2), so ``fit`` keeps the height cut as
its default sensor model. Not done: depth noise, the arm's links, the fold recordings.

For each recording: one mujoco-flex rollout at the posterior mean of a stored ``softsbi fit`` of that
recording (``--runs DIR/<fabric>/report.json``; the prior midpoint with the recording's placement when
there is none), seen through (a) the height-cut sensor model of the fits (area-weighted surface samples,
points within ``--min-height`` of the table unseen, :func:`softsbi.perception.pointcloud.sensor_view`) and
(b) the virtual depth sensor (:class:`softsbi.perception.depth_sensor.VirtualDepthSensor`: the recording's
calibrated cameras, robot mask, DiffCloud's crop, 3500 points per frame; ``--outlier`` adds DiffCloud's
statistical outlier filter). Per phase
(early = frames 0-4, cloth on the table; mid = 10-14, lifting; hanging = 20-24):

* the fraction of the simulated surface each model sees (3000 area-weighted samples per frame);
* the bidirectional and the one-sided (measured -> simulated) Chamfer of the real cloud (as recorded:
  its own sensor already applied) to (a) and (b). A view with no point (flat cloth) is replaced by the
  highest 10 % of the surface samples (the fits' convention, :func:`sensor_indices`);
* the sensor's time per frame.

Figures ``<out>/virtual_sensor_<recording>.png``: top and side views of 4 frames, real cloud vs the
virtual sensor's cloud, plus the simulated surface the sensor does not see.

Usage::

    python -m benchmarks.studies.virtual_sensor [--recordings lift_tan,lift_navy,lift_polka2]
        [--runs FITS] [--out docs/figures] [--json runs/virtual_sensor.json]
    python -m benchmarks.studies.virtual_sensor --compare CAMERA_RUN --height-report HEIGHT_RUN/report.json

``FITS``: a folder of default fits, one per recording (e.g. the real-lift suite's ``--full --out FITS``).

The second form scores a ``sensor="camera"`` fit and a default (height-cut) fit of the same recording on
both metrics (headline frames): the camera fit's posterior predictive (its 30 evaluation rollouts,
re-simulated with their seeds) and both fits' posterior-mean rollouts.
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from softsbi.backends.mujoco_flex import MujocoFlex
from softsbi.core.metrics import chamfer_terms
from softsbi.perception.depth_sensor import DIFFCLOUD_OUTLIER, VirtualDepthSensor
from softsbi.perception.pointcloud import sample_surface, sensor_indices
from softsbi.scenarios.builtin import lift_scenario, load_recording

REPO = Path(__file__).resolve().parents[2]
DATA = REPO.parent / "shared" / "data" / "diffcloud_lift"
PHASES = {"early": range(0, 5), "mid": range(10, 15), "hanging": range(20, 25)}
FIG_FRAMES = (0, 8, 14, 24)


def theta_for(rec: Path, space, runs: Path | None) -> tuple[dict, str]:
    """Posterior mean of a stored fit of ``rec`` (``runs/<fabric>/report.json``), else the prior midpoint."""
    mid = space.midpoint()
    if runs is not None:
        rep = runs / rec.name.replace("lift_", "") / "report.json"
        if rep.is_file():
            d = json.loads(rep.read_text())
            if Path(d.get("observed", "")).name == rec.name:
                pm = {k: float(v) for k, v in d["posterior_mean"].items() if k in space.names}
                return {**mid, **pm}, f"posterior mean of {rep.parent}"
    return mid, "prior midpoint"


def with_fallback(view: np.ndarray, surface: np.ndarray) -> np.ndarray:
    """``view``, or the highest 10 % of ``surface`` when the view is empty (the fits' convention)."""
    return view if len(view) else surface[sensor_indices(surface, np.inf)]


def chamfers(real: np.ndarray, sim: np.ndarray) -> tuple[float, float]:
    sm, ms = chamfer_terms(sim, real)
    return 0.5 * (sm + ms), ms


def run_recording(rec: Path, runs: Path | None, min_height: float, out: Path | None, rng: np.random.Generator,
                  sensor_kw: dict | None = None) -> dict:
    scenario = lift_scenario(rec)
    sim = MujocoFlex()
    space = sim.param_space(scenario)
    theta, source = theta_for(rec, space, runs)
    roll = sim.simulate(scenario, theta)
    real = load_recording(rec)
    sensor = VirtualDepthSensor.for_diffcloud_recording(rec, **(sensor_kw or {}))
    min_z = scenario.table_z + min_height
    V, F, G = roll.vertices, roll.faces, roll.gripper
    rows, times, cams, surfs = [], [], [], []
    for t in range(len(V)):
        t0 = time.perf_counter()
        cam = sensor.observe(V[t], F, G[t], rng)
        times.append(time.perf_counter() - t0)
        surf = sample_surface(V[t], F, 3000, rng)
        hc = surf[surf[:, 2] > min_z]
        seen_cam = float(sensor.seen(surf, V[t], F, G[t]).mean())
        r = real[t][rng.choice(len(real[t]), 1000, replace=False)]
        bi_h, one_h = chamfers(r, with_fallback(hc, surf))
        bi_c, one_c = chamfers(r, with_fallback(cam, surf))
        rows.append({"frame": t, "seen_height": float(len(hc) / len(surf)), "seen_camera": seen_cam,
                     "n_camera_unique": int(len(np.unique(cam, axis=0))),
                     "n_real_unique": int(len(np.unique(real[t], axis=0))),
                     "bi_height": bi_h, "one_height": one_h, "bi_camera": bi_c, "one_camera": one_c})
        cams.append(cam)
        surfs.append(surf)
    phases = {}
    for name, fr in PHASES.items():
        sel = [rows[i] for i in fr]
        phases[name] = {k: float(np.mean([s[k] for s in sel])) for k in
                        ("seen_height", "seen_camera", "bi_height", "one_height", "bi_camera", "one_camera")}
        phases[name]["empty_camera_frames"] = int(sum(len(cams[i]) == 0 for i in fr))
    fig = figure(rec.name, real, cams, surfs, sensor, scenario, V, F, G, source, out) if out is not None else None
    return {"recording": rec.name, "theta": theta, "theta_source": source, "phases": phases, "frames": rows,
            "ms_per_frame": 1e3 * float(np.mean(times)), "ms_per_frame_median": 1e3 * float(np.median(times)),
            "crop": [list(sensor.crop_min), list(sensor.crop_max)], "figure": str(fig)}


def figure(name, real, cams, surfs, sensor, scenario, V, F, G, source, out: Path) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rng = np.random.default_rng(0)
    fig, axes = plt.subplots(2, len(FIG_FRAMES), figsize=(13, 7.4), dpi=80)
    sub = lambda a, n=1200: a[rng.choice(len(a), min(n, len(a)), replace=False)] if len(a) else a  # noqa: E731
    allpts = np.concatenate([real[t] for t in FIG_FRAMES] + [surfs[t] for t in FIG_FRAMES])
    lo, hi = allpts.min(0) - 0.02, allpts.max(0) + 0.02
    for j, t in enumerate(FIG_FRAMES):
        unseen = surfs[t][~sensor.seen(surfs[t], V[t], F, G[t])]
        for i, (a, b, lab) in enumerate(((0, 1, "top view (x-y)"), (1, 2, "side view (y-z)"))):
            ax = axes[i, j]
            u = sub(unseen, 600)
            ax.scatter(u[:, a], u[:, b], s=3, c="#f4a261", alpha=0.5, marker="x", lw=0.6,
                       label="simulated surface the sensor does not see")
            r = sub(real[t])
            ax.scatter(r[:, a], r[:, b], s=2, c="0.45", alpha=0.6, label="real cloud (recorded)")
            c = sub(cams[t])
            if len(c):
                ax.scatter(c[:, a], c[:, b], s=2, c="#1f5fbf", alpha=0.6, label="virtual depth sensor")
            ax.plot(G[t, a], G[t, b], "k+", ms=9, mew=1.5, label="grasp point")
            if i == 1:
                ax.axhline(sensor._lo[2] + (np.linalg.inv(sensor.scene_to_robot)[2, 3]), color="r", lw=0.8,
                           ls="--", label="crop plane (+ clearance)")
            ax.set_xlim(lo[a], hi[a])
            ax.set_ylim(lo[b], hi[b])
            ax.set_aspect("equal")
            ax.set_xlabel("xyz"[a] + " [m]")
            ax.set_ylabel("xyz"[b] + " [m]")
            ax.tick_params(labelsize=7)
            ax.set_title(f"frame {t} ({t * 0.04:.2f} s), {lab}: {len(np.unique(cams[t], axis=0))} px seen", fontsize=8)
    h, lab = [], []
    for ax in axes.ravel():
        for hh, ll in zip(*ax.get_legend_handles_labels()):
            if ll not in lab:
                h.append(hh)
                lab.append(ll)
    fig.legend(h, lab, loc="lower center", ncol=5, fontsize=8, markerscale=3, frameon=False)
    fig.suptitle(f"{name}: real cloud vs virtual depth sensor (overhead + side RealSense calibration, "
                 f"{sensor.cameras[0].width}x{sensor.cameras[0].height} px), "
                 f"mujoco-flex at the {source.split(' of ')[0]}; lift frame", fontsize=9)
    fig.tight_layout(rect=(0, 0.05, 1, 0.96), h_pad=1.6)
    out.mkdir(parents=True, exist_ok=True)
    p = out / f"virtual_sensor_{name}.png"
    fig.savefig(p)
    plt.close(fig)
    return p


def table(results: list[dict]) -> str:
    lines = ["| recording | phase | seen: height cut | seen: camera | bi Chamfer height cut [cm] | bi Chamfer camera [cm] "
             "| one-sided height cut [cm] | one-sided camera [cm] | empty camera frames |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        for ph, v in r["phases"].items():
            lines.append(f"| {r['recording']} | {ph} | {v['seen_height']:.2f} | {v['seen_camera']:.2f} | "
                         f"{100 * v['bi_height']:.2f} | {100 * v['bi_camera']:.2f} | {100 * v['one_height']:.2f} | "
                         f"{100 * v['one_camera']:.2f} | {v['empty_camera_frames']} |")
    if len(results) > 1:
        for ph in PHASES:
            v = {k: np.mean([r["phases"][ph][k] for r in results]) for k in results[0]["phases"][ph]}
            lines.append(f"| mean of {len(results)} | {ph} | {v['seen_height']:.2f} | {v['seen_camera']:.2f} | "
                         f"{100 * v['bi_height']:.2f} | {100 * v['bi_camera']:.2f} | {100 * v['one_height']:.2f} | "
                         f"{100 * v['one_camera']:.2f} | {v['empty_camera_frames']:.1f} |")
    ms = [r["ms_per_frame"] for r in results]
    lines.append(f"\nsensor time per frame (2 cameras): mean {np.mean(ms):.1f} ms "
                 f"(per recording {', '.join(f'{m:.1f}' for m in ms)})")
    return "\n".join(lines)


def compare_fits(camera_run: Path, height_report: Path) -> dict:
    """Both metrics for a camera-sensor fit and a height-cut fit of the same recording (module docstring)."""
    from dataclasses import replace

    from softsbi.workflows.fit.jobs import JobItem, run_jobs
    from softsbi.workflows.fit.runs import load_run
    view = load_run(camera_run, n_eval=30)
    ctx_cam = view.sim_context(keep_rollout=False)
    table_z = view.scenario.table_z
    ctx_h = replace(ctx_cam, camera=None, min_z=float(table_z) + 0.01)
    frames = view.metric_frames
    href = json.loads(height_report.read_text())
    cam_rep = json.loads((camera_run / "report.json").read_text())
    out = {"camera_fit": {"prior_camera": cam_rep["chamfer_prior_m"],
                          "posterior_camera": cam_rep["chamfer_posterior_m"],
                          "posterior_mean": cam_rep["posterior_mean"],
                          "contraction": {k: v["width_ratio"] for k, v in cam_rep["contraction"].items()}},
           "height_fit": {"prior_height": href["chamfer_prior_m"], "posterior_height": href["chamfer_posterior_m"],
                          "posterior_mean": href["posterior_mean"],
                          "contraction": {k: v["width_ratio"] for k, v in href["contraction"].items()}}}
    items = [JobItem(theta, int(seed)) for theta, seed in zip(view.post_theta, view.post_seeds)]
    for name, ctx in (("camera", ctx_cam), ("height", ctx_h)):
        res = [r for r in run_jobs(ctx, items, 1) if r.status == 0]
        out["camera_fit"][f"posterior_predictive_{name}"] = float(np.mean([np.mean(r.chamfer[frames]) for r in res]))
    for fit, pm in (("camera_fit", cam_rep["posterior_mean"]), ("height_fit", href["posterior_mean"])):
        theta = {k: float(v) for k, v in pm.items()}
        for name, ctx in (("camera", ctx_cam), ("height", ctx_h)):
            r = run_jobs(ctx, [JobItem(theta, 0)], 1)[0]
            out[fit][f"posterior_mean_rollout_{name}"] = float(np.mean(r.chamfer[frames]))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--recordings", default="lift_tan,lift_navy,lift_polka2")
    ap.add_argument("--runs", default="runs/real", help="folder of fits <fabric>/report.json")
    ap.add_argument("--out", default=str(REPO / "docs" / "figures"))
    ap.add_argument("--json", default="")
    ap.add_argument("--min-height", type=float, default=0.01)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--figures", default="", help="recordings to draw (default: all of --recordings)")
    ap.add_argument("--resolution", default="160x120", help="render resolution WxH, px")
    ap.add_argument("--mask-radius", type=float, default=0.03)
    ap.add_argument("--clearance", type=float, default=0.005, help="crop plane above robot z 0.075 m, m")
    ap.add_argument("--outlier", action="store_true", help="switch DiffCloud's statistical outlier filter on")
    ap.add_argument("--compare", default="", help="a sensor='camera' fit's run folder (second usage form)")
    ap.add_argument("--height-report", default="", help="report.json of the default fit of the same recording")
    a = ap.parse_args()
    if a.compare:
        print(json.dumps(compare_fits(Path(a.compare), Path(a.height_report)), indent=1))
        return
    w, h = (int(x) for x in a.resolution.split("x"))
    kw = {"resolution": (w, h), "mask_radius": a.mask_radius, "crop_clearance": a.clearance}
    if a.outlier:
        kw["outlier"] = DIFFCLOUD_OUTLIER
    draw = set(a.figures.split(",")) if a.figures else set(a.recordings.split(","))
    runs = Path(a.runs) if a.runs else None
    rng = np.random.default_rng(a.seed)
    results = []
    for name in a.recordings.split(","):
        r = run_recording(DATA / name, runs, a.min_height, Path(a.out) if name in draw else None, rng, kw)
        print(r["recording"], r["theta_source"], f"{r['ms_per_frame']:.1f} ms/frame", r["figure"], flush=True)
        results.append(r)
    print(table(results))
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
