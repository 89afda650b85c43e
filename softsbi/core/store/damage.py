"""What in a run store cannot be read: its metadata files (:func:`check_metadata`, on opening), whole arrays of a
group (:func:`unreadable_groups`), arrays that read but do not have the layout's shape (:func:`shape_faults`) and
single simulations of a round (:func:`damaged_rows`, which the fit simulates again).
:class:`~softsbi.core.store.RunStore` asks these; each names what is damaged, never repairs it."""
from __future__ import annotations

import json
import os
import warnings
from collections import Counter
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import zarr
from zarr.errors import ZarrUserWarning

from softsbi.core.errors import SchemaError
from softsbi.core.types import STATUS_PENDING

#: a round's per-simulation arrays: repaired row by row (:func:`damaged_rows`), not as whole groups
ROW_ARRAYS = ("status", "x", "chamfer", "sensor_x")

#: the shapes of the observed and of a round's arrays (the layout in :mod:`softsbi.core.store`); a letter is a size
#: the arrays share: T frames, P observed points, N simulations, D parameters, K sensor draws, Q dense points,
#: H x W pixels
OBSERVED_SHAPES: dict[str, tuple[str | int, ...]] = {
    "x": ("T", "P", 3), "gripper": ("T", 3), "times": ("T",), "dense": ("T", "Q", 3), "images": ("T", "H", "W", 3),
    "masks": ("T", "H", "W")}
ROUND_SHAPES: dict[str, tuple[str | int, ...]] = {
    "theta": ("N", "D"), "u": ("N", "D"), "seed": ("N",), "status": ("N",), "x": ("N", "T", "P", 3),
    "chamfer": ("N", "T"), "sensor_u": ("N", "K", "D"), "sensor_x": ("N", "K", "T", "P", 3)}


def array_names(g: zarr.Group) -> list[str]:
    """The names of the arrays in ``g``. A folder without metadata (an array or group whose creation a kill
    interrupted) is no member: it is left out without zarr's warning, and the store writes it again when needed."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "Object at .* is not recognized", ZarrUserWarning)
        return list(g.array_keys())


def group_names(g: zarr.Group) -> list[str]:
    """The names of the groups in ``g`` (half-written ones left out, as in :func:`array_names`)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "Object at .* is not recognized", ZarrUserWarning)
        return list(g.group_keys())


def damage_fix(path: Path, rel: str) -> str:
    """What fixes the damaged group ``rel`` (``"rounds/0"``, ``"observed"``, ``"evaluation"``, ...) of the run store at
    ``path``: the folders to remove and the command that computes them again."""
    top = rel.split("/")
    if top[0] == "rounds" and len(top) > 1:
        return (f"remove the folder '{path / 'rounds' / top[1]}', those of later rounds and "
                f"'{path / 'evaluation'}', then re-run the same `softsbi fit` command: it simulates them again")
    if top[0] == "observed":
        return (f"remove the folder '{path / 'observed'}', then re-run the same command: it rebuilds it from "
                f"the recording")
    return (f"remove the folder '{path / top[0]}', then re-run the command that wrote it (`softsbi fit` "
            f"for evaluation/): it computes it again")


def shape_faults(g: zarr.Group, shapes: Mapping[str, tuple[str | int, ...]],
                 sizes: Mapping[str, int] | None = None) -> dict[str, str]:
    """The arrays of group ``g`` that read but do not have their shape in ``shapes`` (:data:`OBSERVED_SHAPES`,
    :data:`ROUND_SHAPES`): ``{array: reason}``, e.g. ``{"x": "its 'x' array has shape (20, 3, 9, 3), expected (30,
    3, 9, 3)"}``. A letter's size is the one given in ``sizes`` (the run's settings: T, D, ...), else the one most of
    the group's arrays agree on; one no array gives is printed as ``*`` (any)."""
    names = set(array_names(g))
    found = {k: tuple(g[k].shape) for k in shapes if k in names}
    known = dict(sizes or {})
    votes: dict[str, list[int]] = {}
    for k, shape in found.items():
        if len(shape) == len(shapes[k]):
            for sym, n in zip(shapes[k], shape):
                if isinstance(sym, str) and sym not in known:
                    votes.setdefault(sym, []).append(n)
    known.update({sym: Counter(ns).most_common(1)[0][0] for sym, ns in votes.items()})
    out = {}
    for k, shape in found.items():
        want = tuple(known.get(sym, "*") if isinstance(sym, str) else sym for sym in shapes[k])
        if len(shape) != len(want) or any(w not in ("*", n) for w, n in zip(want, shape)):
            out[k] = f"its '{k}' array has shape {shape}, expected ({', '.join(map(str, want))}{',' * (len(want) == 1)})"
    return out


def _config_sizes(root: zarr.Group) -> dict[str, int]:
    """The sizes the run's settings fix: T (the scenario's frames), D (the parameters)."""
    config: Any = root.attrs.get("config") or {}
    sizes = {}
    if isinstance(config.get("scenario"), Mapping) and isinstance(config["scenario"].get("times"), list):
        sizes["T"] = len(config["scenario"]["times"])
    if isinstance(config.get("param_space"), list):
        sizes["D"] = len(config["param_space"])
    return sizes


