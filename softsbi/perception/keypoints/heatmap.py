"""Supervised keypoint extractor: one Gaussian heatmap per keypoint from a ResNet + FPN decoder.

Sources:
    * Grannen et al., "Untangling Dense Knots by Learning Task-Relevant Keypoints", CoRL 2020;
      Sundaresan et al., ICRA 2020 (code: ``priyasundaresan/keypoints_cls``): a ResNet-34 regressing
      one Gaussian heatmap per keypoint (sigma 6 px at 320x320), trained with a per-pixel binary
      cross-entropy; the keypoint is the argmax of its channel.
    * Antonova et al., "A Bayesian Treatment of Real-to-Sim for Deformable Object Manipulation"
      (BayesSim-RKHS), RA-L 2022: these keypoints (4 cloth corners of the wiping task, treated as
      an unordered set) are the observations of the real-to-sim posterior.

Differences from the papers (CPU, no pretrained weights available here):
    * the encoder is trained from scratch (no ImageNet weights: torchvision is unavailable), at a
      128-px input by default, with width 32 instead of 64 (see :mod:`softsbi.perception.keypoints.nets`);
    * the heatmap is at input / 2 resolution and the argmax is refined to sub-cell precision by the
      probability-weighted centroid of a ``(2r+1)^2`` window around the peak (``refine_radius``);
    * Adam at ``lr = 1e-3`` (cosine decay) instead of the papers' 1e-6, a fine-tuning rate for
      ImageNet-pretrained weights; from scratch, 1e-3 reached 2.7 px mean error on held-out real
      wiping frames within 60 epochs (``benchmarks/bench_heatmap.py``; 1e-6 was not tried);
    * optionally (``order_invariant``) a set-matched loss, since cloth-corner identities are not
      visible on a symmetric cloth; the wiping benchmark uses it.

Registered through ``softsbi_extractors`` as ``heatmap``.
"""
from __future__ import annotations

import copy
import inspect
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from softsbi.core.errors import DataError, ParameterError, ShapeError, closest
from softsbi.core.interfaces import KeypointExtractor
from softsbi.plugins.hookspecs import hookimpl
from softsbi.data.keypoints import check_images, check_keypoints, keypoint_distances
from softsbi.inference.neural_mdn import merge_config
from softsbi.inference.training import fit_early_stopping, minibatches, predict_batched, torch_threads, train_val_split
from softsbi.perception.keypoints.nets import HeatmapNet

#: the cosine learning-rate schedule ends at this fraction of ``lr``
LR_FLOOR_FRACTION = 0.02
#: OpenCV's 8-bit hue range (degrees / 2)
HUE_RANGE = 180
#: grey levels ``[low, high)`` of the border an augmenting affine warp fills in
BORDER_GREY = (60, 200)

__all__ = ["HeatmapExtractor", "augment", "gaussian_heatmaps", "softsbi_extractors"]

FORMAT = "softsbi.heatmap-extractor/1"
#: image size at which ``sigma`` is given (the 320x320 frames of the original configuration)
SIGMA_REFERENCE_PX = 320.0
_MEAN, _STD = 0.5, 0.25  # input normalisation of uint8/255


# ---------------------------------------------------------------------------------------- helpers
def gaussian_heatmaps(points: np.ndarray, height: int, width: int, sigma: float) -> np.ndarray:
    """Gaussian target heatmaps.

    Args:
        points: ``(B, K, 2)`` heatmap-pixel coordinates ``(u, v)`` (cell centres at integers).
        height, width: heatmap size in cells.
        sigma: standard deviation in cells.

    Returns:
        ``(B, K, height, width)`` float32, ``exp(-d^2 / (2 sigma^2))`` (peak 1 at the point).
    """
    p = np.asarray(points, np.float32)
    xs = np.arange(width, dtype=np.float32)
    ys = np.arange(height, dtype=np.float32)
    gx = np.exp(-((xs[None, None, :] - p[..., 0:1]) ** 2) / (2 * sigma ** 2))  # (B, K, W)
    gy = np.exp(-((ys[None, None, :] - p[..., 1:2]) ** 2) / (2 * sigma ** 2))  # (B, K, H)
    return (gy[..., :, None] * gx[..., None, :]).astype(np.float32)


