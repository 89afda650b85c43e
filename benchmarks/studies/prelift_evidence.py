"""Study: the cloth before the lift, what the real pre-lift frames show of the cloth on the table.

Conclusion. On the ten DiffCloud lift recordings, with the cloth placed where the default (truncated) fits put it,
the sensor saw 0-20 % of the cloth lying on the table before the lift, and 0 % on six of ten: a flat cloth lies
below DiffCloud's crop plane (the table), as the virtual depth sensor reproduces. Most frame-0 points are not the
cloth but scene clutter (a streak beside the gripper at the same place in six recordings made together, whatever the
fabric), gone by frame 5-10. The raised cloth that is seen (a 1.7 cm curl over 13 % of tan's footprint, a 0.4 cm
wrinkle on tan2, a patch 2 cm up on paper and paper2) lies in frames 0-9, which the headline metric leaves out,
under a fifth of the cloth. So the lift scenario has no flatness or wrinkle parameter; the placement the data
support is the yaw, inferred from the hanging frames. Run it again on a recording whose pre-lift cloud shows the
cloth (another crop, a camera closer to the table); such a cloud could enter as a mesh cloth's initial shape
(``placement: {rest: mesh}``).

For each DiffCloud lift recording, frame 0 (the gripper has not moved: the path's first two frames are
equal) is compared with where the scenario puts the cloth: the square of side ``scale`` whose diagonal
leaves the grasped corner along the placement direction rotated by ``yaw``, at a fit's posterior mean
(``--fits``: one finished ``softsbi fit`` per recording, folder names ``tan``, ``tan2``, ...) or at the
nominal placement (side 0.278 m, yaw 0). Per recording it reports

* the number of recorded points and their height above the scenario's table (the crop plane);
* the fraction of them inside the placed cloth's footprint (grown by ``--margin``): points outside it
  cannot be the cloth lying there (other objects, the gripper, a cloth placed elsewhere);
* the footprint's coverage: the fraction of a 1 cm grid over the footprint with a recorded point within
  1.5 cm, i.e. how much of the cloth the sensor saw before the lift;
* the heights of the points inside the footprint (the evidence for wrinkles or folds: a flat cloth is
  below the crop plane and unseen, see :mod:`softsbi.perception.depth_sensor`);
* the fraction of frame 5's and frame 10's points within 0.5 cm of a frame-0 point (static fragments that
  stay where they were, e.g. scene clutter, vs fragments that leave with the cloth).

Usage (``--fits``: e.g. the real-lift suite's ``--full --out DIR``):
    python -m benchmarks.studies.prelift_evidence [--fits DIR] [--figure docs/figures/prelift_frame0.png]
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from softsbi.scenarios.builtin import NOMINAL_SIZE, lift_scenario, placed_direction

DATA = Path(__file__).resolve().parents[3] / "shared/data/diffcloud_lift"
RECS = ["tan", "tan2", "navy", "navy2", "paper", "paper2", "polka", "polka2", "redblack", "redblack2"]


def footprint(corner: np.ndarray, d: np.ndarray, side: float) -> np.ndarray:
    """Corners ``(4, 2)`` m of the square cloth: grasped corner, the two side corners, the far corner."""
    e1 = np.array([d[0] * math.cos(-math.pi / 4) - d[1] * math.sin(-math.pi / 4),
                   d[0] * math.sin(-math.pi / 4) + d[1] * math.cos(-math.pi / 4)])
    e2 = np.array([d[0] * math.cos(math.pi / 4) - d[1] * math.sin(math.pi / 4),
                   d[0] * math.sin(math.pi / 4) + d[1] * math.cos(math.pi / 4)])
    return np.array([corner, corner + side * e1, corner + side * (e1 + e2), corner + side * e2])


def inside(points: np.ndarray, quad: np.ndarray, margin: float) -> np.ndarray:
    """Boolean ``(P,)``: points ``(P, 2)`` within ``margin`` m of the square ``quad (4, 2)`` (or inside it)."""
    o, a, b = quad[0], quad[1] - quad[0], quad[3] - quad[0]
    side = float(np.linalg.norm(a))
    u = (points - o) @ (a / side)
    v = (points - o) @ (b / side)
    return (u >= -margin) & (u <= side + margin) & (v >= -margin) & (v <= side + margin)


def evidence(rec: str, fit: Path | None, margin: float) -> dict:
    """The frame-0 numbers of one recording (module docstring)."""
    sc = lift_scenario(DATA / f"lift_{rec}")
    theta = {"yaw": 0.0, "scale": float(NOMINAL_SIZE)}
    if fit is not None and (fit / "report.json").exists():
        pm = json.loads((fit / "report.json").read_text())["posterior_mean"]
        theta = {"yaw": float(pm.get("yaw", 0.0)), "scale": float(pm["scale"])}
    corner = np.asarray(sc.object["corner"], float)
    quad = footprint(corner, placed_direction(sc, theta), theta["scale"])
    pts = np.load(DATA / f"lift_{rec}" / "000.npy") * 0.35
    pts = np.unique(pts, axis=0)
    h = pts[:, 2] - sc.table_z
    ins = inside(pts[:, :2], quad, margin)
    # coverage of the footprint by the recorded points (1 cm grid, a point within 1.5 cm)
    o, a, b = quad[0], quad[1] - quad[0], quad[3] - quad[0]
    g = np.linspace(0.0, 1.0, max(2, int(theta["scale"] / 0.01)))
    grid = o + g[:, None, None] * a + g[None, :, None] * b
    dist, _ = cKDTree(pts[:, :2]).query(grid.reshape(-1, 2))
    hin = h[ins]
    tree = cKDTree(pts)
    still = {}
    for i in (5, 10):
        f = np.unique(np.load(DATA / f"lift_{rec}" / f"{i:03d}.npy") * 0.35, axis=0)
        still[i] = float((tree.query(f)[0] < 0.005).mean())
    return {"still_there": still, "recording": rec, "theta": theta, "n_points": int(len(pts)), "inside_fraction": float(ins.mean()),
            "coverage": float((dist <= 0.015).mean()),
            "height_inside_cm": None if not len(hin) else [float(np.quantile(hin, q) * 100) for q in (0.1, 0.5, 0.9)],
            "height_outside_cm": None if ins.all() else [float(np.quantile(h[~ins], q) * 100) for q in (0.1, 0.5, 0.9)],
            "quad": quad.tolist(), "corner": corner.tolist(), "points": pts, "heights": h}


def figure(rows: list[dict], path: Path) -> None:
    """Top views of frame 0 (points coloured by height above the table) with the placed cloth's outline."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(2, 5, figsize=(17, 7.6), constrained_layout=True)
    for ax, r in zip(axes.ravel(), rows):
        p, h = r["points"], r["heights"] * 100
        sc = ax.scatter(p[:, 0] * 100, p[:, 1] * 100, c=np.clip(h, 0, 4), s=2, cmap="viridis", vmin=0, vmax=4)
        q = np.vstack([r["quad"], r["quad"][:1]]) * 100
        ax.plot(q[:, 0], q[:, 1], "r-", lw=1.2, label="placed cloth (fit)")
        ax.plot(r["corner"][0] * 100, r["corner"][1] * 100, "r^", ms=8, label="grasped corner")
        ax.set_title(f"lift_{r['recording']}: {r['n_points']} pts, {r['inside_fraction']:.0%} on the cloth,\n"
                     f"cloth seen {r['coverage']:.0%}", fontsize=9)
        ax.set_aspect("equal")
        ax.set_xlim(-50, 30)
        ax.set_ylim(-35, 25)
        ax.set_xlabel("x [cm] (lift frame)")
        ax.set_ylabel("y [cm]")
    axes[0, 0].legend(loc="lower left", fontsize=7)
    fig.colorbar(sc, ax=axes, shrink=0.6, label="height above the table [cm] (clipped at 4)")
    fig.suptitle("Frame 0 of every lift recording (before the lift), top view, with the cloth where the fit places it")
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fits", type=Path, default=None, help="folder of finished fits named tan, tan2, ...")
    ap.add_argument("--margin", type=float, default=0.02, help="footprint margin (m)")
    ap.add_argument("--figure", type=Path, default=None)
    a = ap.parse_args()
    rows = [evidence(r, a.fits / r if a.fits else None, a.margin) for r in RECS]
    print("| recording | yaw [deg] | side [cm] | frame-0 points | on the placed cloth | cloth seen | height on the "
          "cloth q10/50/90 [cm] | height elsewhere q10/50/90 [cm] | frame 5 / 10 at frame-0 places |")
    print("|---|---|---|---|---|---|---|---|---|")
    fmt = lambda v: "-" if v is None else "/".join(f"{x:.1f}" for x in v)  # noqa: E731
    for r in rows:
        print(f"| {r['recording']} | {r['theta']['yaw']:+.1f} | {r['theta']['scale'] * 100:.1f} | {r['n_points']} | "
              f"{r['inside_fraction']:.0%} | {r['coverage']:.0%} | {fmt(r['height_inside_cm'])} | "
              f"{fmt(r['height_outside_cm'])} | {r['still_there'][5]:.2f} / {r['still_there'][10]:.2f} |")
    if a.figure:
        figure(rows, a.figure)


if __name__ == "__main__":
    main()
