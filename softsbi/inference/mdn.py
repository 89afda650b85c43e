"""Mixture density network head with full-covariance Gaussian components.

Source: Bishop, "Mixture Density Networks" (1994); used as the posterior model of
BayesSim (Ramos, Possas, Fox, RSS 2019, Sec. 3-4, eq. 3: ``q(theta | x) = sum_c alpha_c(x)
N(theta; mu_c(x), Sigma_c(x))``) and of BayesSim-RKHS (Antonova et al. 2022, Sec. IV).

Each covariance is parameterised by its Cholesky factor ``L`` (``Sigma = L L^T``) with a
positive diagonal ``softplus(.) + min_scale``, so every output is a valid density; the
negative log-likelihood uses ``log_softmax`` + ``logsumexp`` over components and a
triangular solve, so it is numerically stable.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import torch
from torch import nn
from torch.nn import functional as F

from softsbi.core.distributions import MixtureOfGaussians
from softsbi.core.errors import ShapeError

#: the logits, scale and correlation layers start with their default weights times this (a near-uniform,
#: near-unit mixture at the start)
HEAD_INIT_GAIN = 0.1
_SOFTPLUS_ONE = math.log(math.e - 1.0)  # softplus(_SOFTPLUS_ONE) == 1


@dataclass
class MDNParams:
    """Batched mixture parameters (torch tensors).

    Attributes:
        logits: ``(B, C)`` unnormalised log weights (use ``log_softmax``).
        means: ``(B, C, D)``.
        scale_tril: ``(B, C, D, D)`` lower-triangular, positive diagonal.
    """

    logits: torch.Tensor
    means: torch.Tensor
    scale_tril: torch.Tensor

    @property
    def log_weights(self) -> torch.Tensor:
        return torch.log_softmax(self.logits, dim=-1)

    def affine(self, shift: torch.Tensor, scale: torch.Tensor) -> "MDNParams":
        """Parameters of the pushed-forward mixture ``theta = shift + scale * z`` (elementwise,
        ``shift``/``scale`` of shape ``(D,)``), e.g. to undo the standardisation of ``theta_unit``."""
        return MDNParams(self.logits, self.means * scale + shift, scale[:, None] * self.scale_tril)

    def to_mixtures(self) -> list[MixtureOfGaussians]:
        """One :class:`MixtureOfGaussians` (float64 NumPy) per batch row."""
        w = torch.softmax(self.logits.double(), dim=-1).detach().cpu().numpy()
        m = self.means.detach().double().cpu().numpy()
        L = self.scale_tril.detach().double().cpu().numpy()
        return [MixtureOfGaussians(w[i], m[i], L[i]) for i in range(w.shape[0])]


def mdn_log_prob(params: MDNParams, theta: torch.Tensor) -> torch.Tensor:
    """Log density ``(B,)`` of ``theta (B, D)`` under the per-row mixtures ``params`` (Bishop 1994;
    BayesSim, Ramos et al. 2019, eq. 3).

    ``log sum_c alpha_c N(theta; mu_c, L_c L_c^T)``, computed with a triangular solve and
    ``logsumexp``; matches :meth:`MixtureOfGaussians.log_prob`. ``theta`` are the targets in the
    mixture's units (during training: the standardised ``theta_unit``).

    Raises:
        ShapeError: ``theta`` is not ``(B, D)`` for the mixtures' ``B`` and ``D``.
    """
    B, C, D = params.means.shape
    if theta.shape != (B, D):
        raise ShapeError(f"mdn_log_prob: theta must have shape ({B}, {D}), got {tuple(theta.shape)}")
    diff = (theta[:, None, :] - params.means).unsqueeze(-1)  # (B, C, D, 1)
    z = torch.linalg.solve_triangular(params.scale_tril, diff, upper=False).squeeze(-1)  # (B, C, D)
    logdet = torch.log(torch.diagonal(params.scale_tril, dim1=-2, dim2=-1)).sum(-1)  # (B, C)
    comp = -0.5 * (z * z).sum(-1) - logdet - 0.5 * D * math.log(2 * math.pi)
    return torch.logsumexp(params.log_weights + comp, dim=-1)


def mdn_nll(params: MDNParams, theta: torch.Tensor) -> torch.Tensor:
    """Mean negative log-likelihood (scalar) of ``theta (B, D)``; the MDN training loss.

    Raises:
        ShapeError: as :func:`mdn_log_prob`.
    """
    return -mdn_log_prob(params, theta).mean()


class MDNHead(nn.Module):
    """Linear head mapping features ``(B, H)`` to a C-component full-covariance mixture over ``D`` dims.

    Args:
        in_dim: feature size ``H``.
        out_dim: target dimension ``D``.
        n_components: ``C`` (BayesSim-RKHS posteriors: 4).
        min_scale: floor added to the Cholesky diagonal (in target units), keeps covariances
            positive definite and bounds the density.

    Initialisation: means spread as small random offsets around 0, diagonal scales ~1 and
    equal weights, which suits standardised targets.
    """

    def __init__(self, in_dim: int, out_dim: int, n_components: int = 4, min_scale: float = 1e-3):
        super().__init__()
        if n_components < 1 or out_dim < 1:
            raise ValueError(f"MDNHead needs n_components >= 1 and out_dim >= 1 (got {n_components}, {out_dim})")
        self.D, self.C, self.min_scale = int(out_dim), int(n_components), float(min_scale)
        self.n_off = self.D * (self.D - 1) // 2
        self.logits = nn.Linear(in_dim, self.C)
        self.means = nn.Linear(in_dim, self.C * self.D)
        self.diag = nn.Linear(in_dim, self.C * self.D)
        self.off = nn.Linear(in_dim, self.C * self.n_off) if self.n_off else None
        with torch.no_grad():
            for lin in (self.logits, self.diag) + ((self.off,) if self.off is not None else ()):
                lin.weight.mul_(HEAD_INIT_GAIN)
                lin.bias.zero_()
            self.diag.bias.fill_(_SOFTPLUS_ONE)
        rows, cols = torch.tril_indices(self.D, self.D, offset=-1)
        # one-hot map of the n_off strictly-lower entries into the flattened D x D factor (a matmul, not
        # index_put, so torch.func.vmap can batch the head over ensemble members)
        place = torch.zeros(self.n_off, self.D * self.D)
        place[torch.arange(self.n_off), rows * self.D + cols] = 1.0
        self.register_buffer("_place", place, persistent=False)

    def forward(self, h: torch.Tensor) -> MDNParams:
        return self.assemble(self.logits(h), self.means(h), self.diag(h), self.off(h) if self.off is not None else None)

    def assemble(self, logits: torch.Tensor, means: torch.Tensor, diag: torch.Tensor,
                 off: torch.Tensor | None) -> MDNParams:
        """Mixture parameters from the raw outputs of the four linear layers, each ``(B, ...)``: ``logits
        (B, C)``, ``means (B, C*D)``, ``diag (B, C*D)`` (before ``softplus + min_scale``), ``off
        (B, C*D(D-1)/2)`` (the strictly-lower Cholesky entries; None when ``D = 1``)."""
        B = logits.shape[0]
        means = means.reshape(B, self.C, self.D)
        L = torch.diag_embed(F.softplus(diag).reshape(B, self.C, self.D) + self.min_scale)
        if off is not None:
            L = L + (off.reshape(B, self.C, self.n_off) @ self._place).view(B, self.C, self.D, self.D)
        return MDNParams(logits, means, L)


#: the MLP nonlinearities of :class:`MDNNetwork` by name (the ``activation`` option)
ACTIVATIONS: dict[str, Callable[[], nn.Module]] = {
    "relu": nn.ReLU, "elu": nn.ELU, "silu": nn.SiLU, "tanh": nn.Tanh, "gelu": nn.GELU}


class MDNNetwork(nn.Module):
    """``embedding net -> MLP -> MDNHead`` (BayesSim, Ramos et al. 2019, Sec. 3-4).

    Args:
        features: embedding net mapping a standardised input batch ``(B, ...)`` to ``(B, F)``.
        feat_dim: ``F``.
        hidden: MLP layer widths (empty: the head sits directly on the features).
        out_dim: parameter dimension ``D``.
        n_components: mixture components ``C``.
        activation: one of ``relu, elu, silu, tanh, gelu``.
        min_scale: Cholesky-diagonal floor of the head (standardised target units).
    """

    def __init__(self, features: nn.Module, feat_dim: int, hidden: tuple[int, ...], out_dim: int,
                 n_components: int, activation: str = "relu", min_scale: float = 1e-3):
        super().__init__()
        self.features = features
        layers: list[nn.Module] = []
        last = feat_dim
        for h in hidden:
            layers += [nn.Linear(last, int(h)), ACTIVATIONS[activation]()]
            last = int(h)
        self.mlp = nn.Sequential(*layers)
        self.head = MDNHead(last, out_dim, n_components, min_scale)

    def forward(self, z: torch.Tensor, embedded: bool = False) -> MDNParams:
        """Mixture parameters (standardised target units) of a standardised batch ``z (B, ...)``, or of
        its embedding-net features ``z (B, F)`` when ``embedded`` (the frozen-embedding training phase)."""
        return self.head(self.mlp(z if embedded else self.features(z)))
