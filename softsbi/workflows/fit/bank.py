"""The simulation bank: rollouts stored by what determines them, so that no simulation runs twice.

A rollout is determined by the simulator and its options, the scenario, the effects switched on, the parameters
and the seed (the engines are deterministic). :func:`rollout_key` hashes exactly these; :class:`SimulationBank`
keeps each rollout under its key in a Zarr store (one group per rollout: ``vertices``, ``gripper``, ``faces``,
``times`` and the reason and info in its attributes). Only successful rollouts are kept: a failure may come from
the environment (a timeout, memory) rather than the parameters, and ``fit --retry-failed`` must simulate it again.
The observation, the metric and the sensor model
are computed from the rollout afterwards, so two fits of different recordings of the same task share the
simulations of their first round (drawn from the same prior with the same seed), and ``check``, ``diagnose``,
``compare`` and ``view`` of one run share its posterior-predictive rollouts.

Integrity as for a run store: a rollout is written into a temporary group and renamed into place when complete
(atomic on one file system), so a killed writer leaves nothing half-written; each group carries its key and a
SHA-256 of the key and its arrays, both checked on reading. A damaged or unreadable entry counts as absent, and so
does an entry of the first format, which stored no key (the rollout is simulated again and stored anew); an entry
stored under another key (a folder moved or copied) is not used either, and :class:`BankCount` tells the user how
many there were. Writers need no lock: two processes storing the same key store the same rollout, and the first
rename wins.
"""
from __future__ import annotations

import functools
import hashlib
import json
import os
import shutil
import tempfile
import uuid
from dataclasses import dataclass
from importlib.metadata import version
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import zarr

from softsbi.core.errors import SoftsbiError
from softsbi.core.types import STATUS_OK, Rollout
from softsbi.workflows.fit.config import resume_identity

#: bank format version (part of every key: a new format starts a new bank)
BANK_FORMAT = 1


#: values of ``$SOFTSBI_SIM_BANK`` that switch every bank off (the user's and the runs' own)
OFF = ("off", "none", "0")


#: what :meth:`SimulationBank.lookup` found: the rollout; nothing usable (absent, incomplete, damaged, a failure
#: or an entry of the first format); an intact entry whose stored key is another one (moved or copied there)
HIT, MISS, WRONG_KEY = "hit", "miss", "wrong key"
#: a miss whose successful rollout the bank could not store (a full or read-only disk)
UNSTORED = "miss, not stored"

#: the variable that names the user's bank (or switches every bank off, :data:`OFF`)
ENV = "SOFTSBI_SIM_BANK"


def _variable() -> str:
    """``$SOFTSBI_SIM_BANK`` without surrounding blanks (``""`` when unset)."""
    return os.environ.get(ENV, "").strip()


def banks_enabled() -> bool:
    """False when ``$SOFTSBI_SIM_BANK`` is ``off`` (or ``none``, ``0``): nothing is read from or stored in a bank."""
    return _variable().lower() not in OFF


def default_bank() -> Path | None:
    """The user's simulation bank: ``$SOFTSBI_SIM_BANK``, else ``$XDG_CACHE_HOME/softsbi/sim-bank`` (default
    ``~/.cache/softsbi/sim-bank``); None when banks are off (:func:`banks_enabled`)."""
    if not banks_enabled():
        return None
    if _variable():
        return Path(os.environ[ENV]).expanduser()
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "softsbi" / "sim-bank"


def bank_folder(setting: str) -> Path | None:
    """The folder of a ``--sim-bank`` setting: ``"default"`` the user's (:func:`default_bank`; none when
    ``$SOFTSBI_SIM_BANK`` is ``off``), ``"off"`` none, else that folder (a folder given explicitly wins over
    ``$SOFTSBI_SIM_BANK=off``)."""
    if setting == "off":
        return None
    return default_bank() if setting == "default" else Path(setting).expanduser()


