"""The cloth grid layout both engines use: an ``n x n`` x-major vertex grid (vertex ``i * n + j``), its
triangles and its corners, so that ``rollout.info["corners"]`` and vertex indices agree across engines."""
from __future__ import annotations

import numpy as np


def grid_faces(n: int) -> np.ndarray:
    """Triangles ``(2 (n-1)^2, 3)`` int64 of an ``n x n`` x-major vertex grid (index ``i * n + j``)."""
    f = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
            f.append((a, b, c))
            f.append((a, c, d))
    return np.asarray(f, dtype=np.int64).reshape(-1, 3)


def grid_corners(n: int) -> list[int]:
    """Vertex indices of the 4 corners of an ``n x n`` x-major grid, in the order grid ``(0, 0)``,
    ``(0, n-1)``, ``(n-1, n-1)``, ``(n-1, 0)`` (index ``i * n + j``); index 0 is the grasped corner.
    Both backends use this layout, so ``rollout.info["corners"]`` agrees across them."""
    return [0, n - 1, n * n - 1, (n - 1) * n]