def observed_faults(root: zarr.Group) -> dict[str, str]:
    """The arrays of the store ``root``'s ``observed`` group with the wrong shape (:func:`shape_faults`)."""
    return shape_faults(root["observed"], OBSERVED_SHAPES, _config_sizes(root)) if "observed" in root else {}


def round_faults(root: zarr.Group, r: int) -> dict[str, str]:
    """The arrays of the store ``root``'s round ``r`` with the wrong shape (:func:`shape_faults`); the observed
    points P are the observed state's when it has its shape."""
    sizes = _config_sizes(root)
    if "observed" in root and "x" in array_names(root["observed"]) and "x" not in observed_faults(root):
        sizes["P"] = int(root["observed"]["x"].shape[1])
    return shape_faults(root["rounds"][str(r)], ROUND_SHAPES, sizes)


def check_metadata(path: Path, root: zarr.Group) -> None:
    """Every group's and array's ``zarr.json`` under the store ``path`` parses and opens.

    Raises:
        SchemaError: one line naming the first file that does not, and the fix.
    """
    for folder, dirs, files in os.walk(path):
        here = Path(folder)
        if "zarr.json" in files and "c" in dirs:  # an array's chunks: no metadata below
            dirs.remove("c")
        dirs.sort()
        if "zarr.json" not in files or here == path:
            continue
        rel = here.relative_to(path).as_posix()
        try:
            json.loads((here / "zarr.json").read_bytes())
            root[rel]
        except Exception as exc:  # noqa: BLE001 - a garbage or truncated metadata file
            raise SchemaError(f"run store file '{here / 'zarr.json'}' cannot be read ({type(exc).__name__}); "
                              f"{damage_fix(path, rel)}") from None


def _read_rows(arr: zarr.Array, bad: dict[int, str], name: str) -> np.ndarray:
    """``arr[...]``; when a chunk cannot be read, row by row, with the unreadable rows filled
    (``arr.fill_value``) and named in ``bad``."""
    try:
        return arr[...]
    except Exception:  # noqa: BLE001 - a truncated or corrupt chunk fails with the codec's error
        out = np.full(arr.shape, arr.fill_value, dtype=arr.dtype)
        for i in range(arr.shape[0]):
            try:
                out[i] = arr[i]
            except Exception as exc:  # noqa: BLE001
                bad.setdefault(i, f"its '{name}' chunk cannot be read ({type(exc).__name__})")
        return out


def unreadable_groups(root: zarr.Group, rounds: Sequence[int]) -> dict[str, str]:
    """Groups of the store ``root`` holding an array that cannot be read whole (a truncated or corrupt chunk),
    other than the per-simulation arrays of ``rounds`` (:data:`ROW_ARRAYS`), or an array, these included, that reads
    but has the wrong shape (:func:`observed_faults`, :func:`round_faults`): ``{group path: reason}``; the paths
    are ``observed``, ``rounds/<r>``, ``rounds/<r>/posterior`` and the other top-level groups."""
    out: dict[str, str] = {}
    for why in observed_faults(root).values():
        out.setdefault("observed", why)
    for r in rounds:
        for why in round_faults(root, r).values():
            out.setdefault(f"rounds/{r}", why)

    def scan(path: str, g: zarr.Group, skip: tuple[str, ...] = ()) -> None:
        for k in sorted(array_names(g)):
            if k in skip:
                continue
            try:
                g[k][...]
            except Exception as exc:  # noqa: BLE001 - the codec's error for a damaged chunk
                out.setdefault(path, f"its '{k}' array cannot be read ({type(exc).__name__})")

    for name in sorted(group_names(root)):
        if name != "rounds":
            scan(name, root[name])
    for r in rounds:
        g = root["rounds"][str(r)]
        scan(f"rounds/{r}", g, skip=ROW_ARRAYS)
        if "posterior" in g:
            scan(f"rounds/{r}/posterior", g["posterior"])
    return out


def damaged_rows(g: zarr.Group, complete: bool) -> dict[int, str]:
    """The simulations of the round group ``g`` that cannot be trusted, ``{simulation: reason}``: a chunk that
    cannot be read (truncated or corrupt), or one marked done whose state is missing (a deleted chunk reads as its
    fill value); in a ``complete`` round also a pending one (its status chunk is gone)."""
    bad: dict[int, str] = {}
    arrays = {name: _read_rows(g[name], bad, name) for name in ROW_ARRAYS if name in g}
    done = arrays["status"] == 0
    x = arrays["x"].reshape(len(done), int(np.prod(arrays["x"].shape[1:])))  # a round may draw none
    for i in np.nonzero(done & ~np.all(np.isfinite(x), axis=1))[0]:
        bad.setdefault(int(i), "its stored state is missing (a deleted chunk)")
    if complete:  # a complete round has no pending simulation: its status chunk is gone
        for i in np.nonzero(arrays["status"] == STATUS_PENDING)[0]:
            bad.setdefault(int(i), "its status is missing (a deleted chunk)")
    else:  # a pending simulation is (re)written whole when it is simulated
        bad = {i: why for i, why in bad.items() if arrays["status"][i] != STATUS_PENDING}
    return bad