def check_bank_path(setting: str, folders: Mapping[str, str | Path | None]) -> None:
    """Check a fit's simulation bank before any work: ``setting`` is ``--sim-bank`` (``"default"``: the user's
    bank, :func:`default_bank`; ``"off"``; or a folder), ``folders`` the folders the bank must stay out of, by the
    flag that names them (``{"--out": run_dir, "--observed": recording_dir}``, existing or not; None or ``""``
    is skipped). A bank folder that does not exist is created.

    Raises:
        SoftsbiError: one line naming ``--sim-bank`` or ``$SOFTSBI_SIM_BANK`` and the fix when the setting is
            empty; when the bank and one of ``folders`` lie inside one another; when the bank (given by the flag or
            the variable; a folder given by the flag is used even under ``$SOFTSBI_SIM_BANK=off``) is a file,
            cannot be created or cannot be written (read-only, no permission). The default folder is only checked
            against ``folders``:
            a cache that cannot be written only stores nothing.
    """
    if not str(setting).strip():
        raise SoftsbiError("--sim-bank is empty: give the simulation bank's folder, 'default' (the user's bank) "
                           "or 'off' (or --no-sim-bank)")
    if setting == "off" or (setting == "default" and not banks_enabled()):
        return
    if setting == "default":
        path = default_bank()
        name = ENV if _variable() else "the default simulation bank"
        off = f"{ENV}=off" if name == ENV else "--no-sim-bank"
    else:
        path, name, off = Path(setting).expanduser(), "--sim-bank", "--no-sim-bank"
    assert path is not None  # banks are enabled
    where = path.resolve()
    for flag, folder in folders.items():
        if folder is None or not str(folder):
            continue
        f = Path(folder).resolve()
        if where == f or f in where.parents or where in f.parents:
            what = f"{name} {path} is inside {flag} {folder}" if where == f or f in where.parents else \
                f"{flag} {folder} is inside {name} {path}"
            raise SoftsbiError(f"{what}: keep the simulation bank in a folder of its own, outside every run and "
                               f"recording (or {off})")
    if name == "the default simulation bank":
        return
    if path.exists() and not path.is_dir():
        raise SoftsbiError(f"{name} {path} is a file: give a folder for the simulation bank (created if missing), "
                           f"or {off}")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SoftsbiError(f"{name} {path} cannot be created ({exc.strerror or exc}): give a folder you can write, "
                           f"or {off}") from exc
    try:  # a read-only bank would store nothing, said only after the work
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        raise SoftsbiError(f"{name} {path} cannot be written ({exc.strerror or exc}): give a folder you can write, "
                           f"or {off}") from None


@functools.lru_cache(maxsize=None)
def _engine_version(backend: str) -> str:
    """The version of ``backend``'s engine package ("" when unknown), read once per process: reading an installed
    package's metadata takes milliseconds, and every rollout key (each job through a bank) needs it."""
    try:
        return {"mujoco-flex": "mujoco " + version("mujoco"),
                "pybullet-massspring": "pybullet " + version("pybullet")}.get(backend, "")
    except Exception:  # noqa: BLE001 - an unknown engine version only narrows the key
        return ""


def rollout_key(backend: str, backend_options: Mapping[str, Any], scenario: Mapping[str, Any],
                effects: Sequence[str], values: Mapping[str, float], seed: int) -> str:
    """The SHA-256 (hex) of everything a rollout depends on: the simulator (name, options but its speed knobs
    :data:`~softsbi.workflows.fit.config.SPEED_OPTIONS`, engine version), the
    scenario (its JSON form without where it was read from and how it is viewed:
    :func:`~softsbi.workflows.fit.config.resume_identity`, so that the recordings of one task share its rollouts),
    the effects in order, every parameter value (exactly, as ``float.hex``) and the seed."""
    doc = [BANK_FORMAT, backend, _engine_version(backend), resume_identity("backend_options", dict(backend_options)),
           resume_identity("scenario", dict(scenario)), list(effects),
           sorted((k, float(v).hex()) for k, v in values.items()), int(seed)]
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()


def _digest(key: str, arrays: Mapping[str, np.ndarray]) -> str:
    h = hashlib.sha256(key.encode())
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(name.encode() + str(a.dtype).encode() + str(a.shape).encode() + a.tobytes())
    return h.hexdigest()


def _plain(info: Mapping[str, Any]) -> dict[str, Any]:
    """The JSON-able part of a rollout's ``info`` (scalars and strings; arrays are dropped)."""
    out = {}
    for k, v in info.items():
        if isinstance(v, (bool, int, float, str)) or v is None:
            out[k] = v
        elif isinstance(v, np.generic):
            out[k] = v.item()
    return out


