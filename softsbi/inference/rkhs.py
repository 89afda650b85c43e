"""RKHS-net: a trainable kernel mean embedding of unordered point sets.

Source: Antonova, Yang, Sutanto, Ramos, Kragic, "A Bayesian Treatment of Real-to-Sim for
Deformable Object Manipulation" (RA-L 2022), Sec. IV ("RKHS-net"), built on the random
Fourier features of Rahimi & Recht, "Random Features for Large-Scale Kernel Machines"
(NeurIPS 2007), which approximate the Gaussian (RBF) kernel

    k(p, p') = exp(-||p - p'||^2 / (2 sigma^2))  ~=  phi(p) . phi(p'),
    phi(p) = sqrt(1/M) [cos(W p / sigma), sin(W p / sigma)],  W (M, d) ~ N(0, I).

Averaging ``phi`` over the K points of a set gives the empirical kernel mean embedding
``mu_P = 1/K sum_k phi(p_k)`` of the point distribution: it does not depend on the order
of the points (nor on K), and two sets are close in that space iff their kernel MMD is
small. Following the paper, the frequencies ``W`` and the bandwidth ``sigma`` are trained
end-to-end with the rest of the network (``sigma`` is log-parameterised to stay positive).
"""
from __future__ import annotations

import math

import torch
from torch import nn

from softsbi.core.errors import ShapeError


class _RFFMean(torch.autograd.Function):
    """``mean_k [cos(p_k . Ws), sin(p_k . Ws)]`` with a hand-written backward that keeps only
    ``cos``/``sin`` (about 2x faster and lighter than autograd through ``cat``/``mean``).

    Written in the ``setup_context`` form with ``generate_vmap_rule`` so that ``torch.func.vmap``
    can batch it (the ensemble of :mod:`softsbi.inference.estimators` trains its members as one
    vmapped network); ``cos``/``sin`` are returned as extra non-differentiable outputs so the
    backward can reuse them (the pattern of torch's "Extending torch.func" notes). (Measured and
    dropped: one ``sin`` over ``[p . Ws + pi/2, p . Ws]`` with a backward through ``cs^T @ p``
    was ~1.6x slower: the batched small matmuls cost more than the elementwise products.)"""

    generate_vmap_rule = True

    @staticmethod
    def forward(points: torch.Tensor, Ws: torch.Tensor):  # type: ignore[override]
        # one (N, d) @ (d, M) product (also under vmap: a bmm over the members, not over every set)
        proj = (points.reshape(-1, points.shape[-1]) @ Ws.transpose(-1, -2)).reshape(points.shape[:-1] + (-1,))
        c, s = torch.cos(proj), torch.sin(proj)  # (..., K, M)
        return torch.cat([c.mean(-2), s.mean(-2)], dim=-1), c, s

    @staticmethod
    def setup_context(ctx, inputs, output):  # type: ignore[override]
        points, Ws = inputs
        _, c, s = output
        ctx.mark_non_differentiable(c, s)
        ctx.save_for_backward(points, Ws, c, s)

    @staticmethod
    def backward(ctx, grad: torch.Tensor, _gc=None, _gs=None):  # type: ignore[override]
        points, Ws, c, s = ctx.saved_tensors
        M, K = c.shape[-1], c.shape[-2]
        gc = grad[..., :M].unsqueeze(-2) / K
        gs = grad[..., M:].unsqueeze(-2) / K
        gproj = c * gs - s * gc  # d out / d proj, (..., K, M)
        g_points = gproj @ Ws if ctx.needs_input_grad[0] else None
        g_W = gproj.reshape(-1, M).t() @ points.reshape(-1, points.shape[-1]) if ctx.needs_input_grad[1] else None
        return g_points, g_W


def rff_mean_embedding(points: torch.Tensor, W: torch.Tensor, sigma: torch.Tensor | float,
                       mask: torch.Tensor | None = None) -> torch.Tensor:
    """Random-Fourier-feature kernel mean embedding of point sets (functional form).

    Args:
        points: ``(..., K, d)`` point sets (any leading batch dims), in the units the
            bandwidth refers to (normally standardised coordinates).
        W: ``(M, d)`` frequencies.
        sigma: positive bandwidth (scalar tensor or float), same units as ``points``.
        mask: optional ``(..., K)`` weights (1 = point present, 0 = padding); the mean is
            taken over the present points only.

    Returns:
        ``(..., 2M)``: ``sqrt(1/M) * mean_k [cos(W p_k / sigma), sin(W p_k / sigma)]``.
    """
    M = W.shape[0]
    if mask is None:
        return _RFFMean.apply(points, W / sigma)[0] * math.sqrt(1.0 / M)
    proj = points @ (W.t() / sigma)  # (..., K, M)
    feats = torch.cat([torch.cos(proj), torch.sin(proj)], dim=-1)  # (..., K, 2M)
    m = mask.to(feats.dtype).unsqueeze(-1)
    emb = (feats * m).sum(dim=-2) / m.sum(dim=-2).clamp_min(1.0)
    return emb * math.sqrt(1.0 / M)


