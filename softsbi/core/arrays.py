"""Reading NumPy ``.npy`` files with one clear line per failure.

``np.load`` on a file that is not an ``.npy`` array falls back to unpickling and answers with
numpy's advice to pass ``allow_pickle=True``: wrong (and unsafe) for measured data. Here a file
that is missing, has no ``.npy`` header, is truncated, or holds Python objects is a
:class:`~softsbi.core.errors.DataError` naming the file and the fix.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from softsbi.core.errors import DataError

NPY_MAGIC = b"\x93NUMPY"


def read_npy(path: str | Path, what: str = "array", fix: str = "re-export it with numpy.save") -> np.ndarray:
    """Load a numeric ``.npy`` file (never unpickling).

    Args:
        path: the file.
        what: what the file should hold, for the message (e.g. ``"frame"``, ``"gripper path"``).
        fix: what the user should do, appended to every message.

    Returns:
        the array (any numeric or boolean dtype, any shape).

    Raises:
        DataError: missing file, not an ``.npy`` file, truncated, or an object array.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{what} '{path}' does not exist; {fix}")
    with open(path, "rb") as fh:
        head = fh.read(len(NPY_MAGIC))
    if head != NPY_MAGIC:
        raise DataError(f"{what} '{path}' is not a NumPy .npy file (no .npy header; damaged or another "
                        f"format); {fix}")
    try:
        a = np.load(path, allow_pickle=False)
    except ValueError as exc:
        reason = "holds Python objects, not numbers" if "pickle" in str(exc) else f"cannot be read ({exc})"
        raise DataError(f"{what} '{path}' {reason}; {fix}") from None
    except (OSError, EOFError) as exc:
        raise DataError(f"{what} '{path}' is truncated or unreadable ({exc}); {fix}") from None
    if a.dtype.kind not in "biuf":
        raise DataError(f"{what} '{path}' has dtype {a.dtype}, not numbers; {fix}")
    return a
