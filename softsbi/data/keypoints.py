"""Keypoint data: input checks, a folder loader, a leakage-free block split, metrics, drawing.

Conventions: images are ``(N, H, W, 3)`` uint8 RGB; keypoints are ``(N, K, 2)`` pixel
coordinates ``(u, v)`` = (column, row) with pixel centres at integer coordinates (pixel ``(0, 0)``
covers ``[-0.5, 0.5]^2``).

The annotated wiping set (``shared/data/wiping_keypoints``, from ``priyasundaresan/keypoints_cls``
branch ``deform-realsim``) was inspected frame by frame for this module (see
:func:`wiping_frame_labels`): frames ``0..60`` are 61 distinct *source* images, 31 real (robot
wiping with the green cloth) and 30 simulated (rendered quilted cloth pasted on a table image,
no robot); frames ``61..448`` are 8 augmented copies of each of the sources ``0..48`` in order
(``61 + 8 s .. 68 + 8 s`` are copies of source ``s``; the last group, of source 48, has 4). The
copies share the source's keypoints (colour jitter) or an affine transform of them. Real and
simulated sources are interleaved throughout, so real frames are *not* confined to the start of
the set.
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from softsbi.core.arrays import read_npy
from softsbi.core.errors import DataError, ShapeError

__all__ = [
    "WIPING_REAL_SOURCES",
    "block_split",
    "check_images",
    "check_keypoints",
    "draw_keypoints",
    "index_ranges",
    "keypoint_distances",
    "keypoint_errors",
    "load_keypoint_folder",
    "match_keypoints",
    "wiping_frame_labels",
]

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")

#: Sources (frames 0..60) of the wiping set that are real photographs (robot and green cloth
#: visible); the other 30 sources are simulated. Determined by looking at every frame.
WIPING_REAL_SOURCES = (0, 1, 2, 3, 6, 7, 10, 12, 13, 14, 15, 19, 22, 25, 27, 28, 33, 34, 35, 36, 39, 40, 41,
                       43, 45, 46, 49, 51, 52, 57, 58)
WIPING_N_SOURCES = 61
WIPING_COPIES = 8


# ---------------------------------------------------------------------------------------- checks
def check_images(images: Any, what: str = "images") -> np.ndarray:
    """Validate a batch of RGB images.

    Args:
        images: ``(N, H, W, 3)`` uint8 RGB array.
        what: name used in messages.

    Returns:
        The same data as a C-contiguous uint8 ndarray.

    Raises:
        ShapeError: not an array of rank 4 with 3 channels and dtype uint8; the message names the
            fix (single image, greyscale, RGBA, float images).
    """
    a = np.asarray(images)
    if a.ndim == 3 and a.shape[-1] == 3:
        raise ShapeError(f"{what} must be a batch (N, H, W, 3); got one image {a.shape}: pass {what}[None]")
    if a.ndim == 3 or (a.ndim == 4 and a.shape[-1] == 1):
        raise ShapeError(f"{what} must be (N, H, W, 3) RGB, got greyscale {a.shape}: convert with "
                         f"np.repeat({what}.reshape({what}.shape[:3])[..., None], 3, axis=-1)")
    if a.ndim == 4 and a.shape[-1] == 4:
        raise ShapeError(f"{what} must be (N, H, W, 3) RGB, got RGBA {a.shape}: drop alpha with {what}[..., :3]")
    if a.ndim != 4 or a.shape[-1] != 3:
        raise ShapeError(f"{what} must be (N, H, W, 3) uint8 RGB, got shape {a.shape}")
    if a.dtype != np.uint8:
        hint = ("np.clip(images * 255, 0, 255).round().astype(np.uint8) for values in [0, 1]"
                if a.dtype.kind == "f" else "images.astype(np.uint8) if values are in 0..255")
        raise ShapeError(f"{what} must be uint8 (0..255), got {a.dtype}: convert with {hint}")
    if a.shape[0] == 0 or a.shape[1] < 2 or a.shape[2] < 2:
        raise ShapeError(f"{what} must hold at least one image of at least 2x2 px, got {a.shape}")
    return np.ascontiguousarray(a)


def check_keypoints(keypoints: Any, n: int, height: int, width: int, outside_margin: float = 0.25,
                    what: str = "keypoints", names: Sequence[str] | None = None) -> np.ndarray:
    """Validate keypoints against their images.

    Args:
        keypoints: ``(N, K, 2)`` px ``(u, v)``.
        n: number of images N.
        height, width: image size in px.
        outside_margin: keypoints may lie outside the image by at most this fraction of
            ``max(height, width)`` (annotated corners cut off by the frame, as in the augmented
            wiping copies, lie up to 0.21 of the image outside); farther points mean the file
            does not belong to the image (other resolution, swapped axes). 0 = strictly inside
            ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``.
        what: name used in messages. names: optional per-image names for messages.

    Returns:
        float64 ``(N, K, 2)``.

    Raises:
        ShapeError: not ``(N, K, 2)`` with ``K >= 1``, or N differs from the images.
        DataError: non-finite values, or a point farther outside the image than allowed.
    """
    k = np.asarray(keypoints, dtype=np.float64) if keypoints is not None else None
    if k is None:
        raise ShapeError(f"{what} are required: (N, K, 2) px (u, v) for a supervised extractor")
    if k.ndim == 2 and k.shape[-1] == 2 and n == 1:
        k = k[None]
    if k.ndim != 3 or k.shape[-1] != 2 or k.shape[1] < 1:
        raise ShapeError(f"{what} must be (N, K, 2) px (u, v) with K >= 1, got {k.shape}")
    if k.shape[0] != n:
        raise ShapeError(f"{what} must have one row per image: got {k.shape[0]} keypoint sets for {n} images")
    if not np.isfinite(k).all():
        bad = np.nonzero(~np.isfinite(k).all(axis=(1, 2)))[0]
        raise DataError(f"{what} have non-finite values (NaN/inf) in image(s) {_name(bad[:5], names)}")
    m = float(outside_margin) * max(height, width)
    lo = -0.5 - m
    out = (k[..., 0] < lo) | (k[..., 0] > width - 0.5 + m) | (k[..., 1] < lo) | (k[..., 1] > height - 0.5 + m)
    if out.any():
        i, j = (int(x[0]) for x in np.nonzero(out))
        raise DataError(f"{what}: {int(out.sum())} point(s) lie outside the {width}x{height} image by more than "
                        f"{outside_margin:g} of its size, e.g. image {_name([i], names)} point {j} at "
                        f"(u, v) = ({k[i, j, 0]:g}, {k[i, j, 1]:g}); keypoints are pixel (column, row) of "
                        f"the image they belong to (check the resolution and the (u, v) order)")
    return k


def _name(idx: Iterable[int], names: Sequence[str] | None) -> str:
    idx = [int(i) for i in idx]
    return ", ".join(names[i] for i in idx) if names is not None else ", ".join(map(str, idx))


# ---------------------------------------------------------------------------------------- loading
def load_keypoint_folder(folder: str | Path, outside_margin: float = 0.25) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Read an annotated keypoint folder: ``images/<stem>.jpg|png`` with ``keypoints/<stem>.npy``.

    Args:
        folder: directory with ``images/`` and ``keypoints/`` (the layout of
            ``shared/data/wiping_keypoints``); each ``.npy`` is ``(K, 2)`` px ``(x, y)`` = (u, v).
        outside_margin: see :func:`check_keypoints` (default tolerates annotated points cut off
            by the frame, up to a quarter of the image size outside).

    Returns:
        ``images (N, H, W, 3)`` uint8 RGB, ``keypoints (N, K, 2)`` float64 px, ``names`` (the N
        stems, sorted).

    Raises:
        DataError: folder or sub-folders missing, no images, an image without keypoint file or a
            keypoint file without image, an unreadable file, a keypoint file not ``(K, 2)`` or with
            a K different from the others, points outside their image, images of mixed sizes, or
            images that are not 3-channel colour.
    """
    import cv2  # heavy (OpenCV): loaded only to draw or read images

    folder = Path(folder)
    img_dir, kp_dir = folder / "images", folder / "keypoints"
    for d in (img_dir, kp_dir):
        if not d.is_dir():
            raise DataError(f"{d} not found: a keypoint folder holds images/<name>.jpg|png and "
                            f"keypoints/<name>.npy")
    imgs = {p.stem: p for p in sorted(img_dir.iterdir()) if p.suffix.lower() in IMAGE_SUFFIXES}
    kps = {p.stem: p for p in sorted(kp_dir.iterdir()) if p.suffix == ".npy"}
    if not imgs:
        raise DataError(f"no .jpg/.png images in {img_dir}")
    no_kp, no_img = sorted(set(imgs) - set(kps)), sorted(set(kps) - set(imgs))
    if no_kp:
        raise DataError(f"{len(no_kp)} image(s) without keypoints/<name>.npy, e.g. {', '.join(no_kp[:5])}; "
                        f"annotate them or move them out of {img_dir}")
    if no_img:
        raise DataError(f"{len(no_img)} keypoint file(s) without an image, e.g. {', '.join(no_img[:5])}.npy")
    names = sorted(imgs)
    images, keypoints = [], []
    for name in names:
        im = cv2.imread(str(imgs[name]), cv2.IMREAD_UNCHANGED)
        if im is None:
            raise DataError(f"cannot read image {imgs[name]}")
        ch = 1 if im.ndim == 2 else im.shape[2]
        if ch != 3:
            raise DataError(f"image {imgs[name]} has {ch} channel(s); all images must be 3-channel colour "
                            f"(convert greyscale/RGBA files to RGB)")
        if images and im.shape != images[0].shape:
            raise DataError(f"mixed image sizes: {imgs[name]} is {im.shape[1]}x{im.shape[0]} but "
                            f"{names[0]} is {images[0].shape[1]}x{images[0].shape[0]}; resize them to one size")
        k = read_npy(kps[name], "keypoints", "save them as a (K, 2) array of pixel coordinates")
        k = np.asarray(k)
        if k.ndim != 2 or k.shape[1] != 2 or k.dtype.kind not in "iuf":
            raise DataError(f"keypoints {kps[name]} must be a numeric (K, 2) array of (x, y) px, got "
                            f"{k.dtype} {k.shape}")
        if keypoints and k.shape != keypoints[0].shape:
            raise DataError(f"keypoints {kps[name]} has K={k.shape[0]} but {names[0]}.npy has "
                            f"K={keypoints[0].shape[0]}; every image needs the same number of keypoints")
        images.append(im[..., ::-1])
        keypoints.append(k.astype(np.float64))
    H, W = images[0].shape[:2]
    kp = np.stack(keypoints)
    try:
        kp = check_keypoints(kp, len(names), H, W, outside_margin, names=names)
    except DataError as exc:
        raise DataError(f"{folder}: {exc}") from None
    return np.ascontiguousarray(np.stack(images)), kp, names


