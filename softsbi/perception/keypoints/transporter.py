"""Unsupervised keypoints with the Transporter (``transporter`` extractor).

Source: T. Kulkarni, A. Gupta, C. Ionescu, S. Borgeaud, M. Reynolds, A. Zisserman, V. Mnih,
"Unsupervised Learning of Object Keypoints for Perception and Control", NeurIPS 2019, Sec. 3
(the "transport" operation, Eq. 1-2, and the keypoint bottleneck).

Model (all in torch.nn, CPU-sized). For an input frame ``x`` resized to ``S x S`` (``image_size``):

* feature encoder ``Phi(x)``: ``(B, C, S/4, S/4)`` (conv stack, stride 4);
* keypoint network ``Psi(x)``: same layout with its own weights and K output maps, turned into K
  keypoints ``mu_k`` by a spatial softmax (expected coordinates, normalised ``[-1, 1]`` with the image
  spanning ``[-1, 1]``), then into Gaussian maps ``H_k(p) = exp(-|p - mu_k|^2 / (2 std^2))`` on the
  feature grid (peak 1);
* transport from a source frame ``s`` to a target frame ``t`` of the same sequence, applied keypoint
  by keypoint as in the paper (``k = 1..K``, starting from ``Phi_hat = Phi(s)``)::

      Phi_hat <- (1 - H_k(s)) * (1 - H_k(t)) * Phi_hat + H_k(t) * Phi(t)

  i.e. features of the source are erased around the source and target keypoints and the target's
  features are pasted around the target keypoints;
* decoder: ``Phi_hat`` -> reconstruction of the target frame, ``(B, 3, S, S)``.

Loss: mean squared error (L2, as in the paper; no perceptual loss) between the reconstruction and the
target frame, both scaled to ``[-0.5, 0.5]``, averaged over the pixels that are **not** ignored: with
``masks`` (True = ignore, e.g. the robot/gripper) those pixels contribute nothing, so the keypoints have
no reason to follow the robot. The encoders still *see* the robot (masks are not available at
:meth:`TransporterExtractor.predict` time, so inputs are never blanked).

Training samples (source, target) pairs of frames of the same sequence (``sequence_ids``) at most
``max_gap`` frames apart; the validation split holds out whole sequences when there are at least two
(otherwise random frames), with early stopping on the validation loss (best weights kept).

Keypoints are returned in the caller's pixels ``(u, v)`` = (column, row), pixel centres at integer
coordinates (the centre of the top-left pixel is ``(0, 0)``).

Registered through the ``softsbi_extractors`` hook as ``transporter``.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable, ClassVar, Mapping

import cv2
import numpy as np
import torch
from torch.nn import functional as F

from softsbi.core.errors import DataError, ParameterError, ShapeError
from softsbi.core.interfaces import KeypointExtractor
from softsbi.plugins.hookspecs import hookimpl
from softsbi.inference.neural_mdn import merge_config
from softsbi.inference.training import fit_early_stopping, minibatches, predict_batched, torch_threads
from softsbi.perception.images import check_images
from softsbi.perception.keypoints.transporter_net import (STRIDE, TransporterNet, gaussian_maps, keypoints_in_mask,
                                                          masked_reconstruction_loss, sample_pairs, spatial_softmax,
                                                          transport)

# the network and its building blocks live in transporter_net and stay importable from here
__all__ = ["TransporterExtractor", "TransporterNet", "transport", "spatial_softmax", "gaussian_maps",
           "masked_reconstruction_loss", "sample_pairs", "keypoints_in_mask", "softsbi_extractors"]

CHECKPOINT_FORMAT = "softsbi.transporter/1"


def _merge(defaults: Mapping[str, Any], config: Mapping[str, Any]) -> dict[str, Any]:
    return merge_config("transporter", defaults, config, kind="extractor")


def _check_images(images: Any, what: str = "images") -> np.ndarray:
    """:func:`softsbi.perception.images.check_images` plus: at least one image of at least 8x8 px."""
    images = check_images(images, what)
    if len(images) == 0 or min(images.shape[1:3]) < 8:
        raise ShapeError(f"{what} must hold at least one image of at least 8x8 px, got shape {images.shape}")
    return images


class TransporterExtractor(KeypointExtractor):
    """Unsupervised keypoints of the Transporter (Kulkarni et al. 2019), trained on frame pairs.

    Config options (keyword arguments; unknown names raise :class:`ParameterError` with the closest one):
        image_size: side S of the square network input, px (multiple of 4, 16-256); default 64 (CPU).
            Images of any size are resized to S x S (aspect ratio not kept) and keypoints mapped back.
        n_keypoints: K, default 8.
        channels: feature channels C of ``Phi``, default 32.
        hidden: width of the conv stacks, default 32.
        std: Gaussian std of the keypoint maps in normalised units (image spans [-1, 1]), default 0.1
            (the paper's value; 3.2 px at 64 px).
        epochs: maximum epochs (one pair per training frame per epoch), default 30.
        batch_size: default 16. lr: Adam learning rate, default 1e-3. weight_decay: default 0.
        patience: epochs without validation improvement before stopping, default 5.
        min_epochs: default 3. val_fraction: held-out fraction (sequences, or frames for one sequence),
            default 0.15 (0 disables validation and early stopping).
        max_gap: largest frame distance between source and target, default 10.
        mask_dilate: grow the ignore masks by this many px at the network resolution, default 1.
        grad_clip: gradient-norm clip, default 10.0 (None disables).
        max_seconds: wall-clock budget per fit (None: none); stops early keeping the best weights.
        seed: default seed of :meth:`fit` (weights, pair sampling, split), default 0.
        num_threads: torch threads during fit/predict (restored afterwards), default 1.
        predict_batch: frames per forward pass in :meth:`predict`, default 64.
    """

    name: ClassVar[str] = "transporter"
    supervised: ClassVar[bool] = False
    DEFAULTS: ClassVar[dict[str, Any]] = {
        "image_size": 64, "n_keypoints": 8, "channels": 32, "hidden": 32, "std": 0.1, "epochs": 30,
        "batch_size": 16, "lr": 1e-3, "weight_decay": 0.0, "patience": 5, "min_epochs": 3, "val_fraction": 0.15,
        "max_gap": 10, "mask_dilate": 1, "grad_clip": 10.0, "max_seconds": None, "seed": 0, "num_threads": 1,
        "predict_batch": 64,
    }

    def __init__(self, **config: Any):
        cfg = _merge(self.DEFAULTS, config)
        s = int(cfg["image_size"])
        if s % STRIDE or not 16 <= s <= 256:
            raise ParameterError(f"image_size must be a multiple of {STRIDE} in [16, 256], got {cfg['image_size']}")
        for key in ("n_keypoints", "channels", "epochs", "batch_size", "max_gap", "predict_batch", "num_threads"):
            if int(cfg[key]) < 1:
                raise ParameterError(f"{key} must be >= 1, got {cfg[key]}")
        if int(cfg["hidden"]) < 2:
            raise ParameterError(f"hidden must be >= 2, got {cfg['hidden']}")
        if not float(cfg["std"]) > 0:
            raise ParameterError(f"std must be > 0 (normalised units, image spans [-1, 1]), got {cfg['std']}")
        if not float(cfg["lr"]) > 0:
            raise ParameterError(f"lr must be > 0, got {cfg['lr']}")
        if not 0.0 <= float(cfg["val_fraction"]) < 0.9:
            raise ParameterError(f"val_fraction must be in [0, 0.9), got {cfg['val_fraction']}")
        if int(cfg["mask_dilate"]) < 0:
            raise ParameterError(f"mask_dilate must be >= 0, got {cfg['mask_dilate']}")
        super().__init__(**cfg)
        self._net: TransporterNet | None = None
        self.fit_info: dict[str, Any] = {}

    # ------------------------------------------------------------------ properties
    @property
    def trained(self) -> bool:
        return self._net is not None

    @property
    def n_keypoints(self) -> int:
        return int(self.config["n_keypoints"])

    def _build(self) -> TransporterNet:
        c = self.config
        return TransporterNet(int(c["n_keypoints"]), int(c["channels"]), int(c["hidden"]), float(c["std"]))

    # ------------------------------------------------------------------ preprocessing
    def _resize(self, images: np.ndarray) -> torch.Tensor:
        """``(N, H, W, 3)`` uint8 -> ``(N, S, S, 3)`` uint8 tensor (area resize when shrinking)."""
        s = int(self.config["image_size"])
        if images.shape[1:3] != (s, s):
            interp = cv2.INTER_AREA if min(images.shape[1:3]) >= s else cv2.INTER_LINEAR
            images = np.stack([cv2.resize(im, (s, s), interpolation=interp) for im in images])
        return torch.from_numpy(np.ascontiguousarray(images))

    @staticmethod
    def _as_input(frames: torch.Tensor) -> torch.Tensor:
        """``(B, S, S, 3)`` uint8 -> network input ``(B, 3, S, S)`` float32 in ``[-0.5, 0.5]``."""
        return frames.permute(0, 3, 1, 2).float() / 255.0 - 0.5

    def _to_tensor(self, images: np.ndarray) -> torch.Tensor:
        """``(N, H, W, 3)`` uint8 -> ``(N, 3, S, S)`` float32 in ``[-0.5, 0.5]``."""
        return self._as_input(self._resize(images))

    def _mask_tensor(self, masks: np.ndarray) -> torch.Tensor:
        """``(N, H, W)`` bool -> ``(N, S, S)`` bool: a network pixel is ignored if any source pixel under it
        is, then dilated by ``mask_dilate``."""
        s, d = int(self.config["image_size"]), int(self.config["mask_dilate"])
        m = torch.from_numpy(np.ascontiguousarray(masks)).float()[:, None]
        if m.shape[-2:] != (s, s):
            m = F.adaptive_max_pool2d(m, (s, s)) if min(m.shape[-2:]) >= s else F.interpolate(m, (s, s))
        if d > 0:
            m = F.max_pool2d(m, 2 * d + 1, stride=1, padding=d)
        return m[:, 0] > 0.5

    # ------------------------------------------------------------------ fit
    def fit(self, images: np.ndarray, keypoints: np.ndarray | None = None, masks: np.ndarray | None = None, *,
            seed: int | None = None, progress: Callable[[int, int, float], None] | None = None,
            sequence_ids: np.ndarray | None = None) -> dict[str, Any]:
        """Train on frame pairs of ``images``.

        Args:
            images: ``(N, H, W, 3)`` uint8 RGB, frames in temporal order within each sequence.
            keypoints: ignored (unsupervised); accepted for the common interface.
            masks: optional ``(N, H, W)`` bool, True = pixel ignored in the reconstruction loss (robot).
            seed: seeds weights, split and pair sampling (default: config ``seed``).
            progress: ``progress(epoch, max_epochs, train_loss)`` after each epoch.
            sequence_ids: optional ``(N,)`` labels; pairs are drawn within a sequence (default: all one).

        Returns:
            ``{"epochs", "best_epoch", "train_loss", "val_loss", "seconds", "n_train", "n_val",
            "n_sequences", "history": [(train, val), ...]}`` (losses: masked MSE on ``[-0.5, 0.5]`` pixels).

        Raises:
            ShapeError: images not ``(N, H, W, 3)`` uint8, masks/sequence_ids not matching them.
            DataError: fewer than 2 frames, or masks that ignore every pixel.

        Training uses the shared early-stopping loop (:func:`~softsbi.inference.training.fit_early_stopping`):
        an improvement must lower the validation loss by more than 1e-7; without validation
        (``val_fraction=0``) the epoch with the lowest training loss is kept and all ``epochs`` run; a
        non-finite loss does not stop training by itself.
        """
        images = _check_images(images)
        n = len(images)
        if n < 2:
            raise DataError(f"need at least 2 frames to train the transporter (pairs of frames), got {n}")
        if masks is not None:
            masks = np.asarray(masks)
            if masks.shape != images.shape[:3]:
                raise ShapeError(f"masks must be (N, H, W) = {images.shape[:3]} bool, got {masks.shape}")
            if masks.dtype != bool:
                raise ShapeError(f"masks must be bool (True = ignore), got dtype {masks.dtype}")
            if masks.all():
                raise DataError("masks ignore every pixel; nothing is left to reconstruct")
        if sequence_ids is None:
            seq = np.zeros(n, dtype=np.int64)
        else:
            seq = np.asarray(sequence_ids)
            if seq.shape != (n,):
                raise ShapeError(f"sequence_ids must be (N,) = ({n},), got {seq.shape}")
        cfg = self.config
        seed = int(cfg["seed"] if seed is None else seed)
        with torch_threads(int(cfg["num_threads"]), convolutions=True):
            return self._fit(images, masks, seq, seed, progress)

    def _split(self, seq: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        n, vf = len(seq), float(self.config["val_fraction"])
        if vf <= 0:
            return np.arange(n), np.arange(0)
        ids = np.unique(seq)
        if len(ids) >= 2:
            n_val = min(len(ids) - 1, max(1, int(round(vf * len(ids)))))
            val_ids = rng.choice(ids, n_val, replace=False)
            is_val = np.isin(seq, val_ids)
        else:
            n_val = min(n - 2, max(1, int(round(vf * n))))
            if n_val < 1:
                return np.arange(n), np.arange(0)
            is_val = np.zeros(n, bool)
            is_val[rng.choice(n, n_val, replace=False)] = True
        return np.flatnonzero(~is_val), np.flatnonzero(is_val)

    def _fit(self, images: np.ndarray, masks: np.ndarray | None, seq: np.ndarray, seed: int,
             progress: Callable[[int, int, float], None] | None) -> dict[str, Any]:
        """:meth:`fit` after the checks (inside the thread scope)."""
        cfg = self.config
        t0 = time.perf_counter()
        rng = np.random.default_rng(seed)
        torch.manual_seed(seed)
        x = self._resize(images)  # uint8, converted per batch (4x less memory than float32)
        ign = self._mask_tensor(masks) if masks is not None else None
        tr, va = self._split(seq, rng)
        net = self._build()
        opt = torch.optim.Adam(net.parameters(), lr=float(cfg["lr"]), weight_decay=float(cfg["weight_decay"]))
        max_epochs, bs, gap = int(cfg["epochs"]), int(cfg["batch_size"]), int(cfg["max_gap"])
        val_pairs = sample_pairs(seq, gap, np.random.default_rng(seed + 1), va) if len(va) else None

        def pair_loss(pairs: np.ndarray) -> torch.Tensor:
            """Masked reconstruction loss of ``pairs (b, 2)`` = (source, target) frame indices."""
            s, t = torch.from_numpy(pairs[:, 0]), torch.from_numpy(pairs[:, 1])
            target = self._as_input(x[t])
            rec, _, _ = net(self._as_input(x[s]), target)
            return masked_reconstruction_loss(rec, target, None if ign is None else ign[t])

        def epoch_pairs() -> list[np.ndarray]:
            """This epoch's (source, target) pairs of the training frames, in shuffled batches."""
            src, tgt = sample_pairs(seq, gap, rng, tr)
            return [np.stack([src[j], tgt[j]], 1) for j in minibatches(len(tgt), bs, rng)]

        def validate() -> float:
            assert val_pairs is not None
            sums = predict_batched(lambda p: float(pair_loss(p)) * len(p), np.stack(val_pairs, 1), batch_size=64,
                                   module=net)
            return sum(sums) / len(val_pairs[1])

        info = fit_early_stopping(
            net, pair_loss, epoch_pairs, validate=validate if val_pairs is not None else None, min_delta=1e-7,
            optimizer=opt, max_epochs=max_epochs, patience=int(cfg["patience"]), min_epochs=int(cfg["min_epochs"]),
            grad_clip=None if cfg["grad_clip"] is None else float(cfg["grad_clip"]), stop_on_nonfinite=False,
            max_seconds=cfg["max_seconds"], progress=progress, t0=t0)
        self._net = net
        history = [[r["train_loss"], r["val_loss"]] for r in info["history"]]
        best_epoch = info["best_epoch"]
        self.fit_info = {"epochs": info["epochs"], "best_epoch": best_epoch,
                         "train_loss": history[best_epoch - 1][0] if best_epoch else history[-1][0],
                         "val_loss": info["val_loss"] if val_pairs is not None else None,
                         "seconds": time.perf_counter() - t0, "n_train": int(len(tr)), "n_val": int(len(va)),
                         "n_sequences": int(len(np.unique(seq))), "masked": ign is not None, "history": history}
        return dict(self.fit_info)

    def reconstruction_loss(self, source: np.ndarray, target: np.ndarray, masks: np.ndarray | None = None) -> float:
        """Masked MSE of reconstructing each ``target`` frame from its ``source`` frame (trained model).

        Args:
            source, target: ``(N, H, W, 3)`` uint8 RGB pairs. masks: optional ``(N, H, W)`` bool of the targets.

        Raises:
            RuntimeError: not trained. ShapeError: bad shapes.
        """
        net = self._require()
        source, target = _check_images(source, "source"), _check_images(target, "target")
        if source.shape != target.shape:
            raise ShapeError(f"source and target must have the same shape, got {source.shape} and {target.shape}")
        if masks is not None and (np.shape(masks) != target.shape[:3] or np.asarray(masks).dtype != bool):
            raise ShapeError(f"masks must be (N, H, W) = {target.shape[:3]} bool, got {np.shape(masks)}")
        with torch.no_grad():
            s, t = self._to_tensor(source), self._to_tensor(target)
            rec, _, _ = net(s, t)
            return float(masked_reconstruction_loss(rec, t, None if masks is None else self._mask_tensor(masks)))

    # ------------------------------------------------------------------ predict
    def _require(self) -> TransporterNet:
        if self._net is None:
            raise RuntimeError("the transporter extractor is not trained: call fit(images, masks=..., "
                               "sequence_ids=...) or TransporterExtractor.load('model.pt') first")
        return self._net

    def predict(self, images: np.ndarray) -> np.ndarray:
        """Keypoints ``(N, K, 2)`` float64 px ``(u, v)`` in the pixels of ``images (N, H, W, 3)`` uint8 RGB.

        Raises:
            RuntimeError: called before :meth:`fit` / :meth:`load`.
            ShapeError: images not ``(N, H, W, 3)`` uint8.
        """
        net = self._require()
        images = _check_images(images)
        h, w = images.shape[1:3]
        with torch_threads(int(self.config["num_threads"]), convolutions=True):
            out = predict_batched(lambda im: net.keypoints(self._to_tensor(im)).numpy(), images,
                                  batch_size=int(self.config["predict_batch"]), module=net)
        mu = np.concatenate(out).astype(np.float64)
        u = (mu[..., 0] + 1) / 2 * w - 0.5
        v = (mu[..., 1] + 1) / 2 * h - 0.5
        return np.stack([u, v], axis=-1)

    # ------------------------------------------------------------------ persistence
    def save(self, path: str | Path) -> None:
        """Write config, weights and fit info to ``path`` (``.pt``; parent folders are created).

        Raises:
            RuntimeError: not trained.
        """
        net = self._require()
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        info = {k: v for k, v in self.fit_info.items()}
        torch.save({"format": CHECKPOINT_FORMAT, "extractor": self.name, "config": dict(self.config),
                    "state_dict": net.state_dict(), "fit_info": info}, path)

    @classmethod
    def load(cls, path: str | Path) -> "TransporterExtractor":
        """Inverse of :meth:`save`.

        Raises:
            DataError: the file is missing, unreadable, or not a transporter checkpoint.
        """
        path = Path(path)
        if not path.is_file():
            raise DataError(f"transporter checkpoint not found: {path}")
        try:
            ck = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as exc:
            raise DataError(f"{path} is not a transporter checkpoint (torch.load failed: {exc}); "
                            f"write one with TransporterExtractor.save") from exc
        if not isinstance(ck, dict) or ck.get("format") != CHECKPOINT_FORMAT:
            fmt = ck.get("format") if isinstance(ck, dict) else type(ck).__name__
            raise DataError(f"{path} is not a transporter checkpoint (format {fmt!r}, expected "
                            f"{CHECKPOINT_FORMAT!r}); write one with TransporterExtractor.save")
        cfg = {k: v for k, v in ck["config"].items() if k in cls.DEFAULTS}
        ext = cls(**cfg)
        net = ext._build()
        try:
            net.load_state_dict(ck["state_dict"])
        except (RuntimeError, KeyError) as exc:
            raise DataError(f"{path}: weights do not match the stored config ({exc})") from exc
        net.eval()
        ext._net = net
        ext.fit_info = dict(ck.get("fit_info") or {})
        return ext


@hookimpl
def softsbi_extractors():
    return [TransporterExtractor]