class RKHSNet(nn.Module):
    """Trainable RKHS mean-embedding layer (Antonova et al. 2022, Sec. IV).

    Maps point sets ``(B, T, K, d)`` (or any ``(..., K, d)``) to ``(B, T, 2M)``, one kernel
    mean embedding per set; the output is invariant to the order of the K points.

    Args:
        in_dim: point dimension ``d`` (3 for 3D points).
        n_features: number of random frequencies ``M`` (output has ``2M`` entries).
        sigma: initial bandwidth, in the units of the input points. With points standardised
            to unit variance per coordinate, ``sigma = 1`` is a kernel about as wide as the
            object itself; smaller values resolve finer shape detail.
        learn_frequencies: train ``W`` (paper: yes).
        learn_bandwidth: train ``log sigma`` (paper: yes).
        generator: optional ``torch.Generator`` for drawing ``W`` (else the global RNG).

    Parameters:
        W: ``(M, d)``, initialised ``~ N(0, I)``.
        log_sigma: scalar, ``log`` of the bandwidth.

    Raises:
        ShapeError: in :meth:`forward` if the last input dimension is not ``d``.
    """

    def __init__(self, in_dim: int = 3, n_features: int = 64, sigma: float = 1.0,
                 learn_frequencies: bool = True, learn_bandwidth: bool = True,
                 generator: torch.Generator | None = None):
        super().__init__()
        if n_features < 1 or in_dim < 1:
            raise ValueError(f"RKHSNet needs n_features >= 1 and in_dim >= 1 (got {n_features}, {in_dim})")
        if not sigma > 0:
            raise ValueError(f"RKHSNet bandwidth sigma must be > 0 (got {sigma})")
        self.in_dim = int(in_dim)
        self.n_features = int(n_features)
        W = torch.randn(self.n_features, self.in_dim, generator=generator)
        self.W = nn.Parameter(W, requires_grad=learn_frequencies)
        self.log_sigma = nn.Parameter(torch.tensor(math.log(sigma)), requires_grad=learn_bandwidth)

    @property
    def sigma(self) -> torch.Tensor:
        """Current bandwidth (positive scalar tensor)."""
        return self.log_sigma.exp()

    @property
    def out_dim(self) -> int:
        return 2 * self.n_features

    def forward(self, points: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """Mean embedding ``(..., 2M)`` of ``points (..., K, d)``; see :func:`rff_mean_embedding`."""
        if points.shape[-1] != self.in_dim or points.dim() < 2:
            raise ShapeError(f"RKHSNet expects points of shape (..., K, {self.in_dim}), got {tuple(points.shape)}")
        return rff_mean_embedding(points, self.W, self.sigma, mask)

    def extra_repr(self) -> str:
        return f"in_dim={self.in_dim}, n_features={self.n_features}, sigma={float(self.sigma):.3g}"


class RKHSFrameFeatures(nn.Module):
    """Per-frame RKHS-net embedding of the points, concatenated with the gripper, flattened.

    Input ``(B, T, 1+K, 3)`` standardised states (row 0 gripper); output
    ``(B, T * (2M + 3))``, plus 9 per frame with ``moments`` (each frame's :func:`point_moments`)
    and 1 with ``thickness`` (then row 1 holds the frame's log thickness in its first entry and the
    points follow: ``(B, T, 2+K, 3)``, :meth:`~softsbi.inference.estimators.RKHSEstimator.summary_statistics`). One
    :class:`RKHSNet` is shared by all frames (Antonova et al. 2022, Sec. IV),
    so the output is invariant to the order of the K points within each frame, and K may differ
    between fit and use.
    """

    def __init__(self, n_features: int = 32, sigma: float = 0.5, learn: bool = True, batch_norm: bool = False,
                 n_frames: int | None = None, moments: bool = False, thickness: bool = False):
        super().__init__()
        self.rkhs = RKHSNet(3, n_features, sigma, learn_frequencies=learn, learn_bandwidth=learn)
        self.moments, self.thickness = bool(moments), bool(thickness)
        per_frame = 2 * n_features + 3 + (9 if self.moments else 0) + (1 if self.thickness else 0)
        self.norm = nn.BatchNorm1d(n_frames * per_frame) if batch_norm and n_frames else None

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        pts = z[:, :, 2:, :] if self.thickness else z[:, :, 1:, :]
        parts = [self.rkhs(pts), z[:, :, 0, :]]  # (B, T, 2M), (B, T, 3)
        if self.moments:
            parts.append(point_moments(pts))  # (B, T, 9)
        if self.thickness:
            parts.append(z[:, :, 1, :1])  # (B, T, 1): the frame's log thickness (RKHSEstimator.summary_statistics)
        f = torch.cat(parts, dim=-1).flatten(1)
        return self.norm(f) if self.norm is not None else f


#: index pairs of the upper triangle of a 3 x 3 matrix (xx, xy, xz, yy, yz, zz)
_UPPER = torch.triu_indices(3, 3)


def point_moments(points: torch.Tensor) -> torch.Tensor:
    """First and raw second moments of each point set: ``(..., K, 3) -> (..., 9)``, ``mean_k p_k`` (3) and the
    upper triangle of ``mean_k p_k p_k^T`` (6), in the units of ``points``.

    They are the mean embedding under the polynomial kernel of degree 2 (centroid and spread of the cloud per
    frame). Raw, not central, moments: their mean over a uniform random subset of the points is an unbiased
    estimate of their mean over all of them, as the random-Fourier-feature embedding's is
    (:meth:`~softsbi.inference.estimators.RKHSEstimator.training_view`)."""
    second = points.unsqueeze(-1) * points.unsqueeze(-2)  # (..., K, 3, 3)
    return torch.cat([points.mean(-2), second[..., _UPPER[0], _UPPER[1]].mean(-2)], dim=-1)