def augment(image: np.ndarray, points: np.ndarray, rng: np.random.Generator, mask: np.ndarray | None = None, *,
            rotate_deg: float = 25.0, scale: tuple[float, float] = (0.8, 1.2), shift: float = 0.12,
            brightness: float = 0.25, contrast: float = 0.25, hue: float = 0.04, saturation: float = 0.3,
            p_affine: float = 0.8, p_colour: float = 0.8, tries: int = 10
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Random affine + colour jitter of one image with consistent keypoints (cv2).

    Affine: rotation ``U(-rotate_deg, rotate_deg)`` and isotropic scale ``U(scale)`` about the image
    centre, translation ``U(-shift, shift)`` of the image size; the uncovered border is filled with
    a random grey (as in the augmented copies of the wiping set). Keypoints inside the image must
    stay inside: parameters that push one out are redrawn (up to ``tries`` times, else no affine).
    Colour: HSV hue shift ``U(-hue, hue)`` of the colour circle, saturation and brightness factors
    ``U(1 -+ saturation)``, ``U(1 -+ brightness)``, contrast ``U(1 -+ contrast)`` about the mean.

    Args:
        image: ``(H, W, 3)`` uint8 RGB.
        points: ``(K, 2)`` px (u, v).
        rng: random generator.
        mask: optional ``(H, W)`` bool, warped with the image (nearest; new border = not ignored).

    Returns:
        ``(image (H, W, 3) uint8, points (K, 2) float64, mask or None)``.
    """

    H, W = image.shape[:2]
    pts = np.asarray(points, np.float64)
    out_img, out_pts, out_mask = image, pts, mask
    if rng.random() < p_affine:
        inside = (pts[:, 0] >= 0) & (pts[:, 0] <= W - 1) & (pts[:, 1] >= 0) & (pts[:, 1] <= H - 1)
        for _ in range(tries):
            M = cv2.getRotationMatrix2D(((W - 1) / 2.0, (H - 1) / 2.0), float(rng.uniform(-rotate_deg, rotate_deg)),
                                        float(rng.uniform(*scale)))
            M[:, 2] += rng.uniform(-shift, shift, 2) * (W, H)
            new = pts @ M[:, :2].T + M[:, 2]
            ok = (new[:, 0] >= 0) & (new[:, 0] <= W - 1) & (new[:, 1] >= 0) & (new[:, 1] <= H - 1)
            if (ok | ~inside).all():
                fill = int(rng.integers(*BORDER_GREY))
                out_img = cv2.warpAffine(image, M, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                                         borderValue=(fill, fill, fill))
                out_pts = new
                if mask is not None:
                    out_mask = cv2.warpAffine(mask.astype(np.uint8), M, (W, H), flags=cv2.INTER_NEAREST,
                                              borderMode=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
                break
    if rng.random() < p_colour:
        hsv = cv2.cvtColor(out_img, cv2.COLOR_RGB2HSV).astype(np.int16)
        hsv[..., 0] = (hsv[..., 0] + int(round(rng.uniform(-hue, hue) * HUE_RANGE))) % HUE_RANGE
        hsv[..., 1] = np.clip(hsv[..., 1] * rng.uniform(1 - saturation, 1 + saturation), 0, 255)
        img = cv2.cvtColor(hsv.astype(np.uint8), cv2.COLOR_HSV2RGB).astype(np.float32)
        img *= rng.uniform(1 - brightness, 1 + brightness)
        m = img.mean()
        img = (img - m) * rng.uniform(1 - contrast, 1 + contrast) + m
        out_img = np.clip(img, 0, 255).astype(np.uint8)
    return out_img, out_pts, out_mask


def _resize_batch(images: np.ndarray, size: int) -> np.ndarray:

    H, W = images.shape[1:3]
    if (H, W) == (size, size):
        return images.copy()
    interp = cv2.INTER_AREA if size < min(H, W) else cv2.INTER_LINEAR
    return np.stack([cv2.resize(im, (size, size), interpolation=interp) for im in images])


def _to_tensor(images: np.ndarray) -> torch.Tensor:
    x = torch.from_numpy(np.ascontiguousarray(images)).permute(0, 3, 1, 2).float()
    return (x / 255.0 - _MEAN) / _STD


def _scale_points(points: np.ndarray, src_hw: tuple[int, int], dst_hw: tuple[int, int]) -> np.ndarray:
    """Map px (u, v) between image sizes, pixel centres at integers: ``u' = (u + .5) W'/W - .5``."""
    (h0, w0), (h1, w1) = src_hw, dst_hw
    out = np.array(points, np.float64, copy=True)
    out[..., 0] = (out[..., 0] + 0.5) * (w1 / w0) - 0.5
    out[..., 1] = (out[..., 1] + 0.5) * (h1 / h0) - 0.5
    return out


def decode_heatmaps(logits: torch.Tensor, refine_radius: int = 2, probabilities: bool = False) -> np.ndarray:
    """Keypoints from heatmaps: argmax of each channel, refined by a local weighted centroid.

    Args:
        logits: ``(B, K, h, w)`` heatmap logits (or probabilities with ``probabilities=True``).
        refine_radius: r; the peak cell is refined to the centroid of ``sigmoid(logits)`` (weights
            minus the window minimum, so a flat background does not pull it to the window centre)
            over the ``(2r+1)^2`` window around it; near the border the window shrinks symmetrically
            (a peak on the border cell stays there). 0 = integer argmax.

    Returns:
        ``(B, K, 2)`` float64 heatmap coordinates ``(u, v)`` (cell centres at integers).
    """
    B, K, h, w = logits.shape
    flat = logits.reshape(B, K, -1)
    idx = flat.argmax(-1)
    v0 = (idx // w).double()
    u0 = (idx % w).double()
    if refine_radius <= 0:
        return torch.stack([u0, v0], -1).numpy()
    r = int(refine_radius)
    prob = logits if probabilities else torch.sigmoid(logits)
    padded = F.pad(prob, (r, r, r, r), value=float("nan"))
    # windows (B, K, 2r+1, 2r+1) around the peak
    offs = torch.arange(-r, r + 1)
    rows = (v0.long()[..., None] + r + offs)  # (B, K, 2r+1)
    cols = (u0.long()[..., None] + r + offs)
    bi = torch.arange(B)[:, None, None, None]
    ki = torch.arange(K)[None, :, None, None]
    win = padded[bi, ki, rows[..., :, None], cols[..., None, :]].double()
    # symmetric window per axis: near the border, shrink the radius so truncation adds no bias
    ru = torch.minimum(u0, (w - 1) - u0).clamp(max=r)[..., None, None]
    rv = torch.minimum(v0, (h - 1) - v0).clamp(max=r)[..., None, None]
    sym = (offs.double().abs()[None, None, None, :] <= ru) & (offs.double().abs()[None, None, :, None] <= rv)
    valid = ~torch.isnan(win) & sym
    win = torch.where(valid, win, torch.zeros_like(win))
    lo = torch.where(valid, win, torch.full_like(win, math.inf)).amin(dim=(-2, -1), keepdim=True)
    wgt = torch.where(valid, (win - lo).clamp_min(0), torch.zeros_like(win))
    tot = wgt.sum(dim=(-2, -1))
    o = offs.double()
    du = (wgt * o[None, None, None, :]).sum(dim=(-2, -1)) / tot.clamp_min(1e-12)
    dv = (wgt * o[None, None, :, None]).sum(dim=(-2, -1)) / tot.clamp_min(1e-12)
    flat_peak = tot <= 1e-12
    du = torch.where(flat_peak, torch.zeros_like(du), du)
    dv = torch.where(flat_peak, torch.zeros_like(dv), dv)
    return torch.stack([u0 + du, v0 + dv], -1).numpy()


# ---------------------------------------------------------------------------------------- extractor
class HeatmapExtractor(KeypointExtractor):
    """Supervised Gaussian-heatmap keypoint extractor (ResNet encoder, FPN decoder).

    Images of any size are resized (stretched) to ``input_size x input_size``; the network outputs
    ``K`` heatmaps at ``input_size / 2``; predictions are mapped back to the caller's pixels.

    Config (``HeatmapExtractor(**options)``; unknown options raise :class:`ParameterError` with a
    did-you-mean):
        input_size: network input side in px, a multiple of 32 (default 128, a CPU budget; the
            papers used 320).
        layers: ResNet blocks per stage (default ``[3, 4, 6, 3]`` = ResNet-34).
        width: first-stage channels (default 32; ResNet uses 64).
        sigma: target Gaussian std in px *of a 320-px image* (default 6, the original
            configuration); the heatmap uses ``sigma * (input_size / 2) / 320`` cells, at least
            ``min_sigma_cells`` (default 1.0).
        loss: ``"bce"`` (default; per-pixel binary cross-entropy with logits against the Gaussian,
            as in the papers; with the head bias initialised to a low heatmap its gradient stays
            informative on the many near-zero pixels) or ``"mse"`` (on ``sigmoid(logits)``; not
            benchmarked).
        epochs: maximum epochs (default 120). batch_size: default 16.
        lr: Adam learning rate (default 1e-3, cosine-decayed to ``lr * 0.02`` over ``epochs``);
            the papers' 1e-6 was for fine-tuning pretrained weights.
        weight_decay: Adam L2 (default 1e-4).
        patience: epochs without improvement of the validation mean pixel error before stopping
            (default 25). min_epochs: default 10.
        val_fraction: share of the training images held out (random frames) for early stopping when
            ``fit`` gets no ``val_images`` (default 0.15); 0 validates on the training images.
        augment: random affine + colour jitter of the training images (default True; see
            :func:`augment`). augment_options: dict of :func:`augment` keyword overrides.
        refine_radius: sub-cell refinement window radius in cells (default 2; 0 = plain argmax).
        order_invariant: treat each frame's K keypoints as an unordered set in the loss: its targets
            are assigned to the K channels by the minimum-loss matching (Hungarian, per frame) before
            the loss (and ``monitor="auto"`` uses the set-matched error). For keypoints whose identity
            is not visible (corners of a symmetric cloth); predictions then come in the network's
            own channel order. Default False (channel k learns keypoint k).
        monitor: validation quantity for early stopping and for the kept weights: ``"mean_px"``
            (index-matched mean error), ``"hungarian_px"`` (set-matched), ``"loss"``, or ``"auto"``
            (default: ``hungarian_px`` with ``order_invariant``, else ``mean_px``).
        outside_margin: keypoints may lie outside their image by this fraction of its size
            (default 0.25, see :func:`~softsbi.data.keypoints.check_keypoints`); such
            targets are clamped to the image border, so the model predicts the nearest visible
            point.
        num_threads: torch threads during fit/predict (default None: leave torch's setting).
        max_seconds: stop training after this wall time (default None).
        predict_batch: images per forward pass in :meth:`predict` (default 32).

    Wiping benchmark config (``benchmarks/bench_heatmap.py``, CPU, ~11 min): the defaults with
    ``order_invariant=True, epochs=100, num_threads=1``.
    """

    name: ClassVar[str] = "heatmap"
    supervised: ClassVar[bool] = True

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        """The default config (a copy)."""
        return {"input_size": 128, "layers": [3, 4, 6, 3], "width": 32, "sigma": 6.0, "min_sigma_cells": 1.0,
                "loss": "bce", "epochs": 120, "batch_size": 16, "lr": 1e-3, "weight_decay": 1e-4, "patience": 25,
                "min_epochs": 10, "val_fraction": 0.15, "augment": True, "augment_options": {},
                "refine_radius": 2, "order_invariant": False, "monitor": "auto", "outside_margin": 0.25,
                "num_threads": None, "max_seconds": None, "predict_batch": 32}

    def __init__(self, **config: Any):
        cfg = merge_config("heatmap", self.defaults(), config, kind="extractor")
        cfg["layers"] = [int(n) for n in cfg["layers"]]
        cfg["augment_options"] = dict(cfg["augment_options"] or {})
        if int(cfg["input_size"]) < 32 or int(cfg["input_size"]) % 32:
            raise ParameterError(f"input_size must be a positive multiple of 32 (e.g. 128), got {cfg['input_size']}")
        if cfg["monitor"] not in ("auto", "mean_px", "hungarian_px", "loss"):
            raise ParameterError(f"monitor must be 'auto', 'mean_px', 'hungarian_px' or 'loss', "
                                 f"got {cfg['monitor']!r}")
        if cfg["loss"] not in ("bce", "mse"):
            raise ParameterError(f"loss must be 'bce' or 'mse', got {cfg['loss']!r}")
        if len(cfg["layers"]) != 4 or min(cfg["layers"]) < 1:
            raise ParameterError(f"layers must be 4 positive block counts (e.g. [3, 4, 6, 3]), got {cfg['layers']}")
        bad = [k for k in cfg["augment_options"] if k not in inspect.signature(augment).parameters
               or k in ("image", "points", "rng", "mask")]
        if bad:
            opts = [k for k in inspect.signature(augment).parameters if k not in ("image", "points", "rng", "mask")]
            raise ParameterError(f"unknown augment option '{bad[0]}'.{closest(bad[0], opts)} "
                                 f"Options: {', '.join(opts)}")
        super().__init__(**cfg)
        self._net: HeatmapNet | None = None
        self._k: int | None = None
        self.fit_info: dict[str, Any] = {}
        #: per-epoch ``{epoch, train_loss, val_loss, val_mean_px, val_hungarian_px, seconds}`` of the last fit
        #: (grows during :meth:`fit`, so a ``progress`` callback can read the validation error)
        self.history: list[dict[str, float]] = []

    # ------------------------------------------------------------------ properties
    @property
    def trained(self) -> bool:
        """Whether :meth:`fit` or :meth:`load` has been called."""
        return self._net is not None

    @property
    def n_keypoints(self) -> int:
        """K (0 before training)."""
        return int(self._k or 0)

    @property
    def heatmap_size(self) -> int:
        """Heatmap side in cells (``input_size / 2``)."""
        return int(self.config["input_size"]) // HeatmapNet.stride

    @property
    def monitor(self) -> str:
        """The early-stopping quantity (``monitor`` with ``"auto"`` resolved)."""
        m = self.config["monitor"]
        if m == "auto":
            return "hungarian_px" if self.config["order_invariant"] else "mean_px"
        return m

    @property
    def sigma_cells(self) -> float:
        """Target Gaussian std in heatmap cells."""
        c = self.config
        return max(float(c["sigma"]) * self.heatmap_size / SIGMA_REFERENCE_PX, float(c["min_sigma_cells"]))

    def _build(self, k: int) -> HeatmapNet:
        c = self.config
        # channels-last: the NHWC uint8 batches map to it without a copy, and oneDNN convolutions are
        # 1.2-1.5x faster in it on CPU
        return HeatmapNet(k, c["layers"], int(c["width"])).to(memory_format=torch.channels_last)

    # ------------------------------------------------------------------ training
    def _targets(self, pts_in: np.ndarray) -> torch.Tensor:
        """Heatmap targets for keypoints in input px ``(B, K, 2)``, clamped to the image."""
        S, h = int(self.config["input_size"]), self.heatmap_size
        p = np.clip(pts_in, 0.0, S - 1.0)
        p = _scale_points(p, (S, S), (h, h))
        return torch.from_numpy(gaussian_heatmaps(p, h, h, self.sigma_cells))

    def _loss(self, logits: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None) -> torch.Tensor:
        """Mean per-pixel loss of ``logits (B, K, h, w)`` against ``target (B, K, h, w)``, optionally
        weighted per pixel by ``weight (B, h, w)``; with ``order_invariant`` each frame's targets are
        first assigned to channels by the minimum-loss matching."""
        if not self.config["order_invariant"]:
            per = self._per_pixel(logits, target)
            if weight is None:
                return per.mean()
            w = weight[:, None].expand_as(per)
            return (per * w).sum() / w.sum().clamp_min(1.0)
        from scipy.optimize import linear_sum_assignment  # heavy (~1 s): only the unordered loss needs it

        per = self._per_pixel(logits[:, :, None], target[:, None])  # (B, K pred, K target, h, w)
        if weight is None:
            cost = per.mean(dim=(-2, -1))
        else:
            wt = weight[:, None, None]
            cost = (per * wt).sum(dim=(-2, -1)) / wt.sum(dim=(-2, -1)).clamp_min(1.0)
        cols = torch.stack([torch.as_tensor(linear_sum_assignment(c.numpy())[1]) for c in cost.detach()])
        return cost.gather(2, cols[..., None]).mean()

    def _per_pixel(self, logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        if self.config["loss"] == "bce":
            logits, target = torch.broadcast_tensors(logits, target)
            return F.binary_cross_entropy_with_logits(logits, target, reduction="none")
        return (torch.sigmoid(logits) - target) ** 2

    def fit(self, images: np.ndarray, keypoints: np.ndarray | None = None, masks: np.ndarray | None = None, *,
            seed: int = 0, progress: Callable[[int, int, float], None] | None = None,
            val_images: np.ndarray | None = None, val_keypoints: np.ndarray | None = None) -> dict[str, Any]:
        """Train the heatmap network (from scratch) on annotated images.

        Args:
            images: ``(N, H, W, 3)`` uint8 RGB, any size (resized to ``input_size``).
            keypoints: ``(N, K, 2)`` px (u, v) of ``images`` (required).
            masks: optional ``(N, H, W)`` bool, True = pixels ignored in the loss.
            seed: seeds the weight init, the validation split, batch order and augmentation.
            progress: ``progress(epoch, max_epochs, train_loss)`` after every epoch.
            val_images, val_keypoints: an explicit validation set (e.g. held-out blocks from
                :func:`~softsbi.data.keypoints.block_split`); otherwise ``val_fraction`` of
                ``images`` (random frames) is held out.

        Returns:
            ``{"epochs", "best_epoch", "train_loss", "val_loss", "val_mean_px", "val_hungarian_px",
            "monitor", "seconds", "n_train", "n_val", "history"}``: losses are mean per-pixel losses,
            ``val_mean_px`` / ``val_hungarian_px`` the validation mean keypoint error (index- /
            set-matched) in the validation images' px, all at the best epoch by ``monitor`` (whose
            weights are kept); ``history`` lists the per-epoch values.

        Raises:
            ShapeError: images not ``(N, H, W, 3)`` uint8; keypoints not ``(N, K, 2)`` for them;
                masks not ``(N, H, W)``; validation set with another K.
            DataError: non-finite keypoints or points outside the image (beyond ``outside_margin``).
            RuntimeError: the loss is non-finite in the first epoch (diverged; the extractor stays untrained).

        Training uses the shared early-stopping loop
        (:func:`~softsbi.inference.training.fit_early_stopping`): Adam with cosine decay, validation
        after every epoch, the weights of the best ``monitor`` epoch (ties: lower ``val_loss``) kept.
        """
        t0 = time.perf_counter()
        c = self.config
        images = check_images(images)
        N, H, W = images.shape[:3]
        kp = check_keypoints(keypoints, N, H, W, float(c["outside_margin"]))
        K = kp.shape[1]
        if masks is not None:
            masks = np.asarray(masks).astype(bool)
            if masks.shape != (N, H, W):
                raise ShapeError(f"masks must be (N, H, W) = {(N, H, W)} bool (True = ignore), got {masks.shape}")
        rng = np.random.default_rng(seed)
        if val_images is not None or val_keypoints is not None:
            if val_images is None or val_keypoints is None:
                raise ShapeError("pass both val_images and val_keypoints, or neither")
            vimg = check_images(val_images, "val_images")
            vkp = check_keypoints(val_keypoints, len(vimg), vimg.shape[1], vimg.shape[2], float(c["outside_margin"]),
                                  "val_keypoints")
            if vkp.shape[1] != K:
                raise ShapeError(f"val_keypoints have K={vkp.shape[1]} but keypoints have K={K}")
            tr_idx = np.arange(N)
        else:
            tr_idx, va = train_val_split(N, float(c["val_fraction"]), rng)
            tr_idx, va = np.sort(tr_idx), np.sort(va)
            if len(va) == 0:
                va = tr_idx
            vimg, vkp = images[va], kp[va]
        S = int(c["input_size"])
        h = self.heatmap_size
        x_tr = _resize_batch(images[tr_idx], S)
        p_tr = _scale_points(kp[tr_idx], (H, W), (S, S))
        m_tr = None
        if masks is not None:
            m_tr = np.stack([cv2.resize(m.astype(np.uint8), (S, S), interpolation=cv2.INTER_NEAREST)
                             for m in masks[tr_idx]]).astype(bool)
        x_va = _to_tensor(_resize_batch(vimg, S))
        t_va = self._targets(_scale_points(vkp, vimg.shape[1:3], (S, S)))
        aug_opts = dict(c["augment_options"])

        def batch_loss(b: np.ndarray) -> torch.Tensor:
            """Loss of the training images ``b`` (augmented with ``rng`` when ``augment``)."""
            imgs, pts, wts = x_tr[b], p_tr[b], None
            if c["augment"]:
                outs = [augment(imgs[i], pts[i], rng, None if m_tr is None else m_tr[b[i]], **aug_opts)
                        for i in range(len(b))]
                imgs = np.stack([o[0] for o in outs])
                pts = np.stack([o[1] for o in outs])
                if m_tr is not None:
                    wts = torch.from_numpy(~np.stack([o[2] for o in outs]))
            elif m_tr is not None:
                wts = torch.from_numpy(~m_tr[b])
            if wts is not None:  # ignore-mask at heatmap resolution (a cell is ignored if all its px are)
                wts = F.adaptive_max_pool2d(wts[:, None].float(), h)[:, 0]
            return self._loss(net(_to_tensor(imgs)), self._targets(pts), wts)

        def validate() -> dict[str, float]:
            val_loss, val_px, val_set_px = self._evaluate(x_va, t_va, vkp, vimg.shape[1:3])
            return {"val_loss": val_loss, "val_mean_px": val_px, "val_hungarian_px": val_set_px}

        with torch_threads(c["num_threads"], convolutions=True):
            torch.manual_seed(seed)
            self._k = K
            self._net = net = self._build(K)
            opt = torch.optim.Adam(net.parameters(), lr=float(c["lr"]), weight_decay=float(c["weight_decay"]))
            max_epochs = int(c["epochs"])
            sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(1, max_epochs),
                                                               eta_min=float(c["lr"]) * LR_FLOOR_FRACTION)
            monitor = self.monitor
            monitor_key = {"mean_px": "val_mean_px", "hungarian_px": "val_hungarian_px", "loss": "val_loss"}[monitor]
            self.history = []
            # batches: a last batch of 1 is merged into the previous one (BatchNorm needs > 1 sample)
            info = fit_early_stopping(
                net, batch_loss, lambda: minibatches(len(tr_idx), int(c["batch_size"]), rng, min_size=2),
                validate=validate, monitor=(monitor_key, "val_loss"), optimizer=opt, scheduler=sched,
                max_epochs=max_epochs, patience=int(c["patience"]), min_epochs=int(c["min_epochs"]),
                max_seconds=c["max_seconds"], progress=progress, history=self.history, t0=t0)
            if info["best_epoch"] == 0:
                self._net, self._k = None, None
                raise RuntimeError(f"extractor 'heatmap' training diverged (non-finite loss) in the first epoch; "
                                   f"try a smaller lr (now {c['lr']})")
        best = info["best"]
        self.fit_info = {"epochs": info["epochs"], "best_epoch": best["epoch"], "train_loss": float(best["train_loss"]),
                         "val_loss": float(best["val_loss"]), "val_mean_px": float(best["val_mean_px"]),
                         "val_hungarian_px": float(best["val_hungarian_px"]), "monitor": monitor,
                         "seconds": time.perf_counter() - t0, "n_train": len(tr_idx), "n_val": len(vimg),
                         "history": self.history}
        return dict(self.fit_info)

    def _evaluate(self, x: torch.Tensor, target: torch.Tensor, true_px: np.ndarray, hw: tuple[int, int]
                  ) -> tuple[float, float, float]:
        """Validation loss and mean px error, index-matched and set-matched (validation images' px)."""
        assert self._net is not None
        net, r = self._net, int(self.config["refine_radius"])

        def loss_and_keypoints(xb: torch.Tensor, tb: torch.Tensor) -> tuple[float, np.ndarray]:
            lg = net(xb)
            return float(self._loss(lg, tb, None)) * len(lg), decode_heatmaps(lg, r)

        out = predict_batched(loss_and_keypoints, x, target, batch_size=int(self.config["predict_batch"]), module=net)
        losses, preds = [o[0] for o in out], [o[1] for o in out]
        h = self.heatmap_size
        pred = _scale_points(np.concatenate(preds), (h, h), hw)
        return (sum(losses) / len(x), float(keypoint_distances(pred, true_px).mean()),
                float(keypoint_distances(pred, true_px, "hungarian").mean()))

    # ------------------------------------------------------------------ inference
    def heatmaps(self, images: np.ndarray) -> np.ndarray:
        """Predicted heatmaps ``(N, K, input_size/2, input_size/2)`` float32 probabilities (sigmoid).

        Raises:
            RuntimeError: not trained. ShapeError: bad images.
        """
        return torch.sigmoid(self._forward(images)).numpy()

    def _forward(self, images: np.ndarray) -> torch.Tensor:
        if self._net is None:
            raise RuntimeError("the heatmap extractor is not trained: train it first with fit(images, keypoints) "
                               "or load a checkpoint with HeatmapExtractor.load(path)")
        images = check_images(images)
        S, net = int(self.config["input_size"]), self._net
        with torch_threads(self.config["num_threads"], convolutions=True):
            outs = predict_batched(lambda im: net(_to_tensor(_resize_batch(im, S))), images,
                                   batch_size=int(self.config["predict_batch"]), module=net)
        return torch.cat(outs)

    def predict(self, images: np.ndarray) -> np.ndarray:
        """Keypoints of ``images (N, H, W, 3)`` uint8 RGB (any size).

        Returns:
            ``(N, K, 2)`` float64 px ``(u, v)`` in the given images' pixels (pixel centres at
            integers): the refined argmax of each heatmap channel, mapped back from the heatmap.

        Raises:
            RuntimeError: called before :meth:`fit` / :meth:`load`.
            ShapeError: images not ``(N, H, W, 3)`` uint8 (greyscale, RGBA, float, single image).
        """
        images = check_images(images) if self._net is not None else images
        logits = self._forward(images)
        h = self.heatmap_size
        pts = decode_heatmaps(logits, int(self.config["refine_radius"]))
        return _scale_points(pts, (h, h), images.shape[1:3])

    # ------------------------------------------------------------------ persistence
    def save(self, path: str | Path) -> None:
        """Write config, K and weights to ``path`` (``torch.save`` of a dict of tensors and plain
        Python values, loadable with ``weights_only=True``).

        Raises:
            RuntimeError: not trained.
        """
        if self._net is None:
            raise RuntimeError("nothing to save: train it first with fit(images, keypoints)")
        info = {k: v for k, v in self.fit_info.items() if k != "history"}
        ckpt = {"format": FORMAT, "config": copy.deepcopy(self.config), "n_keypoints": int(self._k or 0),
                "state_dict": {k: v.detach().cpu().contiguous().clone() for k, v in self._net.state_dict().items()},
                "fit_info": info}
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        torch.save(ckpt, path)

    @classmethod
    def load(cls, path: str | Path) -> HeatmapExtractor:
        """Inverse of :meth:`save` (``torch.load(weights_only=True)``).

        Raises:
            DataError: the file is missing, unreadable, or not a heatmap-extractor checkpoint.
        """
        path = Path(path)
        if not path.is_file():
            raise DataError(f"checkpoint {path} not found; train and save one with HeatmapExtractor.fit / .save")
        try:
            ckpt = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as exc:
            raise DataError(f"{path} is not a readable torch checkpoint: {exc}") from exc
        if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
            raise DataError(f"{path} is not a heatmap-extractor checkpoint (format "
                            f"{ckpt.get('format') if isinstance(ckpt, dict) else type(ckpt).__name__!r}, "
                            f"expected {FORMAT!r})")
        try:
            cfg = {k: v for k, v in ckpt["config"].items() if k in cls.defaults()}
            obj = cls(**cfg)
            obj._k = int(ckpt["n_keypoints"])
            obj._net = obj._build(obj._k)
            obj._net.load_state_dict(ckpt["state_dict"])
        except (KeyError, RuntimeError, ParameterError, TypeError) as exc:
            raise DataError(f"{path}: corrupt heatmap-extractor checkpoint: {exc}") from exc
        obj._net.eval()
        obj.fit_info = dict(ckpt.get("fit_info", {}))
        return obj


@hookimpl
def softsbi_extractors():
    return [HeatmapExtractor]
