"""Supervised heatmap keypoints on the real wiping set: held-out error, training time, CPU speed.

Data: ``shared/data/wiping_keypoints`` (449 frames, 320x320, 4 cloth corners; 61 source images,
31 real and 30 simulated, and 8 augmented copies of each of sources 0..48, see
:mod:`softsbi.data.keypoints`). Split: :func:`block_split` with the source id as group
(15 contiguous blocks of sources; an image and its copies never straddle splits), so no test
image, nor an augmented copy of it, is seen in training. Training on train, early stopping on val,
metrics on test at the original 320x320 pixel coordinates, for all test frames, real-only and
simulated-only, index-matched and with Hungarian set matching.

Config: the default trains with the set-matched loss (``order_invariant=True``): the corner
identities of the simulated cloth (a symmetric square, often rotated 45 degrees) are not visible,
and the index-matched loss made two channels fire on the same corner (``--ordered`` reproduces
it). The set-matched (``hungarian_*``) metrics are then the meaningful ones, as for the
downstream RKHS embedding, which treats keypoints as an unordered set; index-matched numbers of
such a model only measure its arbitrary channel order.

Speed: ``predict`` (resize + network + decoding) in frames/s on CPU at input 128 and 320 px,
batch 1 and 16 (the 320-px figure runs the trained weights at 320: speed only).

Outputs: ``benchmarks/results/heatmap_wiping.pt`` (checkpoint), ``benchmarks/results/heatmap.json``
and ``docs/figures/heatmap_test_predictions.png`` (held-out real test frames; ``..._sim.png``: the
simulated ones; filled dots =
prediction, rings = ground truth, same colour = same corner after set matching; label = frame,
original or augmented copy, mean error in px at 320).

Usage (the machine is shared; one torch thread was faster than two under load)::

    nice -n 15 python benchmarks/bench_heatmap.py [--epochs 120] [--width 32] [--threads 1]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np
import torch

from softsbi.perception.keypoints.heatmap import HeatmapExtractor
from softsbi.data.keypoints import (
    block_split,
    draw_keypoints,
    index_ranges,
    keypoint_errors,
    load_keypoint_folder,
    match_keypoints,
    wiping_frame_labels,
)

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "wiping_keypoints"


def fps(ex: HeatmapExtractor, images: np.ndarray, batch: int, seconds: float = 2.0, repeats: int = 3) -> float:
    """Frames/s of ``ex.predict`` on ``images`` in batches of ``batch``: the best of ``repeats``
    windows of about ``seconds`` each, after one warm-up call (the machine is shared: the best
    window is the least disturbed one)."""
    ex.predict(images[:batch])
    best = 0.0
    for _ in range(repeats):
        n, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < seconds or n < 2 * batch:
            i = (n // batch * batch) % max(1, len(images) - batch)
            ex.predict(images[i:i + batch])
            n += batch
        best = max(best, n / (time.perf_counter() - t0))
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DATA))
    ap.add_argument("--input-size", type=int, default=128)
    ap.add_argument("--width", type=int, default=32)
    ap.add_argument("--layers", type=int, nargs=4, default=[3, 4, 6, 3])
    ap.add_argument("--epochs", type=int, default=100)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--batch-size", type=int, default=16)
    ap.add_argument("--patience", type=int, default=25)
    ap.add_argument("--loss", default="bce")
    ap.add_argument("--no-augment", action="store_true")
    ap.add_argument("--ordered", action="store_true",
                    help="index-matched loss (channel k = keypoint k) instead of the set-matched loss")
    ap.add_argument("--max-minutes", type=float, default=25.0, help="training wall-time cap")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    ap.add_argument("--figure", default=str(ROOT / "docs" / "figures" / "heatmap_test_predictions.png"))
    ap.add_argument("--eval-only", action="store_true",
                    help="skip training: evaluate the saved checkpoint (training figures from the previous json)")
    ap.add_argument("--tag", default="", help="suffix of the output names (for trial runs)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    images, kps, _ = load_keypoint_folder(args.data)
    lab = wiping_frame_labels(len(images))
    split = block_split(len(images), (0.7, 0.15, 0.15), n_blocks=15, groups=lab["source"])
    tr, va, te = split["train"], split["val"], split["test"]
    split_info = {s: {"n": len(ix), "n_real": int(lab["real"][ix].sum()),
                      "frame_ranges": index_ranges(ix), "sources": sorted(set(lab["source"][ix].tolist())),
                      "real_sources": sorted(set(lab["source"][ix][lab["real"][ix]].tolist()))}
                  for s, ix in split.items()}
    print(json.dumps({k: {kk: v[kk] for kk in ("n", "n_real", "frame_ranges")} for k, v in split_info.items()}),
          flush=True)

    config = dict(input_size=args.input_size, layers=args.layers, width=args.width, epochs=args.epochs, lr=args.lr,
                  batch_size=args.batch_size, patience=args.patience, loss=args.loss, augment=not args.no_augment,
                  order_invariant=not args.ordered,
                  num_threads=args.threads, max_seconds=args.max_minutes * 60)
    ex = HeatmapExtractor(**config)

    def progress(epoch: int, max_epochs: int, loss: float) -> None:
        h = ex.history[-1]
        print(f"epoch {epoch}/{max_epochs} train_loss {loss:.5f} val_loss {h['val_loss']:.5f} "
              f"val_mean_px {h['val_mean_px']:.2f} val_hungarian_px {h['val_hungarian_px']:.2f} "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)

    ckpt = out / f"heatmap_wiping{args.tag}.pt"
    t0 = time.perf_counter()
    if args.eval_only:  # re-evaluate the saved checkpoint; training figures from the previous report
        ex = HeatmapExtractor.load(ckpt)
        prev = json.loads((out / f"heatmap{args.tag}.json").read_text())
        info = {**prev["training"], "history": prev["history"]}
    else:
        info = ex.fit(images[tr], kps[tr], seed=args.seed, progress=progress, val_images=images[va],
                      val_keypoints=kps[va])
        ex.save(ckpt)
    print(json.dumps({k: v for k, v in info.items() if k != "history"}), flush=True)

    results: dict = {}
    preds = {}
    for s, ix in split.items():
        p = ex.predict(images[ix])
        preds[s] = p
        res = {"all": keypoint_errors(p, kps[ix])}
        for sub, m in (("real", lab["real"][ix]), ("simulated", ~lab["real"][ix]),
                       ("real_unaugmented", lab["real"][ix] & ~lab["augmented"][ix])):
            if m.any():
                res[sub] = keypoint_errors(p[m], kps[ix][m])
        results[s] = res
        print(s, json.dumps({k: {m: round(v[m], 3) for m in ("mean_px", "median_px", "pck@10px",
                                                               "hungarian_mean_px", "hungarian_pck@10px")}
                             for k, v in res.items()}), flush=True)

    # inference speed (320-px input: the trained weights run at 320 for timing only)
    speed = []
    ex320 = HeatmapExtractor(**{**ex.config, "input_size": 320})
    ex320._net, ex320._k = ex._net, ex._k
    for threads in sorted({1, 2}):
        for size, e in ((args.input_size, ex), (320, ex320)):
            for batch in (1, 16):
                e.config["num_threads"] = threads
                f = fps(e, images[te], batch)
                speed.append({"input_px": size, "batch": batch, "threads": threads, "frames_per_s": round(f, 2)})
                print(json.dumps(speed[-1]), flush=True)
    ex.config["num_threads"] = args.threads

    # figure: held-out real test frames (set-matched model: predictions reordered to the truth first,
    # so colours and the per-frame error label use the Hungarian matching)
    real_te = te[lab["real"][te]]
    pr = preds["test"][lab["real"][te]]
    if ex.config["order_invariant"]:
        pr = match_keypoints(pr, kps[real_te])
    d = np.linalg.norm(pr - kps[real_te], axis=-1).mean(1)
    labels = [f"#{i} {'orig' if not lab['augmented'][i] else 'aug'} {e:.1f}px" for i, e in zip(real_te, d)]
    fig = Path(args.figure)
    if args.tag:
        fig = fig.with_name(fig.stem + args.tag + fig.suffix)
    draw_keypoints(images[real_te], pr, kps[real_te], labels=labels, ncols=7, tile=200, path=fig)
    sim_te = te[~lab["real"][te]]  # the simulated test frames, for the failure modes
    ps = preds["test"][~lab["real"][te]]
    if ex.config["order_invariant"]:
        ps = match_keypoints(ps, kps[sim_te])
    d = np.linalg.norm(ps - kps[sim_te], axis=-1).mean(1)
    labels = [f"#{i} {'orig' if not lab['augmented'][i] else 'aug'} {e:.1f}px" for i, e in zip(sim_te, d)]
    fig_sim = fig.with_name(fig.stem + "_sim" + fig.suffix)
    draw_keypoints(images[sim_te], ps, kps[sim_te], labels=labels, ncols=7, tile=200, path=fig_sim)

    doc = {
        "benchmark": "supervised heatmap keypoints on shared/data/wiping_keypoints (issue 6, item 2)",
        "config": ex.config, "seed": args.seed, "split": split_info,
        "primary_metrics": ("hungarian_* (set-matched): the model is trained order-invariant, index-matched "
                            "numbers only reflect its channel order") if ex.config["order_invariant"] else
                           "index-matched and hungarian_* both meaningful",
        "split_rule": "block_split(449, (0.7, 0.15, 0.15), n_blocks=15, groups=source id): contiguous blocks of "
                      "source images, each with its augmented copies; real = robot photograph or a copy of one",
        "training": {k: v for k, v in info.items() if k != "history"}, "history": info["history"],
        "metrics_px_at_320": results, "inference": speed,
        "machine": {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
                    "torch": torch.__version__, "load_avg_at_end": os.getloadavg(),
                    "note": "shared 2-core machine under load, run with nice -n 15: timings are upper bounds"},
        "checkpoint": str(ckpt.relative_to(ROOT)) if ckpt.is_relative_to(ROOT) else str(ckpt),
        "figure": str(fig.relative_to(ROOT)) if fig.is_relative_to(ROOT) else str(fig),
        "figure_simulated": str(fig_sim.relative_to(ROOT)) if fig_sim.is_relative_to(ROOT) else str(fig_sim),
    }
    (out / f"heatmap{args.tag}.json").write_text(json.dumps(doc, indent=1, default=float))
    print("wrote", out / f"heatmap{args.tag}.json", flush=True)


if __name__ == "__main__":
    main()
