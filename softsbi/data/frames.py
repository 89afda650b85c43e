"""Folders of RGB frames (``000.png, 001.png, ...``): the one reader and writer of image sequences, used by
recording directories (:mod:`softsbi.data.recording`, ``images/``) and the image observers
(:mod:`softsbi.perception.images`, ``fit --observed FRAMES_DIR``)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from softsbi.core.errors import DataError
from softsbi.data.keypoints import IMAGE_SUFFIXES, check_images

__all__ = ["IMAGE_SUFFIXES", "load_frames", "numbered_files", "save_frames"]


def numbered_files(folder: str | Path, suffixes: tuple[str, ...], start: int | None = 0) -> list[Path]:
    """The frame files of ``folder`` in frame order: those with one of ``suffixes`` (lower case, with the dot)
    whose name is a number, which must be the frame's index written with three digits or more (``000.npy``, ...,
    ``999.npy``, ``1000.npy``), as :func:`save_frames` and the recording writer name them.

    Args:
        start: the first frame's index; None: any (DiffCloud's folders), the numbering consecutive from it.

    Returns:
        the files (an empty list when there are none, or no such folder).

    Raises:
        DataError: a file named by a number written otherwise (``5.npy``, ``0005.npy``), named with the name it
            needs; a gap or a duplicate in the numbering, with the missing names.
    """
    folder = Path(folder)
    if not folder.is_dir():
        return []
    files = [f for f in folder.iterdir() if f.suffix.lower() in suffixes and f.stem.isdigit()]
    odd = sorted((f for f in files if f.stem != f"{int(f.stem):03d}"), key=lambda f: (int(f.stem), f.name))
    if odd:
        right = f"{int(odd[0].stem):03d}{odd[0].suffix}"
        twin = f" ({right} is there too: remove one of them)" if (folder / right).exists() else ""
        others = f"; so are {', '.join(f.name for f in odd[1:4])}" if len(odd) > 1 else ""
        raise DataError(f"'{odd[0]}' is misnamed: frames are named by their index with three digits or more "
                        f"(000{odd[0].suffix}, 001{odd[0].suffix}, ...); rename it to {right}{twin}{others}")
    files.sort(key=lambda f: int(f.stem))
    idx = [int(f.stem) for f in files]
    first = idx[0] if start is None and idx else start or 0
    if idx and idx != list(range(first, first + len(idx))):
        missing = sorted(set(range(first, idx[-1] + 1)) - set(idx))
        raise DataError(f"'{folder}': frame numbering must run {first:03d}, {first + 1:03d}, ... without gaps (missing "
                        f"{', '.join(f'{i:03d}' for i in missing[:5])}); renumber the files")
    return files

def load_frames(folder: str | Path, size: tuple[int, int] | None = None) -> np.ndarray:
    """Read a folder of frames ``000.png, 001.png, ...`` (or ``.jpg``) in numeric order as RGB.

    Args:
        folder: the frames folder.
        size: optional ``(width, height)`` px to resize every frame to (``cv2.INTER_AREA``).

    Returns:
        ``(T, H, W, 3)`` uint8 RGB.

    Raises:
        DataError: missing folder, no numbered frames, gaps in the numbering, unreadable files,
            frames of different sizes, or a resize that changes the aspect ratio by more than 2 %.
    """
    import cv2  # heavy (OpenCV): loaded only to read or write image frames

    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"frames folder '{folder}' does not exist; it must hold 000.png, 001.png, ... "
                        f"(one RGB frame per scenario frame)")
    files = numbered_files(folder, IMAGE_SUFFIXES, start=None)
    if not files:
        raise DataError(f"'{folder}' holds no frames named 000.png, 001.png, ... (.png/.jpg)")
    frames = []
    for f in files:
        im = cv2.imread(str(f), cv2.IMREAD_COLOR)
        if im is None:
            raise DataError(f"cannot read image '{f}'; re-export it as PNG or JPEG")
        frames.append(cv2.cvtColor(im, cv2.COLOR_BGR2RGB))
    shapes = {fr.shape for fr in frames}
    if len(shapes) > 1:
        raise DataError(f"'{folder}': frames have different sizes {sorted(shapes)}; all frames must share one size")
    out = np.stack(frames)
    if size is not None:
        w, h = size
        H, W = out.shape[1:3]
        if abs((W / H) / (w / h) - 1) > 0.02:
            raise DataError(f"'{folder}': frames are {W}x{H} px, which cannot be resized to {w}x{h} without "
                            f"distortion; crop them or pass a camera with the frames' aspect ratio")
        if (W, H) != (w, h):
            out = np.stack([cv2.resize(fr, (w, h), interpolation=cv2.INTER_AREA) for fr in out])
    return out


def save_frames(images: np.ndarray, folder: str | Path) -> list[Path]:
    """Write ``images (T, H, W, 3)`` uint8 RGB as ``folder/000.png, 001.png, ...``; returns the paths."""
    import cv2  # heavy (OpenCV): loaded only to read or write image frames

    images = check_images(images)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, im in enumerate(images):
        p = folder / f"{i:03d}.png"
        cv2.imwrite(str(p), cv2.cvtColor(im, cv2.COLOR_RGB2BGR))
        paths.append(p)
    return paths
