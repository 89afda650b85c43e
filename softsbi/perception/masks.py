"""HSV colour masks and the bidirectional mask Chamfer distance.

These implement the image-space evaluation of BayesSim-RKHS (Antonova et al. 2022): segment the
cloth in real and simulated frames by colour (HSV thresholds), then compare the masks frame by
frame with a bidirectional Chamfer distance in pixels and average over time.

HSV follows OpenCV: ``H`` in 0..179 (degrees / 2), ``S`` and ``V`` in 0..255.

Default cloth thresholds (:data:`CLOTH_HSV`, ``H in [35, 90]``, ``S >= 45``, ``60 <= V <= 215``)
were chosen on the real wiping images (``shared/data/wiping_keypoints``, every 4th of the 449
frames; cloth = inside the keypoint quadrilateral eroded by 3 px) and hold the rendered cloth:

* real cloth (green pot-holder): H 62-103 (1st-99th percentile, median 71; RGB about
  (100, 145, 120)), S 43-230, V 50-228; rendered cloth (:class:`~softsbi.core.camera.RenderStyle`
  ``(112, 150, 86)``): H 48, S 109, V 150, down to V ~70 on slopes facing away from the light;
* excluded: salmon table H 172-179 and 0-1; white arm H 88-95 with V >= 217 (hence ``V <= 215``);
  black gripper V 46-99 at S 157-207 (mostly under ``V >= 60``, the rest removed by the opening);
  purple augmentation borders H ~146; blue marker H ~105.

Result: 90 % of the cloth pixels, clean masks on frames 0-280 by eye (3x3 opening against
speckle). Known misses: the flat grey-green fill borders of some rotated (augmented) frames
(e.g. 114, 162: H 37-80, S 45-65) are taken for cloth, and strongly colour-jittered frames (100,
260) are detected only in patches.
"""
from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

from softsbi.core.errors import DataError, ShapeError

#: (lo, hi) OpenCV-HSV bounds of the green cloth (real wiping images and rendered frames)
CLOTH_HSV_LO = (35, 45, 60)
CLOTH_HSV_HI = (90, 255, 215)
CLOTH_HSV = (CLOTH_HSV_LO, CLOTH_HSV_HI)


def _check_images(images: np.ndarray) -> np.ndarray:
    a = np.asarray(images)
    if a.ndim < 3 or a.shape[-1] != 3:
        hint = " (4 channels: drop alpha with images[..., :3])" if a.ndim >= 3 and a.shape[-1] == 4 else ""
        raise ShapeError(f"images must be (..., H, W, 3) RGB, got shape {a.shape}{hint}")
    if a.dtype != np.uint8:
        raise DataError(f"images must be uint8 RGB (0-255), got dtype {a.dtype}; convert with "
                        f"(img * 255).round().astype(np.uint8) for floats in [0, 1]")
    if a.shape[-3] < 1 or a.shape[-2] < 1:
        raise ShapeError(f"images must have H, W >= 1, got {a.shape}")
    return a


def _check_bounds(lo: Sequence[int], hi: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    lo_a, hi_a = np.asarray(lo, dtype=int), np.asarray(hi, dtype=int)
    if lo_a.shape != (3,) or hi_a.shape != (3,):
        raise ShapeError(f"lo and hi must be (h, s, v) triples, got {lo!r} and {hi!r}")
    if not (0 <= lo_a[0] <= 179 and 0 <= hi_a[0] <= 179):
        raise DataError(f"hue bounds must be in 0..179 (OpenCV HSV), got {lo_a[0]} and {hi_a[0]}")
    if np.any(lo_a[1:] < 0) or np.any(hi_a[1:] > 255) or np.any(lo_a[1:] > hi_a[1:]):
        raise DataError(f"saturation/value bounds must satisfy 0 <= lo <= hi <= 255, got lo={tuple(lo_a)}, "
                        f"hi={tuple(hi_a)}")
    return lo_a, hi_a


def hsv_mask(images: np.ndarray, lo: Sequence[int] = CLOTH_HSV_LO, hi: Sequence[int] = CLOTH_HSV_HI,
             open_px: int = 3) -> np.ndarray:
    """Pixels whose OpenCV-HSV colour lies in ``[lo, hi]``.

    Args:
        images: ``(..., H, W, 3)`` uint8 RGB (one image or any batch shape).
        lo, hi: ``(h, s, v)`` bounds, inclusive; H in 0..179, S and V in 0..255. If ``lo_h > hi_h``
            the hue range wraps around red: ``h >= lo_h or h <= hi_h``.
        open_px: side of the square structuring element of a morphological opening that removes
            speckle smaller than it (0 or 1: no opening).

    Returns:
        bool ``(..., H, W)``.

    Raises:
        ShapeError: not ``(..., H, W, 3)``, or bounds not triples.
        DataError: dtype not uint8, bounds out of range.
    """

    a = _check_images(images)
    lo_a, hi_a = _check_bounds(lo, hi)
    batch = a.shape[:-3]
    flat = a.reshape((-1,) + a.shape[-3:])
    out = np.zeros(flat.shape[:-1], dtype=bool)
    kernel = np.ones((int(open_px), int(open_px)), np.uint8) if int(open_px) > 1 else None
    for i, img in enumerate(flat):
        hsv = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2HSV)
        h, s, v = hsv[..., 0], hsv[..., 1], hsv[..., 2]
        if lo_a[0] <= hi_a[0]:
            hue = (h >= lo_a[0]) & (h <= hi_a[0])
        else:
            hue = (h >= lo_a[0]) | (h <= hi_a[0])
        m = hue & (s >= lo_a[1]) & (s <= hi_a[1]) & (v >= lo_a[2]) & (v <= hi_a[2])
        if kernel is not None:
            m = cv2.morphologyEx(m.astype(np.uint8), cv2.MORPH_OPEN, kernel).astype(bool)
        out[i] = m
    return out.reshape(batch + out.shape[-2:])


