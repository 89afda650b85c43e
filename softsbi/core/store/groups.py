"""The named groups of a run store outside its rounds (``evaluation``, ``refine``, ``best_fit``, a check's arrays):
whole groups written and read at once, and row groups that grow one simulation at a time
(:class:`NamedGroups`, a part of :class:`~softsbi.core.store.RunStore`)."""
from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import zarr

from softsbi.core.errors import SchemaError
from softsbi.core.store.posterior import put_array
from softsbi.core.store.damage import array_names
from softsbi.core.types import jsonable


def holds(attrs: Mapping[str, Any], key: Mapping[str, Any]) -> bool:
    """Whether a stored group's attributes ``attrs`` hold every value of ``key`` (what the group was computed from):
    a value that differs, or one the attributes lack (a group stored by an older version), does not match."""
    return all(attrs.get(k) == v for k, v in key.items())


class NamedGroups:
    """Named top-level groups of arrays in a run store: :class:`~softsbi.core.store.RunStore`'s methods for them.

    Needs ``path`` (the store's folder) and ``root`` (its open root group, reopened after a group is removed).
    """

    path: Path
    root: zarr.Group

    def remove_group(self, name: str) -> None:
        """Remove a top-level group (e.g. ``evaluation``) and everything in it (nothing when it does not exist)."""
        shutil.rmtree(self.path / name, ignore_errors=True)
        self.root = zarr.open_group(str(self.path), mode="a")

    def write_group(self, name: str, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Any] | None = None,
                    units: Mapping[str, str] | None = None) -> None:
        """(Over)write a named group of arrays, e.g. ``evaluation`` or ``checks``."""
        if name in self.root:
            shutil.rmtree(self.path / name, ignore_errors=True)
            self.root = zarr.open_group(str(self.path), mode="a")
        g = self.root.require_group(name)
        for k, v in arrays.items():
            v = np.asarray(v)
            put_array(g, k, v, tuple(f"dim_{i}" for i in range(v.ndim)), (units or {}).get(k, ""))
        if attrs:
            g.attrs.update(jsonable(dict(attrs)))

    def read_group(self, name: str, keys: Sequence[str] | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """The arrays of group ``name`` (those named in ``keys``, default all) and its attributes.

        Raises:
            SchemaError: an array cannot be read (a damaged chunk); the message names it and the fix.
        """
        g = self.root[name]
        out = {}
        for k in (array_names(g) if keys is None else [k for k in keys if k in g]):
            try:
                out[k] = g[k][...]
            except Exception as exc:  # noqa: BLE001 - the codec's error for a damaged chunk
                raise SchemaError(f"'{self.path / name / k}' cannot be read ({type(exc).__name__}: a damaged chunk); "
                                  f"re-run the same `softsbi fit` command: it computes the group '{name}' again") \
                    from None
        return out, dict(g.attrs)

    def has(self, name: str) -> bool:
        return name in self.root

    # -- row groups: simulations stored one by one outside the rounds (a best fit's refinement) ----------------
    def append_rows(self, name: str, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Any] | None = None,
                    units: Mapping[str, str] | None = None) -> int:
        """Append rows (axis 0) to the arrays of group ``name``, creating them on first use with one row per
        chunk (so each row is written atomically, as a round's simulations are); ``arrays`` must hold a
        ``status`` array, written last: the group's row count is ``len(status)`` (:meth:`read_rows`), so rows
        cut short by a killed append are overwritten by the next one. ``attrs`` update the group's attributes.

        Returns:
            The index of the first appended row.
        """
        if "status" not in arrays:
            raise ValueError("append_rows needs a 'status' array (it marks the rows as stored)")
        g = self.root.require_group(name)
        start = int(g["status"].shape[0]) if "status" in g else 0
        for k in [k for k in arrays if k != "status"] + ["status"]:
            v = np.asarray(arrays[k])
            if k not in g:
                g.create_array(k, shape=(0,) + v.shape[1:], dtype=v.dtype, chunks=(1,) + v.shape[1:],
                               dimension_names=("row",) + tuple(f"dim_{i}" for i in range(1, v.ndim)),
                               attributes={"units": (units or {}).get(k, "")})
            arr = g[k]
            arr.resize((start + len(v),) + tuple(arr.shape[1:]))
            arr[start:start + len(v)] = v
        if attrs:
            g.attrs.update(jsonable(dict(attrs)))
        return start

    def write_rows(self, name: str, start: int, arrays: Mapping[str, np.ndarray]) -> None:
        """Overwrite rows ``start..`` of group ``name``'s arrays (``status`` last, as :meth:`append_rows`)."""
        g = self.root[name]
        for k in [k for k in arrays if k != "status"] + (["status"] if "status" in arrays else []):
            v = np.asarray(arrays[k])
            g[k][start:start + len(v)] = v

    def read_rows(self, name: str) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Group ``name``'s arrays cut to its row count ``len(status)`` (:meth:`append_rows`), and its attributes."""
        arrays, attrs = self.read_group(name)
        n = len(arrays["status"]) if "status" in arrays else 0
        return {k: v[:n] for k, v in arrays.items()}, attrs
