"""PNG figures of a fit: Chamfer per round, posterior pair plot, real vs simulated clouds."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def write_fit_plots(out_dir: Path, result: Any, meas: Any, cfg: Any, samples: np.ndarray) -> list[Path]:
    """Write ``chamfer_rounds.png``, ``posterior_pairs.png`` and ``clouds.png`` into ``out_dir``.

    Args:
        result: :class:`~softsbi.core.loop.FitResult`. meas: the measurement.
        samples: ``(S, D)`` final-posterior samples, physical units.
    """
    paths = [plot_chamfer_rounds(out_dir / "chamfer_rounds.png", result.report),
             plot_pairs(out_dir / "posterior_pairs.png", result.param_space, samples, meas.truth)]
    image_fit = result.report.get("metric") == "mask_chamfer_px"
    name = "frames.png" if image_fit else "clouds.png"
    try:
        paths.append((plot_frames if image_fit else plot_clouds)(out_dir / name, result, meas, cfg))
    except Exception as exc:  # noqa: BLE001 - a failed preview must not lose the fit
        (out_dir / name.replace(".png", "_error.txt")).write_text(f"could not draw {name}: {exc}\n")
    return paths


def plot_chamfer_rounds(path: Path, report: dict[str, Any]) -> Path:
    """Mean Chamfer of rollouts at prior samples and at each round's posterior samples: 3-D
    Chamfer in cm, or for image fits the mask Chamfer in px."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 4))
    if report.get("metric") == "mask_chamfer_px":
        key, scale, unit, what = "mask_chamfer_{}_px", 1.0, "px", "HSV cloth-mask Chamfer"
    else:
        key, scale, unit, what = "chamfer_{}_m", 100.0, "cm", "bidirectional Chamfer"
    post, post_std = key.format("posterior"), key.format("posterior_std")
    rows = [r for r in report["per_round"] if r.get(post) is not None]
    if report.get(key.format("prior")) is not None:
        m, s = report[key.format("prior")] * scale, (report.get(key.format("prior_std")) or 0) * scale
        ax.axhspan(m - s, m + s, color="0.85", label="prior ± std")
        ax.axhline(m, color="0.4", lw=1.5, label=f"prior mean {m:.2f} {unit}")
    if rows:
        x = [r["round"] + 1 for r in rows]
        y = np.array([r[post] for r in rows]) * scale
        e = np.array([r[post_std] or 0 for r in rows]) * scale
        ax.errorbar(x, y, yerr=e, marker="o", color="C0", capsize=3, label="posterior after round (mean ± std)")
        ax.set_xticks(x)
    ax.set_xlabel("round")
    ax.set_ylabel(f"{what}, mean over frames [{unit}]")
    ax.set_title(f"Distance to the measurement\n{Path(str(report.get('observed', ''))).name}", fontsize=10)
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_pairs(path: Path, space: Any, samples: np.ndarray, truth: dict[str, float] | None = None) -> Path:
    """Corner plot of posterior samples over the prior box (log axes for log-scaled parameters)."""
    plt = _plt()
    D = space.dim
    fig, axes = plt.subplots(D, D, figsize=(2.3 * D + 0.5, 2.3 * D + 0.5), squeeze=False)
    for i, pi in enumerate(space):
        for j, pj in enumerate(space):
            ax = axes[i, j]
            if j > i:
                ax.axis("off")
                continue
            if i == j:
                bins = np.geomspace(pi.low, pi.high, 30) if pi.log else np.linspace(pi.low, pi.high, 30)
                ax.hist(samples[:, i], bins=bins, color="C0", alpha=0.8)
                if pi.log:
                    ax.set_xscale("log")
                ax.set_xlim(pi.low, pi.high)
                ax.set_yticks([])
                if truth and pi.name in truth:
                    ax.axvline(truth[pi.name], color="C3", lw=2)
            else:
                ax.scatter(samples[:1500, j], samples[:1500, i], s=2, alpha=0.3, color="C0")
                if pj.log:
                    ax.set_xscale("log")
                if pi.log:
                    ax.set_yscale("log")
                ax.set_xlim(pj.low, pj.high)
                ax.set_ylim(pi.low, pi.high)
                if truth and pi.name in truth and pj.name in truth:
                    ax.plot(truth[pj.name], truth[pi.name], "x", color="C3", ms=9, mew=2)
            if i == D - 1:
                ax.set_xlabel(f"{pj.name} [{pj.unit}]", fontsize=8)
            if j == 0 and i > 0:
                ax.set_ylabel(f"{pi.name} [{pi.unit}]", fontsize=8)
            ax.tick_params(labelsize=6)
    title = "Posterior (axes = prior bounds)" + ("; red = hidden true value" if truth else "")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_clouds(path: Path, result: Any, meas: Any, cfg: Any, frames: tuple[int, ...] | None = None) -> Path:
    """Real (grey) vs simulated-at-posterior-median (blue) clouds: side view and top view."""
    from .perception.pointcloud import rollout_clouds
    from .plugins import registry

    plt = _plt()
    theta = dict(result.report["posterior_median"])
    theta.update(cfg.fixed)
    sim = registry().simulator(cfg.backend)(**cfg.backend_options)
    ro = sim.simulate(meas.scenario, theta, effects=cfg.effects, seed=0)
    T = meas.scenario.n_frames
    frames = frames or tuple(sorted({0, T // 3, 2 * T // 3, T - 1}))
    fig, axes = plt.subplots(2, len(frames), figsize=(3.2 * len(frames), 6.4), squeeze=False)
    sim_pts = rollout_clouds(ro, 800, np.random.default_rng(0)) if ro.ok else None
    for c, f in enumerate(frames):
        real = meas.dense[f]
        for r, (a, b, lab) in enumerate([(1, 2, ("y [m]", "z [m]")), (0, 1, ("x [m]", "y [m]"))]):
            ax = axes[r, c]
            ax.scatter(real[:, a], real[:, b], s=2, color="0.55", alpha=0.5, label="measured")
            if sim_pts is not None:
                ax.scatter(sim_pts[f][:, a], sim_pts[f][:, b], s=2, color="C0", alpha=0.6, label="simulated")
            ax.plot(meas.scenario.gripper[f, a], meas.scenario.gripper[f, b], "r+", ms=12, mew=2, label="gripper")
            ax.set_aspect("equal", adjustable="datalim")
            ax.set_xlabel(lab[0], fontsize=8)
            ax.set_ylabel(lab[1], fontsize=8)
            ax.tick_params(labelsize=7)
            if r == 0:
                ax.set_title(f"frame {f} (t = {meas.scenario.times[f]:.2f} s)", fontsize=9)
    axes[0, 0].legend(fontsize=7, markerscale=4, loc="upper left")
    status = "" if ro.ok else f" (simulation failed: {ro.reason})"
    fig.suptitle(f"Measured vs simulated at the posterior median{status}\nrow 1: side view (y-z), "
                 f"row 2: top view (x-y)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_frames(path: Path, result: Any, meas: Any, cfg: Any, frames: tuple[int, ...] | None = None) -> Path:
    """Image fits: measured frames (top) and frames rendered at the posterior median (bottom), with
    the extractor's keypoints (cyan) and the HSV cloth-mask outline (yellow) of each."""
    from .core.loop import observer_options
    from .perception.masks import hsv_mask
    from .plugins import registry

    plt = _plt()
    theta = dict(result.report["posterior_median"])
    theta.update(cfg.fixed)
    obs = registry().observer(cfg.observer)(**observer_options(cfg, meas.scenario))
    sim = registry().simulator(cfg.backend)(**cfg.backend_options)
    ro = sim.simulate_images(meas.scenario, theta, camera=obs.camera, style=obs.style, effects=cfg.effects, seed=0)
    T = meas.scenario.n_frames
    frames = frames or tuple(sorted({0, T // 3, 2 * T // 3, T - 1}))
    rows = [("measured", meas.images)] + ([("posterior median", ro.rgb)] if ro.ok else [])
    fig, axes = plt.subplots(len(rows), len(frames), figsize=(2.8 * len(frames), 3.0 * len(rows)), squeeze=False)
    for r, (label, imgs) in enumerate(rows):
        kp = obs.observe_images(imgs, meas.scenario.gripper, meas.scenario.times).points
        m = hsv_mask(imgs)
        for c, f in enumerate(frames):
            ax = axes[r, c]
            ax.imshow(imgs[f])
            if m[f].any():
                ax.contour(m[f], levels=[0.5], colors="yellow", linewidths=0.7)
            ax.scatter(kp[f, :, 0], kp[f, :, 1], s=16, c="cyan", edgecolors="k", linewidths=0.5)
            ax.set_title(f"{label}, frame {f}", fontsize=8)
            ax.axis("off")
    status = "" if ro.ok else f" (posterior simulation failed: {ro.reason})"
    rep = result.report
    score = (f"; mask Chamfer prior {rep['mask_chamfer_prior_px']:.2f} px -> posterior "
             f"{rep['mask_chamfer_posterior_px']:.3f} px" if rep.get("mask_chamfer_posterior_px") is not None else "")
    fig.suptitle(f"{meas.scenario.name}, {cfg.observer} keypoints (cyan), HSV cloth mask (yellow){score}{status}",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_check(path: Path, out: dict[str, Any], ch: np.ndarray) -> Path:
    """Heatmap (frame x region) and Chamfer per frame with its posterior band and phases."""
    plt = _plt()
    t = np.array(out["times_s"])
    reg = np.array(out["region_error_m"]) * 100
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2), gridspec_kw={"width_ratios": [1.2, 1]})
    ax = axes[0]
    m = np.array(out["chamfer_per_frame_m"]["mean"]) * 100
    ax.fill_between(t, np.array(out["chamfer_per_frame_m"]["q05"]) * 100,
                    np.array(out["chamfer_per_frame_m"]["q95"]) * 100, color="C0", alpha=0.25,
                    label="5-95% over posterior rollouts")
    ax.plot(t, m, color="C0", lw=2, label="mean")
    for k, ph in enumerate(out["phases"]):
        ax.axvspan(ph["t_s"][0], ph["t_s"][1], color=f"C{k + 2}", alpha=0.07)
        ax.text(np.mean(ph["t_s"]), 0.02, ph["phase"], transform=ax.get_xaxis_transform(), ha="center", fontsize=8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("Chamfer to the measurement [cm]")
    ax.set_ylim(bottom=0)
    mis = out["misspecification"]
    ax.set_title(f"Posterior predictive check (misspecification p = {mis['p_value_gamma']:.2g})", fontsize=10)
    ax.legend(fontsize=8, loc="upper right")
    ax.grid(alpha=0.3)
    ax = axes[1]
    im = ax.imshow(reg.T, aspect="auto", origin="lower", cmap="magma",
                   extent=[t[0] - 0.02, t[-1] + 0.02, 0.5, reg.shape[1] + 0.5])
    ax.set_yticks(range(1, reg.shape[1] + 1))
    ax.set_yticklabels(out["regions"], fontsize=7)
    ax.set_xlabel("time [s]")
    ax.set_title("Error per region of the cloth [cm]\n(regions ordered by distance from the grasp)", fontsize=10)
    fig.colorbar(im, ax=ax, fraction=0.046)
    fig.suptitle(out["summary"], fontsize=8, wrap=True)
    fig.tight_layout(rect=(0, 0, 1, 0.9))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_compare(path: Path, a: dict, b: dict, la: str, lb: str) -> None:
    """Two runs' posterior-predictive checks: Chamfer per frame and error per region."""
    plt = _plt()
    t = np.array(a["times_s"])
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    ax = axes[0]
    for res, lab, col in ((a, la, "C3"), (b, lb, "C0")):
        c = res["chamfer_per_frame_m"]
        ax.fill_between(t, np.array(c["q05"]) * 100, np.array(c["q95"]) * 100, color=col, alpha=0.2)
        ax.plot(t, np.array(c["mean"]) * 100, color=col, lw=2, label=f"{lab}: {res['chamfer_mean_m'] * 100:.2f} cm")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("Chamfer to the measurement [cm]")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Error per time step (band: 5-95% over posterior rollouts)", fontsize=10)
    ax = axes[1]
    names = a["regions"]
    x = np.arange(len(names))
    ax.bar(x - 0.2, [a["region_mean_m"][n] * 100 for n in names], 0.4, color="C3", label=la)
    ax.bar(x + 0.2, [b["region_mean_m"].get(n, 0) * 100 for n in names], 0.4, color="C0", label=lb)
    ax.set_xticks(x)
    ax.set_xticklabels([n.split(" ")[0] for n in names], fontsize=8)
    ax.set_xlabel("region of the cloth (R1 at the grasp ... R9 farthest)")
    ax.set_ylabel("mean error [cm]")
    ax.legend(fontsize=8)
    ax.set_title("Error per region", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
