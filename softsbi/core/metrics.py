"""Distances between point sets: the paper's bidirectional Chamfer distance, and its one-sided half.

Source: Antonova et al. 2022 (BayesSim-RKHS), Sec. V "distance to ground-truth state":
bidirectional Chamfer distance between point sets (there: HSV-mask pixels; here also
3-D clouds). We use the *symmetric mean nearest-neighbour distance* (not squared), so the
value is in the units of the points (metres for clouds, pixels for masks):

    CD(A, B) = 1/2 * ( mean_{a in A} min_{b in B} |a - b|  +  mean_{b in B} min_{a in A} |a - b| )

The one-sided (directed) Chamfer ``D(A -> B) = mean_{a in A} min_{b in B} |a - b|`` is one of the two
halves; with ``A`` the measurement and ``B`` the simulation it asks only "is every measured point
explained by the simulation?", so a partial measurement (a depth sensor's view) is not penalised for
what it did not see (Fan et al. 2017 call the pair of halves the Chamfer distance's two terms).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from softsbi.core.errors import ShapeError


def chamfer_terms(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """The two one-sided Chamfer terms ``(D(a -> b), D(b -> a))`` of point sets ``a (n, d)`` and ``b (m, d)``:
    mean distance of each point of one set to the nearest point of the other, in the points' units.

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
    return float(dab.mean()), float(dba.mean())


def chamfer(a: np.ndarray, b: np.ndarray) -> float:
    """Bidirectional Chamfer distance between point sets ``a (n, d)`` and ``b (m, d)``.

    Returns:
        The symmetric mean nearest-neighbour distance, in the points' units.

    Raises:
        ShapeError: empty sets or mismatched dimensions.
    """
    ab, ba = chamfer_terms(a, b)
    return 0.5 * (ab + ba)


def one_sided_chamfer(measured: np.ndarray, simulated: np.ndarray) -> float:
    """One-sided Chamfer ``D(measured -> simulated)``: the mean distance of each measured point
    ``(n, d)`` to the nearest simulated point ``(m, d)``, in the points' units (module docstring).

    Raises:
        ShapeError: empty sets or mismatched dimensions.
    """
    return chamfer_terms(measured, simulated)[0]


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



#: a displacement's axes whose magnitude is at least this share of the largest one's are named together: (1.9, 2.0, 0)
#: is "+x and +y alike", never "mostly +y"
DIRECTION_TIE = 2 / 3
#: displacements (cm) below this read as none: they print as 0.0
DIRECTION_NONE_CM = 0.05


def offset_axes(offset_cm: tuple[float, float, float] | np.ndarray) -> list[str]:
    """The dominant axes of a displacement ``(x, y, z)`` (cm), each with its sign: ``["+y"]``, ``["-z (down)"]``, or
    several in axis order when they tie (each at least :data:`DIRECTION_TIE` of the largest: ``["+x", "+y"]``); none
    below :data:`DIRECTION_NONE_CM`."""
    off = np.asarray(offset_cm, float)
    big = float(np.abs(off).max())
    if not np.isfinite(big) or big < DIRECTION_NONE_CM:
        return []
    return [f"{'+-'[int(off[a] < 0)]}{'xyz'[a]}" + ((" (up)" if off[2] > 0 else " (down)") if a == 2 else "")
            for a in range(3) if abs(off[a]) >= DIRECTION_TIE * big]


def offset_direction(offset_cm: tuple[float, float, float] | np.ndarray) -> str:
    """:func:`offset_axes` in words: ``"+y"``, ``"+x and +y"`` (a tie), ``"none"``."""
    axes = offset_axes(offset_cm)
    return "none" if not axes else axes[0] if len(axes) == 1 else f"{', '.join(axes[:-1])} and {axes[-1]}"