def wiping_frame_labels(n: int = 449) -> dict[str, np.ndarray]:
    """Per-frame provenance of the annotated wiping set (see the module docstring).

    Args:
        n: number of frames (449 in ``shared/data/wiping_keypoints``).

    Returns:
        ``{"source": (n,) int`` (the source image 0..60 a frame is or was augmented from),
        ``"real": (n,) bool`` (a real photograph or a copy of one), ``"augmented": (n,) bool``
        (frames >= 61)``}``.

    Source: visual inspection of all 449 frames of the wiping data set; the copy groups
    are confirmed by frames whose keypoints equal their source's exactly.
    """
    idx = np.arange(n)
    source = np.where(idx < WIPING_N_SOURCES, idx, (idx - WIPING_N_SOURCES) // WIPING_COPIES)
    real = np.isin(source, WIPING_REAL_SOURCES)
    return {"source": source.astype(np.int64), "real": real, "augmented": idx >= WIPING_N_SOURCES}


# ---------------------------------------------------------------------------------------- split
def block_split(n: int, fractions: Sequence[float] = (0.7, 0.15, 0.15), n_blocks: int = 15,
                groups: Sequence[int] | np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Split frames ``0..n-1`` into train / val / test by contiguous blocks (not random frames).

    Neighbouring frames of a video are near duplicates, so a random frame split leaks test frames
    into training. Here the sequence of *units* is cut into ``n_blocks`` contiguous blocks of about
    equal frame count, and whole blocks are dealt to the splits so that every split's share of
    blocks tracks ``fractions`` along the sequence (a deterministic largest-deficit rule; test and
    val blocks are spread over the sequence rather than taken from its end, so each sees both
    real and simulated material where the two are interleaved).

    Units: without ``groups`` a unit is one frame and every block is one contiguous index range.
    With ``groups`` (e.g. ``wiping_frame_labels()["source"]``: an image and its augmented copies
    share a group id) a unit is one group, blocks are contiguous runs of group ids, and no group is
    ever split across train/val/test (for the wiping set a block is then the source range
    ``a..b`` plus the frame range of their copies ``61 + 8a .. 68 + 8b``).

    For the wiping set, ``block_split(449, groups=wiping_frame_labels()["source"])`` (the default
    15 blocks) gives a test split of 54 frames, sources 7-9 and 27-29 with their copies (frames
    7-9, 27-29, 117-140, 277-300), of which 27 are real (50 %, against 53 % real in the whole
    set: sources 7, 27, 28 are real, 8, 9, 29 simulated); val has 63 frames (sources 13-16 and
    37-39, frames 13-16, 37-39, 165-196, 357-380), 57 % real; train the other 332 frames, 53 % real.
    A plain frame split (``groups=None``) would leak: copies of a test source sit in other blocks.

    Args:
        n: number of frames.
        fractions: ``(train, val, test)`` shares of blocks (normalised; val or test may be 0).
        n_blocks: number of blocks (at most the number of units).
        groups: optional ``(n,)`` group id per frame (any ints; unit order = order of first
            appearance).

    Returns:
        ``{"train", "val", "test"}``: sorted int64 frame indices, disjoint, covering ``0..n-1``.

    Raises:
        ValueError: ``n < 1``, bad ``fractions``, ``n_blocks`` < 1, ``groups`` of wrong length.
    """
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    f = np.asarray(fractions, dtype=np.float64)
    if f.shape != (3,) or (f < 0).any() or f.sum() <= 0:
        raise ValueError(f"fractions must be 3 non-negative numbers (train, val, test), got {fractions}")
    f = f / f.sum()
    if groups is None:
        unit_of = np.arange(n)
    else:
        g = np.asarray(groups)
        if g.shape != (n,):
            raise ValueError(f"groups must have one id per frame ({n},), got {g.shape}")
        _, first, inv = np.unique(g, return_index=True, return_inverse=True)
        rank = np.empty(len(first), np.int64)
        rank[np.argsort(first, kind="stable")] = np.arange(len(first))
        unit_of = rank[inv.reshape(-1)]
    n_units = int(unit_of.max()) + 1
    sizes = np.bincount(unit_of, minlength=n_units)
    n_blocks = int(n_blocks)
    if n_blocks < 1:
        raise ValueError(f"n_blocks must be >= 1, got {n_blocks}")
    n_blocks = min(n_blocks, n_units)
    # block of each unit: cut the cumulative frame count into n_blocks equal shares
    centre = np.cumsum(sizes) - sizes / 2.0
    block_of_unit = np.minimum((centre / n * n_blocks).astype(np.int64), n_blocks - 1)
    block_of_unit = np.maximum.accumulate(block_of_unit)
    assigned = np.zeros(3)
    split_of_block = np.empty(n_blocks, np.int64)
    for b in range(n_blocks):
        deficit = f * (b + 1) - assigned
        s = int(np.argmax(deficit[[2, 1, 0]]))  # ties: test, then val, then train
        s = 2 - s
        split_of_block[b] = s
        assigned[s] += 1
    split = split_of_block[block_of_unit[unit_of]]
    return {name: np.nonzero(split == i)[0].astype(np.int64) for i, name in enumerate(("train", "val", "test"))}


def index_ranges(idx: Sequence[int] | np.ndarray) -> list[tuple[int, int]]:
    """Contiguous runs of sorted frame indices as inclusive ``(first, last)`` pairs."""
    a = np.unique(np.asarray(idx, dtype=np.int64))
    if a.size == 0:
        return []
    cut = np.nonzero(np.diff(a) > 1)[0]
    starts = np.r_[a[0], a[cut + 1]]
    ends = np.r_[a[cut], a[-1]]
    return [(int(s), int(e)) for s, e in zip(starts, ends)]


# ---------------------------------------------------------------------------------------- metrics
def keypoint_distances(pred: np.ndarray, true: np.ndarray, match: str = "index") -> np.ndarray:
    """Euclidean distances ``(N, K)`` px between predicted and true keypoints.

    Args:
        pred, true: ``(N, K, 2)`` px (the same pixel units).
        match: ``"index"`` pairs keypoint k with keypoint k; ``"hungarian"`` treats each frame's
            keypoints as an unordered set and pairs them by the assignment of minimum total
            distance (``scipy.optimize.linear_sum_assignment``), as the downstream RKHS embedding
            is permutation invariant.

    Raises:
        ShapeError: shapes differ or are not ``(N, K, 2)``. ValueError: unknown ``match``.
    """
    p, t = np.asarray(pred, np.float64), np.asarray(true, np.float64)
    if p.shape != t.shape or p.ndim != 3 or p.shape[-1] != 2:
        raise ShapeError(f"pred and true must both be (N, K, 2), got {p.shape} and {t.shape}")
    if match == "index":
        return np.linalg.norm(p - t, axis=-1)
    if match != "hungarian":
        raise ValueError(f"match must be 'index' or 'hungarian', got {match!r}")
    from scipy.optimize import linear_sum_assignment  # heavy (scipy): loaded only to match keypoints

    out = np.empty(p.shape[:2])
    for i in range(len(p)):
        cost = np.linalg.norm(p[i][:, None] - t[i][None], axis=-1)
        r, c = linear_sum_assignment(cost)
        out[i, r] = cost[r, c]
    return out


def match_keypoints(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """Reorder each frame's predicted keypoints to the truth by the minimum-distance assignment.

    Args:
        pred, true: ``(N, K, 2)`` px.

    Returns:
        ``(N, K, 2)``: ``pred`` with its keypoints permuted per frame so that keypoint k is the
        one assigned to ``true[:, k]`` (``scipy.optimize.linear_sum_assignment``); index-matched
        distances of the result equal the Hungarian distances of :func:`keypoint_distances`.

    Raises:
        ShapeError: shapes differ or are not ``(N, K, 2)``.
    """
    p, t = np.asarray(pred, np.float64), np.asarray(true, np.float64)
    if p.shape != t.shape or p.ndim != 3 or p.shape[-1] != 2:
        raise ShapeError(f"pred and true must both be (N, K, 2), got {p.shape} and {t.shape}")
    from scipy.optimize import linear_sum_assignment  # heavy (scipy): loaded only to match keypoints

    out = np.empty_like(p)
    for i in range(len(p)):
        r, c = linear_sum_assignment(np.linalg.norm(p[i][:, None] - t[i][None], axis=-1))
        out[i, c] = p[i, r]
    return out


def keypoint_errors(pred: np.ndarray, true: np.ndarray, thresholds: Sequence[float] = (5, 10, 20)
                    ) -> dict[str, float]:
    """Pixel-error summary of keypoint predictions.

    Args:
        pred, true: ``(N, K, 2)`` px.
        thresholds: radii in px for PCK (percentage of correct keypoints).

    Returns:
        ``{"mean_px", "median_px", "max_px", "pck@5px", "pck@10px", "pck@20px"}`` with index-matched
        keypoints, the same keys prefixed ``hungarian_`` with per-frame set matching (see
        :func:`keypoint_distances`), plus ``n_frames`` and ``n_keypoints``. PCK@r is the fraction
        (0..1) of keypoints within ``r`` px of the truth.

    Raises:
        ShapeError: see :func:`keypoint_distances`.
    """
    res: dict[str, float] = {}
    for prefix, match in (("", "index"), ("hungarian_", "hungarian")):
        d = keypoint_distances(pred, true, match).ravel()
        res[prefix + "mean_px"] = float(d.mean())
        res[prefix + "median_px"] = float(np.median(d))
        res[prefix + "max_px"] = float(d.max())
        for r in thresholds:
            res[f"{prefix}pck@{r:g}px"] = float((d <= r).mean())
    res["n_frames"] = int(np.asarray(pred).shape[0])
    res["n_keypoints"] = int(np.asarray(pred).shape[1])
    return res


# ---------------------------------------------------------------------------------------- drawing
_COLOURS = [(230, 25, 75), (60, 180, 75), (255, 225, 25), (0, 130, 200), (245, 130, 48), (145, 30, 180),
            (70, 240, 240), (240, 50, 230)]


def draw_keypoints(images: np.ndarray, pred: np.ndarray, true: np.ndarray | None = None, *,
                   labels: Sequence[str] | None = None, ncols: int = 4, tile: int | None = None,
                   path: str | Path | None = None) -> np.ndarray:
    """Contact sheet of images with predicted (filled dots) and true (rings) keypoints.

    Keypoint k has the same colour in prediction and truth; a thin line joins each prediction to
    the truth of the same index.

    Args:
        images: ``(N, H, W, 3)`` uint8 RGB.
        pred: ``(N, K, 2)`` px (u, v) in the images' pixels.
        true: optional ``(N, K, 2)`` px.
        labels: optional caption per tile.
        ncols: tiles per row.
        tile: tile side in px (default: the image width, at most 320).
        path: if given, the sheet is also written there as PNG.

    Returns:
        ``(rows * tile_h, ncols * tile, 3)`` uint8 RGB sheet.

    Raises:
        ShapeError: bad images, or keypoints not ``(N, K, 2)`` for those images.
    """
    import cv2  # heavy (OpenCV): loaded only to draw or read images

    images = check_images(images)
    N, H, W = images.shape[:3]
    pred = np.asarray(pred, np.float64)
    if pred.shape[0] != N or pred.ndim != 3 or pred.shape[-1] != 2:
        raise ShapeError(f"pred must be (N, K, 2) with N={N}, got {pred.shape}")
    if true is not None:
        true = np.asarray(true, np.float64)
        if true.shape != pred.shape:
            raise ShapeError(f"true must have the shape of pred {pred.shape}, got {true.shape}")
    tw = int(tile or min(W, 320))
    th = max(1, int(round(H * tw / W)))
    s = tw / W
    r = max(2, int(round(tw / 80)))
    tiles = []
    for i in range(N):
        im = cv2.resize(images[i], (tw, th), interpolation=cv2.INTER_AREA).copy()
        for k in range(pred.shape[1]):
            c = _COLOURS[k % len(_COLOURS)]
            p = tuple(int(round((x + 0.5) * s - 0.5)) for x in pred[i, k])
            if true is not None:
                t = tuple(int(round((x + 0.5) * s - 0.5)) for x in true[i, k])
                cv2.line(im, p, t, c, 1, cv2.LINE_AA)
                cv2.circle(im, t, r + 3, (255, 255, 255), 2, cv2.LINE_AA)
                cv2.circle(im, t, r + 3, c, 1, cv2.LINE_AA)
            cv2.circle(im, p, r, (0, 0, 0), -1, cv2.LINE_AA)
            cv2.circle(im, p, r - 1, c, -1, cv2.LINE_AA)
        if labels is not None:
            (tw_, th_), _ = cv2.getTextSize(str(labels[i]), cv2.FONT_HERSHEY_SIMPLEX, 0.4, 1)
            cv2.rectangle(im, (0, 0), (tw_ + 6, th_ + 7), (0, 0, 0), -1)
            cv2.putText(im, str(labels[i]), (3, th_ + 3), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1,
                        cv2.LINE_AA)
        tiles.append(im)
    ncols = max(1, min(int(ncols), N))
    while len(tiles) % ncols:
        tiles.append(np.zeros_like(tiles[0]))
    rows = [np.hstack(tiles[j:j + ncols]) for j in range(0, len(tiles), ncols)]
    sheet = np.ascontiguousarray(np.vstack(rows))
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(path), sheet[..., ::-1]):
            raise DataError(f"could not write {path}")
    return sheet