def _check_mask(m: np.ndarray, name: str, ndim: int) -> np.ndarray:
    a = np.asarray(m)
    if a.ndim != ndim:
        want = "(H, W)" if ndim == 2 else "(T, H, W)"
        raise ShapeError(f"{name} must be {want} bool, got shape {a.shape}")
    if a.dtype != bool:
        raise DataError(f"{name} must be a bool mask, got dtype {a.dtype}; use mask > 0 or mask.astype(bool)")
    return a


def _dist_to(mask: np.ndarray) -> np.ndarray:
    """Euclidean distance (px) of every pixel to the nearest True pixel of ``mask`` (non-empty)."""
    return cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def mask_chamfer(mask_a: np.ndarray, mask_b: np.ndarray) -> float:
    """Bidirectional Chamfer distance between two masks, px.

    ``0.5 * (mean_{p in a} d(p, b) + mean_{q in b} d(q, a))`` where ``d(p, m)`` is the Euclidean
    distance from pixel ``p`` to the nearest True pixel of ``m`` (exact, ``cv2.distanceTransform``
    with ``DIST_MASK_PRECISE``). Every True pixel counts (filled masks, not contours): a filled
    ``s x s`` square against itself shifted by ``d`` px along an axis gives
    ``d (d + 1) / (2 s)``; a one-pixel-wide line shifted perpendicular to itself by ``d`` gives ``d``.

    Empty masks: both empty -> 0; exactly one empty -> the image diagonal ``sqrt(H^2 + W^2)``
    (the largest distance possible inside the image, so a missed detection is maximally bad).

    Args:
        mask_a, mask_b: ``(H, W)`` bool, same shape.

    Raises:
        ShapeError: not 2-D or different shapes. DataError: not bool.
    """
    a = _check_mask(mask_a, "mask_a", 2)
    b = _check_mask(mask_b, "mask_b", 2)
    if a.shape != b.shape:
        raise ShapeError(f"mask_a and mask_b must have the same shape, got {a.shape} and {b.shape}")
    na, nb = int(a.sum()), int(b.sum())
    if na == 0 and nb == 0:
        return 0.0
    if na == 0 or nb == 0:
        return float(np.hypot(*a.shape))
    return float(0.5 * (_dist_to(b)[a].mean() + _dist_to(a)[b].mean()))


def mask_chamfer_per_frame(masks_a: np.ndarray, masks_b: np.ndarray) -> np.ndarray:
    """:func:`mask_chamfer` of each frame pair: ``(T, H, W)`` bool x2 -> ``(T,)`` float px.

    The paper's score is the mean over time of this array.

    Raises:
        ShapeError: not 3-D or different shapes. DataError: not bool.
    """
    a = _check_mask(masks_a, "masks_a", 3)
    b = _check_mask(masks_b, "masks_b", 3)
    if a.shape != b.shape:
        raise ShapeError(f"masks_a and masks_b must have the same shape (T, H, W), got {a.shape} and {b.shape}")
    return np.array([mask_chamfer(x, y) for x, y in zip(a, b)], dtype=float)
