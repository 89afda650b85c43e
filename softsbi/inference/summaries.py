"""BayesSim trajectory summary statistics.

Source: Ramos, Possas, Fox, "BayesSim: adaptive domain randomization via probabilistic
inference for robotics simulators" (RSS 2019), Sec. 4 ("Summary statistics"): with state
differences ``tau_t = s_{t+1} - s_t`` and actions ``a_t``, the features are the
cross-correlations ``<tau_i, a_j> = sum_t tau_t[i] a_t[j]`` for every state dimension ``i``
and action dimension ``j``, plus the mean ``E[tau_i]`` and variance ``Var[tau_i]`` of each
state dimension over time.

Here the state of a frame is the flattened ``(1 + K, 3)`` array (gripper then K cloth
points), and the action of a frame is the gripper displacement ``a_t = g_{t+1} - g_t``.
Because the cloth points are an *unordered* set resampled every frame, ``tau`` of a point
row is the difference of two unrelated points; these summaries are therefore expected to
be weak for point clouds (the motivation of the RKHS embedding in Antonova et al. 2022).
"""
from __future__ import annotations

import numpy as np

from softsbi.core.errors import ShapeError


def n_summary_features(n_points: int, dim: int = 3) -> int:
    """Number of features :func:`bayessim_summaries` returns for ``K = n_points``:
    ``S * A + 2 * S`` with ``S = (1 + K) * dim`` state and ``A = dim`` action dims."""
    S = (1 + n_points) * dim
    return S * dim + 2 * S


def bayessim_summaries(x: np.ndarray) -> np.ndarray:
    """BayesSim summary statistics of trajectories (Ramos et al. 2019, Sec. 4).

    Args:
        x: ``(N, T, 1 + K, 3)`` float, metres: per frame the gripper position (row 0) then
            K cloth points. ``T >= 2``.

    Returns:
        ``(N, F)`` float64 with ``F = S*3 + 2*S``, ``S = (1+K)*3``, laid out as
        ``[cross-correlations (S x 3, row-major: state dim i, action dim j),
        mean of tau (S), variance of tau (S)]``. Units: m^2 for the cross-correlations
        and variances, m for the means.

    Raises:
        ShapeError: ``x`` is not 4-D with last dim 3, or has fewer than 2 frames.
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 4 or x.shape[-1] != 3 or x.shape[2] < 1:
        raise ShapeError(f"bayessim_summaries expects x of shape (N, T, 1+K, 3), got {x.shape}")
    N, T = x.shape[:2]
    if T < 2:
        raise ShapeError(f"bayessim_summaries needs at least 2 frames (T >= 2), got T={T}")
    s = x.reshape(N, T, -1)  # (N, T, S)
    tau = np.diff(s, axis=1)  # (N, T-1, S)
    a = np.diff(x[:, :, 0, :], axis=1)  # (N, T-1, 3) gripper displacement
    cross = np.einsum("nts,nta->nsa", tau, a).reshape(N, -1)
    return np.concatenate([cross, tau.mean(axis=1), tau.var(axis=1)], axis=1)