class SimulationBank:
    """Rollouts by :func:`rollout_key` in a Zarr store at ``path`` (created on the first store).

    Args:
        path: the store's folder.
        writable: False: read only (a bank on a read-only file system, or one shared by others).
    """

    def __init__(self, path: str | Path, writable: bool = True):
        self.path = Path(path)
        self.writable = writable

    def _where(self, key: str) -> Path:
        return self.path / key[:2] / key

    def get(self, key: str) -> Rollout | None:
        """The stored rollout of ``key``, or None when absent, incomplete, damaged, a failure, of the first format
        or stored under another key (:meth:`lookup`)."""
        return self.lookup(key)[0]

    def lookup(self, key: str) -> tuple[Rollout | None, str]:
        """``(rollout, what)``: the stored rollout of ``key`` and :data:`HIT`; or None and :data:`WRONG_KEY` when
        the entry in ``key``'s place is intact but was stored under another key (moved or copied there); or None
        and :data:`MISS` otherwise (absent, incomplete, damaged, a failure, an entry of the first format)."""
        where = self._where(key)
        if not where.is_dir():
            return None, MISS
        try:
            g = zarr.open_group(str(where), mode="r")
            arrays = {n: np.asarray(g[n][...]) for n in ("times", "gripper", "vertices", "faces")}
            attrs = dict(g.attrs)
            stored, sha256 = attrs.get("key"), attrs.get("sha256")  # an entry of the first format has neither
            if not isinstance(stored, str) or sha256 != _digest(stored, arrays):
                return None, MISS
            if stored != key:
                return None, WRONG_KEY
            if int(attrs["status"]) != STATUS_OK:
                return None, MISS
            return Rollout(times=arrays["times"], gripper=arrays["gripper"], vertices=arrays["vertices"],
                           faces=arrays["faces"].astype(int), status=int(attrs["status"]), reason=str(attrs["reason"]),
                           info=dict(attrs["info"])), HIT  # put writes it with the key
        except Exception:  # noqa: BLE001 - a damaged entry is an absent one: simulated again
            return None, MISS

    def put(self, key: str, ro: Rollout) -> bool:
        """Store ``ro`` under ``key`` (a failed rollout or one with images is not stored: the bank keeps successful
        states). Returns whether it was stored; a bank that cannot be written (read-only, full disk) stores nothing
        and says False."""
        if not self.writable or ro.rgb is not None or int(ro.status) != STATUS_OK:
            return False
        arrays = {"times": np.asarray(ro.times, float), "gripper": np.asarray(ro.gripper, float),
                  "vertices": np.asarray(ro.vertices, float), "faces": np.asarray(ro.faces, np.int64)}
        where = self._where(key)
        tmp = self.path / "tmp" / f"{key}-{uuid.uuid4().hex}"
        try:
            tmp.parent.mkdir(parents=True, exist_ok=True)
            g = zarr.open_group(str(tmp), mode="w")
            for name, a in arrays.items():
                g.create_array(name, data=a)
            g.attrs.update({"status": int(ro.status), "reason": str(ro.reason), "info": _plain(ro.info),
                            "key": key, "sha256": _digest(key, arrays)})
            where.parent.mkdir(parents=True, exist_ok=True)
            if where.exists():  # an entry lookup() turned down (damaged, old, another key's) is replaced
                shutil.rmtree(where, ignore_errors=True)
            os.rename(tmp, where)
            return True
        except OSError:
            shutil.rmtree(tmp, ignore_errors=True)
            return False

    def __len__(self) -> int:
        return sum(1 for d in self.path.glob("??/*") if d.is_dir()) if self.path.is_dir() else 0


@dataclass
class BankCount:
    """What one phase's simulations found in their bank: ``hits`` read instead of simulated, ``wrong_key`` entries
    stored under another key that were simulated again and replaced (:meth:`SimulationBank.lookup`)."""

    hits: int = 0
    wrong_key: int = 0
    unstored: int = 0

    def add(self, what: str | None) -> None:
        """Count one simulation's lookup (a job result's ``"bank"``: :data:`HIT`, :data:`MISS`, :data:`WRONG_KEY`,
        :data:`UNSTORED` or None without a bank)."""
        self.hits += what == HIT
        self.wrong_key += what == WRONG_KEY
        self.unstored += what == UNSTORED

    def warning(self, bank: str | Path | None) -> str | None:
        """The one line that tells the user of entries under the wrong key and of rollouts the bank could not store
        (None when there were none)."""
        said = []
        if self.wrong_key:
            said.append(f"{self.wrong_key} stored rollout(s) sat under another rollout's key (moved or copied); they "
                        f"were not used but simulated again and replaced")
        if self.unstored:
            said.append(f"{self.unstored} rollout(s) could not be stored (the disk is full or read-only); the "
                        f"command goes on, and they are simulated again when next needed: free space on that disk")
        return f"simulation bank {bank}: " + "; ".join(said) if said else None
