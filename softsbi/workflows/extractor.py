"""``softsbi train-extractor``: train a keypoint extractor on annotated images or on rendered
rollouts, and measure its test error."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from softsbi.core.errors import SoftsbiError
from softsbi.core.results import write_json_atomic
from softsbi.core.types import jsonable
from softsbi.core import defaults
from softsbi.data.keypoints import block_split, keypoint_errors, load_keypoint_folder
from softsbi.perception.synthdata import render_training_set, visible_corner_labels
from softsbi.plugins import registry


class ExtractorProgress:
    """Progress of :func:`train_extractor` (does nothing by default)."""

    def message(self, text: str) -> None:
        """A sentence for the user (data set sizes, test error)."""

    def task(self, description: str, total: int | None) -> Callable[..., None]:
        """A new task; returns its progress callback ``(done, total, loss=None)`` (rendering calls it
        with rollouts done, training with epochs done and the loss)."""
        return lambda *a, **k: None


def train_extractor(kind: str, out: str | Path, data: str | Path | None = None, simulate: str | None = None,
                    backend: str = defaults.BACKEND, rollouts: int = defaults.IMAGE_ROLLOUTS,
                    image_size: int = defaults.IMAGE_SIZE, mask_robot: bool = True,
                    options: Mapping[str, Any] | None = None, seed: int = defaults.SEED,
                    progress: ExtractorProgress | None = None) -> dict[str, Any]:
    """Train extractor ``kind`` and save it to ``out`` (``.pt``) with a summary ``out.json``.

    Args:
        data: an annotated folder (``images/NNNNN.jpg|png`` + ``keypoints/NNNNN.npy``): contiguous
            train / val / test blocks; the test error is reported.
        simulate: instead of ``data``, a scenario rendered at prior samples (``rollouts`` rollouts,
            ``image_size`` px; labels = projected cloth corners; robot masks from the segmentation).
        mask_robot: unsupervised extractors leave the robot out of the reconstruction loss.
        options: the extractor's constructor options.

    Returns:
        the summary: ``extractor``, ``train`` (epochs, seconds, losses), ``test`` (pixel errors,
        with ``data``) or ``frames`` (with ``simulate``), ``checkpoint``.

    Raises:
        SoftsbiError: neither or both of ``data`` and ``simulate``; PluginNotFound: unknown kind;
        DataError: a malformed annotated folder.
    """
    progress = progress or ExtractorProgress()
    cls = registry().extractor(kind)
    if (data is None) == (simulate is None):
        raise SoftsbiError("give exactly one of --data FOLDER (annotated images) or --simulate SCENARIO (rendered)")
    ext = cls(**dict(options or {}))
    supervised = bool(getattr(cls, "supervised", True))
    summary: dict[str, Any] = {"extractor": kind}
    if data is not None:
        info = _train_on_annotations(ext, kind, supervised, Path(data), seed, progress, summary)
    else:
        d = render_training_set(backend, simulate, n_rollouts=rollouts, size=image_size, seed=seed,
                                progress=progress.task(f"rendering {simulate} on {backend}", rollouts))
        cb = progress.task(f"training {kind}", None)
        H, W = d["images"].shape[1:3]
        if supervised:
            info = ext.fit(d["images"], visible_corner_labels(d["corners"], W, H), seed=seed, progress=cb)
        else:
            info = ext.fit(d["images"], None, d["robot_masks"] if mask_robot else None, seed=seed, progress=cb,
                           sequence_ids=d["sequence_ids"])
        summary["frames"] = int(len(d["images"]))
    summary["train"] = {k: v for k, v in info.items() if k != "history"}
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    ext.save(out)
    write_json_atomic(out.with_suffix(".json"), jsonable(summary))
    return dict(summary, checkpoint=str(out))


def _train_on_annotations(ext: Any, kind: str, supervised: bool, data: Path, seed: int,
                          progress: ExtractorProgress, summary: dict[str, Any]) -> dict[str, Any]:
    images, kps, _ = load_keypoint_folder(data)
    split = block_split(len(images))
    tr, va, te = split["train"], split["val"], split["test"]
    progress.message(f"{len(images)} annotated images from {data}: contiguous blocks, {len(tr)} train / {len(va)} "
                     f"val / {len(te)} test")
    cb = progress.task(f"training {kind}", None)
    if supervised:
        info = ext.fit(images[tr], kps[tr], seed=seed, progress=cb, val_images=images[va], val_keypoints=kps[va])
    else:
        info = ext.fit(images[np.r_[tr, va]], seed=seed, progress=cb)
    summary["test"] = keypoint_errors(ext.predict(images[te]), kps[te])
    progress.message(f"test ({len(te)} frames): mean {summary['test']['mean_px']:.2f} px, PCK@10px "
                     f"{summary['test']['pck@10px'] * 100:.0f}% (set-matched: mean "
                     f"{summary['test']['hungarian_mean_px']:.2f} px)")
    return info
