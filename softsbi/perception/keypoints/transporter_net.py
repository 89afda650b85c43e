"""The Transporter network and its building blocks (Kulkarni et al., "Unsupervised Learning of Object Keypoints
for Perception and Control", NeurIPS 2019, Sec. 3): the spatial softmax, the Gaussian keypoint maps, the
transport operation, the masked reconstruction loss, the sampling of training pairs, and
:class:`TransporterNet`. The extractor that trains and applies it is
:class:`~softsbi.perception.keypoints.transporter.TransporterExtractor` (the model is described there).
"""
from __future__ import annotations

import cv2
import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from softsbi.core.errors import ShapeError

__all__ = ["TransporterNet", "grid_coords", "transport", "spatial_softmax", "gaussian_maps",
           "masked_reconstruction_loss", "sample_pairs", "keypoints_in_mask"]

#: the encoders' downsampling factor: features and keypoint maps are ``S / STRIDE`` on a side
STRIDE = 4



# --------------------------------------------------------------------------------------------
# building blocks (pure functions, tested on their own)
# --------------------------------------------------------------------------------------------
def grid_coords(h: int, w: int, device: torch.device | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Normalised centres of an ``h x w`` grid: ``xs (w,)``, ``ys (h,)`` in ``(-1, 1)``, cell ``j`` at
    ``(2 j + 1) / n - 1`` (the image spans ``[-1, 1]``, as ``align_corners=False``)."""
    xs = (2 * torch.arange(w, dtype=torch.float32, device=device) + 1) / w - 1
    ys = (2 * torch.arange(h, dtype=torch.float32, device=device) + 1) / h - 1
    return xs, ys


def spatial_softmax(logits: torch.Tensor) -> torch.Tensor:
    """Expected coordinates of a softmax over each map.

    Args:
        logits: ``(B, K, h, w)`` keypoint-network outputs.

    Returns:
        ``(B, K, 2)`` normalised ``(x, y)`` in ``[-1, 1]`` (x along columns, y along rows).
    """
    b, k, h, w = logits.shape
    p = torch.softmax(logits.reshape(b, k, h * w), dim=-1).reshape(b, k, h, w)
    xs, ys = grid_coords(h, w, logits.device)
    x = (p.sum(2) * xs).sum(-1)
    y = (p.sum(3) * ys).sum(-1)
    return torch.stack([x, y], dim=-1)


def gaussian_maps(mu: torch.Tensor, h: int, w: int, std: float) -> torch.Tensor:
    """Isotropic Gaussians with peak 1 centred on keypoints.

    Args:
        mu: ``(B, K, 2)`` normalised ``(x, y)``.
        h, w: grid size.
        std: standard deviation in normalised units (image spans ``[-1, 1]``; 0.1 = 5 % of the side).

    Returns:
        ``(B, K, h, w)`` with ``H = exp(-|p - mu|^2 / (2 std^2))``.
    """
    xs, ys = grid_coords(h, w, mu.device)
    gx = torch.exp(-(xs[None, None, :] - mu[..., 0:1]) ** 2 / (2 * std ** 2))  # (B, K, w)
    gy = torch.exp(-(ys[None, None, :] - mu[..., 1:2]) ** 2 / (2 * std ** 2))  # (B, K, h)
    return gy[..., :, None] * gx[..., None, :]


def transport(phi_s: torch.Tensor, phi_t: torch.Tensor, h_s: torch.Tensor, h_t: torch.Tensor) -> torch.Tensor:
    """The transport operation (Kulkarni et al. 2019, Eq. 1), applied keypoint by keypoint.

    Starting from ``out = phi_s``, for ``k = 1..K``:
    ``out = (1 - h_s[:, k]) * (1 - h_t[:, k]) * out + h_t[:, k] * phi_t``.

    Properties (tested): where every ``h_s, h_t`` is 0 the output is ``phi_s``; where ``h_t[:, K-1]`` is 1
    it is ``phi_t``; with ``K = 1`` it is exactly the paper's
    ``(1 - H_s)(1 - H_t) Phi_s + H_t Phi_t``; and for binary maps with ``h_s == h_t``,
    ``phi_s == phi_t`` it is the identity.

    Args:
        phi_s, phi_t: ``(B, C, h, w)`` source / target features.
        h_s, h_t: ``(B, K, h, w)`` source / target Gaussian maps in ``[0, 1]``.

    Returns:
        ``(B, C, h, w)`` transported features.

    Raises:
        ShapeError: mismatching shapes.
    """
    if phi_s.shape != phi_t.shape or h_s.shape != h_t.shape or phi_s.ndim != 4 or h_s.ndim != 4 \
            or phi_s.shape[0] != h_s.shape[0] or phi_s.shape[2:] != h_s.shape[2:]:
        raise ShapeError(f"transport needs phi (B, C, h, w) x2 and H (B, K, h, w) x2 on the same grid; got "
                         f"phi_s {tuple(phi_s.shape)}, phi_t {tuple(phi_t.shape)}, H_s {tuple(h_s.shape)}, "
                         f"H_t {tuple(h_t.shape)}")
    out = phi_s
    for k in range(h_s.shape[1]):
        s, t = h_s[:, k:k + 1], h_t[:, k:k + 1]
        out = (1 - s) * (1 - t) * out + t * phi_t
    return out


def masked_reconstruction_loss(pred: torch.Tensor, target: torch.Tensor,
                               ignore: torch.Tensor | None = None) -> torch.Tensor:
    """Mean squared error over the pixels that are not ignored.

    Args:
        pred, target: ``(B, 3, S, S)`` images (any consistent scale).
        ignore: ``(B, S, S)`` bool/float, 1 (True) = the pixel contributes nothing (value *and*
            gradient are independent of ``pred``/``target`` there). None: all pixels count.

    Returns:
        Scalar: ``sum_w (pred - target)^2 / (3 * sum_w)``, ``w = 1 - ignore``; 0 when every pixel of the
        batch is ignored.
    """
    if ignore is None:
        return F.mse_loss(pred, target)
    w = (1.0 - ignore.to(pred.dtype))[:, None]
    err = torch.where(w > 0, pred - target, torch.zeros((), dtype=pred.dtype))
    return (w * err ** 2).sum() / (3.0 * w.sum()).clamp_min(1.0)


def sample_pairs(sequence_ids: np.ndarray, max_gap: int, rng: np.random.Generator,
                 index: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One (source, target) pair per target frame, both from the same sequence.

    Frames are assumed to be in temporal order within each sequence. The source is drawn uniformly among
    the frames of the target's sequence (restricted to ``index``) at most ``max_gap`` positions away and
    different from the target when the sequence has another frame in reach.

    Args:
        sequence_ids: ``(N,)`` sequence label of every frame.
        max_gap: largest ``|source - target|`` in frames (>= 1).
        rng: random generator.
        index: frames that may be used (default all), e.g. the training split.

    Returns:
        ``(src, tgt)`` int arrays of frame indices, ``tgt`` = ``index`` in order.
    """
    sequence_ids = np.asarray(sequence_ids)
    index = np.arange(len(sequence_ids)) if index is None else np.asarray(index, dtype=np.int64)
    rank = np.empty(len(sequence_ids), dtype=np.int64)  # position of each frame within its sequence
    for sid in np.unique(sequence_ids):
        members = np.flatnonzero(sequence_ids == sid)
        rank[members] = np.arange(len(members))
    src = np.empty(len(index), dtype=np.int64)
    seq_idx = sequence_ids[index]
    for sid in np.unique(seq_idx):
        where = np.flatnonzero(seq_idx == sid)
        frames = index[where]
        for p, f in zip(where, frames):
            cand = frames[np.abs(rank[frames] - rank[f]) <= max_gap]
            if len(cand) > 1:
                cand = cand[cand != f]
            src[p] = cand[rng.integers(len(cand))]
    return src, index.astype(np.int64)


def keypoints_in_mask(keypoints: np.ndarray, masks: np.ndarray, dilate: int = 0) -> float:
    """Fraction of keypoints that fall on a True pixel of their frame's mask.

    Args:
        keypoints: ``(N, K, 2)`` px ``(u, v)`` = (column, row), pixel centres at integers.
        masks: ``(N, H, W)`` bool, e.g. the cloth (``segmentation == SEG_OBJECT``).
        dilate: grow each mask by this many pixels (square structuring element) first; 0 = none.

    Returns:
        Fraction in ``[0, 1]``; keypoints outside the image or non-finite count as outside.

    Raises:
        ShapeError: mismatching shapes.
    """
    kp = np.asarray(keypoints, dtype=np.float64)
    m = np.asarray(masks).astype(bool)
    if kp.ndim != 3 or kp.shape[-1] != 2 or m.ndim != 3 or len(m) != len(kp):
        raise ShapeError(f"keypoints must be (N, K, 2) and masks (N, H, W) with the same N; got "
                         f"{kp.shape} and {m.shape}")
    if kp.size == 0:
        return float("nan")
    if dilate > 0:
        ker = np.ones((2 * dilate + 1, 2 * dilate + 1), np.uint8)
        m = np.stack([cv2.dilate(f.astype(np.uint8), ker) > 0 for f in m])
    n, h, w = m.shape
    with np.errstate(invalid="ignore"):
        col = np.rint(kp[..., 0])
        row = np.rint(kp[..., 1])
    ok = np.isfinite(col) & np.isfinite(row) & (col >= 0) & (col < w) & (row >= 0) & (row < h)
    frame = np.broadcast_to(np.arange(n)[:, None], ok.shape)
    hit = np.zeros(ok.shape, dtype=bool)
    hit[ok] = m[frame[ok], row[ok].astype(int), col[ok].astype(int)]
    return float(hit.mean())


# --------------------------------------------------------------------------------------------
# network
# --------------------------------------------------------------------------------------------
def _encoder(out_ch: int, hidden: int) -> nn.Sequential:
    """``(B, 3, S, S) -> (B, out_ch, S/4, S/4)``: conv5x5/2, conv3x3, conv3x3/2, conv3x3 (ReLU)."""
    return nn.Sequential(
        nn.Conv2d(3, hidden // 2, 5, stride=2, padding=2), nn.ReLU(),
        nn.Conv2d(hidden // 2, hidden, 3, padding=1), nn.ReLU(),
        nn.Conv2d(hidden, hidden, 3, stride=2, padding=1), nn.ReLU(),
        nn.Conv2d(hidden, out_ch, 3, padding=1),
    )


class TransporterNet(nn.Module):
    """Feature encoder ``Phi``, keypoint network ``Psi`` and decoder (Kulkarni et al. 2019, Sec. 3).

    Args:
        n_keypoints: K.
        channels: feature channels C of ``Phi``.
        hidden: width of the conv stacks.
        std: Gaussian std of the keypoint maps, normalised units (image spans ``[-1, 1]``).
    """

    def __init__(self, n_keypoints: int, channels: int, hidden: int, std: float):
        super().__init__()
        self.std = float(std)
        self.phi = nn.Sequential(_encoder(channels, hidden), nn.ReLU())
        self.psi = nn.Sequential(_encoder(hidden, hidden), nn.ReLU(), nn.Conv2d(hidden, n_keypoints, 1))
        self.decoder = nn.Sequential(
            nn.Conv2d(channels, hidden, 3, padding=1), nn.ReLU(),
            nn.Upsample(scale_factor=2, mode="bilinear", align_corners=False),
            nn.Conv2d(hidden, hidden, 3, padding=1), nn.ReLU(),
            nn.Upsample(scale_factor=2, mode="bilinear", align_corners=False),
            nn.Conv2d(hidden, hidden // 2, 3, padding=1), nn.ReLU(),
            nn.Conv2d(hidden // 2, 3, 3, padding=1),
        )

    def keypoints(self, x: torch.Tensor) -> torch.Tensor:
        """``x (B, 3, S, S)`` in ``[-0.5, 0.5]`` -> keypoints ``(B, K, 2)`` normalised ``(x, y)``."""
        return spatial_softmax(self.psi(x))

    def forward(self, source: torch.Tensor, target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Reconstruct ``target`` from ``source``.

        Args:
            source, target: ``(B, 3, S, S)`` in ``[-0.5, 0.5]``.

        Returns:
            ``(reconstruction (B, 3, S, S), mu_s (B, K, 2), mu_t (B, K, 2))``.
        """
        b = source.shape[0]
        both = torch.cat([source, target])
        phi = self.phi(both)
        mu = spatial_softmax(self.psi(both))
        h, w = phi.shape[-2:]
        hm = gaussian_maps(mu, h, w, self.std)
        out = transport(phi[:b], phi[b:], hm[:b], hm[b:])
        return self.decoder(out), mu[:b], mu[b:]
