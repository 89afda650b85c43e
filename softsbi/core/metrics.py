"""Distances between point sets: the paper's bidirectional Chamfer distance.

Source: Antonova et al. 2022 (BayesSim-RKHS), Sec. V "distance to ground-truth state":
bidirectional Chamfer distance between point sets (there: HSV-mask pixels; here also
3-D clouds). We use the *symmetric mean nearest-neighbour distance* (not squared), so the
value is in the units of the points (metres for clouds, pixels for masks):

    CD(A, B) = 1/2 * ( mean_{a in A} min_{b in B} |a - b|  +  mean_{b in B} min_{a in A} |a - b| )
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from softsbi.core.errors import ShapeError


def chamfer(a: np.ndarray, b: np.ndarray) -> float:
    """Bidirectional Chamfer distance between point sets ``a (n, d)`` and ``b (m, d)``.

    Returns:
        The symmetric mean nearest-neighbour distance, in the points' units.

    Raises:
        ShapeError: empty sets or mismatched dimensions.
    """
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise ShapeError(f"chamfer needs (n, d) and (m, d) arrays with the same d; got {a.shape} and {b.shape}")
    if len(a) == 0 or len(b) == 0:
        raise ShapeError("chamfer of an empty point set is undefined")
    dab, _ = cKDTree(b).query(a)
    dba, _ = cKDTree(a).query(b)
    return 0.5 * (float(dab.mean()) + float(dba.mean()))


def chamfer_per_frame(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Chamfer distance per frame between two sequences of point sets.

    Args:
        a: ``(T, n, d)`` or a list of ``T`` arrays ``(n_t, d)``.
        b: ``(T, m, d)`` or a list of ``T`` arrays.

    Returns:
        ``(T,)`` distances in the points' units.
    """
    if len(a) != len(b):
        raise ShapeError(f"sequences have different frame counts: {len(a)} vs {len(b)}")
    return np.array([chamfer(x, y) for x, y in zip(a, b)])


def directed_nn_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """For each point of ``a (n, d)`` its distance ``(n,)`` to the nearest point of ``b (m, d)``.

    Used by the posterior predictive check to say *where* a model misses the measurement.
    """
    d, _ = cKDTree(np.asarray(b, float)).query(np.asarray(a, float))
    return d


def describe_change(before: float, after: float) -> str:
    """A relative change in words: ``"37% lower"``, ``"12% higher"`` or ``"unchanged"`` (never a
    negative "lower"); ``"n/a"`` when ``before`` is zero or not finite."""
    if not (np.isfinite(before) and np.isfinite(after)) or before == 0:
        return "n/a"
    ch = after / before - 1
    if round(abs(ch) * 100) == 0:
        return "unchanged"
    return f"{abs(ch) * 100:.0f}% {'lower' if ch < 0 else 'higher'}"
