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


def local_thickness(clouds: np.ndarray, k: int = 8) -> np.ndarray:
    """Mean local thickness of point clouds: ``(..., P, 3) -> (...)`` m.

    For every point, the covariance of it and its ``k`` nearest neighbours (``min(k, P - 1)``); its smallest
    eigenvalue is the variance across the best-fitting local plane (the surface-variation statistic of
    point-cloud normal estimation, Pauly et al. 2002). The result is the mean over points of its square root.
    A smooth surface sampled densely gives about 0 (its curvature's share only); independent sensor noise of
    standard deviation ``s`` per axis gives about ``s`` for a curve and a little less for a surface, whatever
    the sampling density. The random-Fourier-feature mean embedding hardly sees such noise (it multiplies each
    feature by ``exp(-|w|^2 s^2 / 2)``, under 2 % for 1 cm on a 30 cm cloth at the default bandwidth), so this
    is the summary that makes a noise parameter identifiable (:class:`~softsbi.inference.estimators.RKHSEstimator`'s
    ``frame_thickness``).

    Args:
        clouds: ``(..., P, 3)`` points, m, ``P >= 2``.
        k: neighbours per point.

    Raises:
        ShapeError: not ``(..., P, 3)`` with ``P >= 2``.
    """
    from scipy.spatial import cKDTree  # heavy (~1 s): only the thickness summary needs it
    c = np.asarray(clouds, dtype=np.float64)
    if c.ndim < 2 or c.shape[-1] != 3 or c.shape[-2] < 2:
        raise ShapeError(f"local_thickness needs clouds of shape (..., P, 3) with P >= 2, got {c.shape}")
    lead, P = c.shape[:-2], c.shape[-2]
    kk = max(1, min(int(k), P - 1))
    flat = c.reshape(-1, P, 3)
    out = np.empty(len(flat))
    for i, pts in enumerate(flat):
        _, idx = cKDTree(pts).query(pts, kk + 1)
        nb = pts[idx]  # (P, kk + 1, 3): each point and its neighbours
        x, y, z = (nb - nb.mean(axis=1, keepdims=True)).transpose(2, 0, 1)  # (P, kk + 1) each
        cov = [(u * v).mean(axis=1) for u, v in ((x, x), (y, y), (z, z), (x, y), (y, z), (x, z))]
        out[i] = np.sqrt(np.clip(smallest_eigenvalue_3x3(*cov), 0.0, None)).mean()
    return out.reshape(lead)


def smallest_eigenvalue_3x3(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, e: np.ndarray,
                            f: np.ndarray) -> np.ndarray:
    """The smallest eigenvalue of each symmetric matrix ``[[a, d, f], [d, b, e], [f, e, c]]`` (arrays of one shape),
    in closed form: the trigonometric solution of the characteristic cubic (Smith 1961, "Eigenvalues of a symmetric
    3 x 3 matrix", Commun. ACM 4(4)), a few times faster than a batched ``numpy.linalg.eigvalsh`` on the many small
    matrices of :func:`local_thickness`, and equal to it to rounding."""
    q = (a + b + c) / 3
    p = np.sqrt(((a - q) ** 2 + (b - q) ** 2 + (c - q) ** 2 + 2 * (d * d + e * e + f * f)) / 6)
    s = np.where(p > 0, p, 1.0)  # p = 0: a multiple of the identity, every eigenvalue q
    b11, b22, b33, b12, b23, b13 = (a - q) / s, (b - q) / s, (c - q) / s, d / s, e / s, f / s
    det = b11 * (b22 * b33 - b23 * b23) - b12 * (b12 * b33 - b23 * b13) + b13 * (b12 * b23 - b22 * b13)
    phi = np.arccos(np.clip(det / 2, -1.0, 1.0)) / 3
    lam = np.where(p > 0, q + 2 * p * np.cos(phi + 2 * np.pi / 3), q)
    # one Newton step on the characteristic polynomial: arccos near +-1 loses half the digits of a smallest
    # eigenvalue near 0 (a flat neighbourhood), which a step from that estimate restores
    tr, minors = a + b + c, a * b - d * d + b * c - e * e + a * c - f * f
    det_c = a * (b * c - e * e) - d * (d * c - e * f) + f * (d * e - b * f)
    poly = det_c - lam * (minors - lam * (tr - lam))
    slope = -minors + lam * (2 * tr - 3 * lam)
    return np.where(slope != 0, lam - poly / np.where(slope != 0, slope, 1.0), lam)
