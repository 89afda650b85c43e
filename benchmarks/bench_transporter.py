"""The transporter suite: unsupervised Transporter keypoints on wipe frames, robot masked out of the loss vs not.

Question: does ignoring the robot/gripper pixels in the reconstruction loss keep the Transporter's
keypoints (Kulkarni et al. 2019) on the cloth? Both models get the same data, seed, config and budget;
only ``masks`` differs.

Data (``--data``):
    * ``rendered`` (default when available): ``MujocoFlex().simulate_images`` of the ``wipe`` scenario
      (``make_scenario('wipe')``) through its camera (``scenario_camera(scenario, size)``), at parameters drawn
      uniformly within ``MujocoFlex().param_space(scenario)`` (``ParamSpace.sample_prior``, log-uniform
      for log-scaled parameters). Robot mask = ``segmentation == SEG_ROBOT``; cloth mask =
      ``segmentation == SEG_OBJECT``.
    * ``synthetic``: cv2-drawn sequences (salmon table, green deforming quadrilateral cloth, white arm with
      black gripper moving independently and partly over the cloth), masks exact.

Metric: fraction of predicted keypoints on held-out rollouts that fall inside the cloth mask (exact and
dilated by 2 px, square element) and inside the robot mask; training time; inference frames/s at 64 and
128 px input frames (1 torch thread, model input resized to ``image_size``).

With ``--outputs`` (the full configuration, ~30 min on one core) the masked model is saved as
``benchmarks/results/transporter_wipe.pt`` and the held-out frames drawn into ``docs/figures/transporter_keypoints.png``
(masked model top, unmasked bottom); the default configuration is a smoke run (~1 min).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from softsbi.core.types import SEG_OBJECT, SEG_ROBOT
from softsbi.perception.keypoints.transporter import TransporterExtractor, keypoints_in_mask

from benchmarks.runner import REPO as ROOT, table

RESULTS = ROOT / "benchmarks" / "results"
FIGURES = ROOT / "docs" / "figures"
TABLE, CLOTH, ARM, GRIPPER = (214, 104, 98), (112, 150, 86), (225, 225, 225), (30, 30, 34)


# ------------------------------------------------------------------ data
def synthetic_sequences(n_seq: int, T: int, size: int, seed: int) -> dict[str, np.ndarray]:
    """cv2-drawn sequences: ``images (N, size, size, 3)`` uint8, ``cloth_masks``/``robot_masks (N, H, W)``
    bool (cloth = visible cloth pixels), ``sequence_ids (N,)``."""
    rng = np.random.default_rng(seed)
    s = size / 64.0
    imgs, cloth, robot, seq = [], [], [], []
    for k in range(n_seq):
        c0 = rng.uniform(12, 24, 2) * s
        vc = rng.uniform(0.4, 1.0, 2) * s * 31 / T
        r0 = rng.uniform([38, 6], [56, 20]) * s
        vr = rng.uniform([-1.4, 0.6], [-0.6, 1.4]) * s * 31 / T
        ang0, dang = rng.uniform(0, 90), rng.uniform(-2, 2)
        base = np.array([[-11, -8], [11, -8], [11, 8], [-11, 8]], float) * s
        wobble = rng.normal(0, 1.0, (4, 2))
        for t in range(T):
            im = np.empty((size, size, 3), np.uint8)
            im[:] = TABLE
            wobble = 0.8 * wobble + rng.normal(0, 0.8, (4, 2))
            quad = c0 + vc * t + base * (1 + 0.15 * np.sin(0.3 * t + k)) + wobble * s
            cm = np.zeros((size, size), np.uint8)
            cv2.fillPoly(cm, [np.round(quad).astype(np.int32)], 1)
            rc, ang = r0 + vr * t, ang0 + dang * t
            rm = np.zeros((size, size), np.uint8)
            d = np.array([np.cos(np.radians(ang + 90)), np.sin(np.radians(ang + 90))])
            arm = cv2.boxPoints(((float(rc[0]), float(rc[1])), (7 * s, 26 * s), float(ang)))
            gc = rc + d * 13 * s
            grip = cv2.boxPoints(((float(gc[0]), float(gc[1])), (10 * s, 6 * s), float(ang)))
            cv2.fillPoly(rm, [np.round(arm).astype(np.int32)], 1)
            cv2.fillPoly(rm, [np.round(grip).astype(np.int32)], 2)
            im[cm > 0] = CLOTH
            im[rm == 1] = ARM
            im[rm == 2] = GRIPPER
            noise = rng.normal(0, 3, im.shape)
            imgs.append(np.clip(im + noise, 0, 255).astype(np.uint8))
            cloth.append((cm > 0) & (rm == 0))
            robot.append(rm > 0)
            seq.append(k)
    return {"images": np.stack(imgs), "cloth_masks": np.stack(cloth), "robot_masks": np.stack(robot),
            "sequence_ids": np.array(seq)}


def rendered_sequences(n_rollouts: int, size: int, seed: int, grid: int) -> dict[str, np.ndarray]:
    """Rendered mujoco-flex wipe rollouts at prior samples (failed rollouts skipped, at most 2x tries)."""
    from softsbi.backends.mujoco_flex import MujocoFlex
    from softsbi.scenarios.builtin import make_scenario
    from softsbi.scenarios.cameras import scenario_camera
    from softsbi.perception.render import robot_mask_from_depth

    sim = MujocoFlex(grid=grid)
    sc = make_scenario("wipe")
    cam = scenario_camera(sc, size)
    space = sim.param_space(sc)
    rng = np.random.default_rng(seed)
    out: dict[str, list] = {k: [] for k in ("images", "cloth_masks", "robot_masks", "sequence_ids", "theta")}
    tries, failed, iou = 0, 0, []
    t0 = time.perf_counter()
    while len(out["theta"]) < n_rollouts and tries < 2 * n_rollouts:
        tries += 1
        theta = space.as_dict(space.sample_prior(1, rng)[0])
        ro = sim.simulate_images(sc, theta, cam, seed=int(rng.integers(2**31)))
        if not ro.ok or ro.rgb is None:
            failed += 1
            continue
        i = len(out["theta"])
        seg = np.asarray(ro.segmentation)
        out["images"].append(np.asarray(ro.rgb))
        out["cloth_masks"].append(seg == SEG_OBJECT)
        out["robot_masks"].append(seg == SEG_ROBOT)
        depth_mask = robot_mask_from_depth(ro.depth, cam, sc.table_z)
        inter, union = (depth_mask & (seg == SEG_ROBOT)).sum(), (depth_mask | (seg == SEG_ROBOT)).sum()
        iou.append(inter / max(union, 1))
        out["sequence_ids"].append(np.full(len(seg), i))
        out["theta"].append(space.as_array(theta))
    res = {k: np.concatenate(v) if k != "theta" else np.asarray(v) for k, v in out.items()}
    res["failed"] = failed
    res["names"] = space.names
    res["render_seconds"] = time.perf_counter() - t0
    res["depth_mask_iou"] = float(np.mean(iou))
    return res


def rendering_available() -> bool:
    from softsbi.backends.mujoco_flex import MujocoFlex
    from softsbi.core.interfaces import Simulator
    return MujocoFlex.simulate_images is not Simulator.simulate_images


# ------------------------------------------------------------------ evaluation
def fps(ext: TransporterExtractor, images: np.ndarray, size: int, repeats: int = 5) -> float:
    frames = np.stack([cv2.resize(im, (size, size), interpolation=cv2.INTER_LINEAR) for im in images])
    ext.predict(frames[:8])  # warm-up
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        ext.predict(frames)
        best = min(best, time.perf_counter() - t)
    return float(len(frames) / best)


def evaluate(ext: TransporterExtractor, test: dict[str, np.ndarray]) -> dict[str, float]:
    kp = ext.predict(test["images"])
    return {"in_cloth": keypoints_in_mask(kp, test["cloth_masks"]),
            "in_cloth_dilated2": keypoints_in_mask(kp, test["cloth_masks"], dilate=2),
            "in_robot": keypoints_in_mask(kp, test["robot_masks"]),
            "in_robot_dilated2": keypoints_in_mask(kp, test["robot_masks"], dilate=2),
            "keypoint_std_px": float(kp.std(axis=0).mean())}


def figure(models: dict[str, TransporterExtractor], test: dict[str, np.ndarray], path: Path, scale: int = 3,
           n_cols: int = 6) -> None:
    """Held-out frames with keypoints; one row per model (masked top), keypoint k has colour k."""
    seq = test["sequence_ids"]
    ids = np.unique(seq)[:2]
    frames = []
    for sid in ids:
        idx = np.flatnonzero(seq == sid)
        frames += list(idx[np.linspace(0, len(idx) - 1, n_cols // len(ids)).round().astype(int)])
    frames = np.array(frames)
    imgs = test["images"][frames]
    h, w = imgs.shape[1:3]
    cmap = np.array([(255, 230, 0), (0, 200, 255), (255, 0, 255), (0, 255, 0), (255, 128, 0), (0, 0, 255),
                     (255, 255, 255), (128, 0, 255), (0, 255, 170), (255, 0, 90), (140, 255, 0), (0, 110, 160)])
    rows = []
    for label, ext in models.items():
        kp = ext.predict(imgs)
        tiles = []
        for im, pts in zip(imgs, kp):
            big = cv2.resize(im, (w * scale, h * scale), interpolation=cv2.INTER_NEAREST).copy()
            for k, (u, v) in enumerate(pts):
                c = tuple(int(x) for x in cmap[k % len(cmap)])
                centre = (int(round((u + 0.5) * scale - 0.5)), int(round((v + 0.5) * scale - 0.5)))
                cv2.circle(big, centre, max(3, scale + 1), (0, 0, 0), -1, cv2.LINE_AA)
                cv2.circle(big, centre, max(2, scale), c, -1, cv2.LINE_AA)
            tiles.append(np.pad(big, ((2, 2), (2, 2), (0, 0)), constant_values=255))
        row = np.concatenate(tiles, axis=1)
        bar = np.full((22, row.shape[1], 3), 255, np.uint8)
        cv2.putText(bar, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
        rows.append(np.concatenate([bar, row]))
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), cv2.cvtColor(np.concatenate(rows), cv2.COLOR_RGB2BGR))


# ------------------------------------------------------------------ suite
FULL = {"rollouts": 48, "test_rollouts": 8, "epochs": 40, "max_seconds": 600.0, "outputs": True}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--data", choices=["auto", "rendered", "synthetic"], default="auto")
    ap.add_argument("--rollouts", type=int, default=6, help="training rollouts (sequences)")
    ap.add_argument("--test-rollouts", type=int, default=2)
    ap.add_argument("--size", type=int, default=64, help="rendered frame size, px")
    ap.add_argument("--grid", type=int, default=9, help="mujoco-flex cloth grid")
    ap.add_argument("--epochs", type=int, default=2)
    ap.add_argument("--max-seconds", type=float, default=60.0, help="training budget per model, s")
    ap.add_argument("--keypoints", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--outputs", action="store_true", help="save the masked model and the figure")


def suite(args: argparse.Namespace) -> dict:
    torch.set_num_threads(1)
    data = args.data
    if data == "auto":
        data = "rendered" if rendering_available() else "synthetic"
    n_all = args.rollouts + args.test_rollouts
    if data == "rendered":
        ds = rendered_sequences(n_all, args.size, args.seed, args.grid)
        source = (f"mujoco-flex (grid {args.grid}) simulate_images of the wipe scenario through its camera at "
                  f"{args.size} px, parameters from the prior")
    else:
        ds = synthetic_sequences(n_all, 31, args.size, args.seed)
        source = "synthetic cv2 sequences: table, deforming quadrilateral cloth, arm and gripper moving independently"
    seq = ds["sequence_ids"]
    n_seq = len(np.unique(seq))
    test_ids = np.unique(seq)[-args.test_rollouts:]
    is_test = np.isin(seq, test_ids)
    train = {k: ds[k][~is_test] for k in ("images", "cloth_masks", "robot_masks", "sequence_ids")}
    test = {k: ds[k][is_test] for k in ("images", "cloth_masks", "robot_masks", "sequence_ids")}
    cfg = dict(image_size=64, n_keypoints=args.keypoints, channels=32, hidden=32, std=0.1, epochs=args.epochs,
               batch_size=16, lr=1e-3, patience=6, min_epochs=5, val_fraction=0.15, max_gap=10, mask_dilate=1,
               max_seconds=args.max_seconds, num_threads=1)
    results: dict[str, dict] = {}
    models: dict[str, TransporterExtractor] = {}
    for label, masks in (("masked", train["robot_masks"]), ("unmasked", None)):
        ext = TransporterExtractor(**cfg)
        info = ext.fit(train["images"], masks=masks, sequence_ids=train["sequence_ids"], seed=args.seed)
        ev = evaluate(ext, test)
        ev.update(train_seconds=info["seconds"], epochs=info["epochs"], best_epoch=info["best_epoch"],
                  val_loss=info["val_loss"], train_loss=info["train_loss"],
                  fps_64px=fps(ext, test["images"], 64), fps_128px=fps(ext, test["images"], 128))
        results[label] = ev
        models[label] = ext
    figures = []
    if args.outputs:
        RESULTS.mkdir(parents=True, exist_ok=True)
        models["masked"].save(RESULTS / "transporter_wipe.pt")
        r = results
        figure({f"robot masked out of the loss: {r['masked']['in_cloth']:.0%} of keypoints in cloth "
                f"({r['masked']['in_cloth_dilated2']:.0%} within 2 px)": models["masked"],
                f"no mask: {r['unmasked']['in_cloth']:.0%} in cloth ({r['unmasked']['in_cloth_dilated2']:.0%} "
                f"within 2 px)": models["unmasked"]}, test, FIGURES / "transporter_keypoints.png")
        figures.append({"path": "figures/transporter_keypoints.png",
                        "caption": "held-out frames: robot masked out of the loss (top), no mask (bottom)"})
    pct = lambda v: round(100 * v, 1)  # noqa: E731
    what = {"masked": "masked out of the loss", "unmasked": "in the loss"}
    rows = [[what[label], pct(r["in_cloth"]), pct(r["in_cloth_dilated2"]), pct(r["in_robot"]), round(r["train_seconds"]),
             r["epochs"], round(r["fps_64px"]), round(r["fps_128px"])] for label, r in results.items()]
    n_test = len(test_ids)
    return {"tables": [table(f"{args.keypoints} keypoints on {n_test} held-out rollouts ({n_seq - n_test} for "
                             f"training, {data} {args.size} px frames)",
                             ["robot pixels", "% in the cloth", "% within 2 px of the cloth",
                              "% on the robot", "training s", "epochs", "frames/s at 64 px", "frames/s at 128 px"],
                             rows, note=f"The cloth covers {test['cloth_masks'].mean():.1%} of the held-out pixels, "
                                        f"the robot {test['robot_masks'].mean():.1%}.")],
            "figures": figures,
            "data": {"data_source": source, "config": cfg, "results": results,
                     "failed_rollouts": int(ds.get("failed", 0))}}
