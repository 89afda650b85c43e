"""A round's posterior in the run store (``rounds/<r>/posterior``): a mixture's arrays, or the state of the estimator
that gives it (any estimator), with its format (:data:`POSTERIOR_FORMAT`) and a sha256 checksum of its content, so
that a damaged posterior is named in one line, never used (:class:`~softsbi.core.store.RunStore` writes and reads
it through :func:`encode_posterior`, :func:`write_posterior` and :func:`read_posterior_group`)."""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import numpy as np
import zarr

from softsbi.core.distributions import MixtureOfGaussians
from softsbi.core.errors import PosteriorDamaged, SchemaError
from softsbi.core.store.damage import array_names
from softsbi.core.types import jsonable

#: format of a round's ``posterior`` group
POSTERIOR_FORMAT = "softsbi.posterior/1"


@dataclass
class EstimatorState:
    """What restores a fitted posterior estimator: its plugin ``name``, the constructor ``options`` and
    ``state`` (its :meth:`~softsbi.core.interfaces.PosteriorEstimator.state_dict`)."""

    name: str
    options: dict[str, Any]
    state: dict[str, Any]


#: marks an array in a stored state dict (its name under ``posterior/state``)
_ARRAY = "$array"


def _encode_state(obj: Any, arrays: dict[str, np.ndarray], what: str) -> Any:
    """JSON skeleton of a state dict; every array goes to ``arrays`` under a new name."""
    if isinstance(obj, Mapping):
        if _ARRAY in obj:
            raise SchemaError(f"{what} uses the reserved key {_ARRAY!r}; rename it")
        return {str(k): _encode_state(v, arrays, what) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_encode_state(v, arrays, what) for v in obj]
    if obj is None or isinstance(obj, (bool, int, float, str, np.generic)):
        return jsonable(obj)
    if hasattr(obj, "__array__"):
        a = np.asarray(obj.detach() if hasattr(obj, "detach") else obj)
        if a.dtype == object:
            raise SchemaError(f"{what} holds an array of Python objects; give numbers")
        name = str(len(arrays))
        arrays[name] = a
        return {_ARRAY: name}
    raise SchemaError(f"{what} holds a {type(obj).__name__}; a state dict holds NumPy arrays, numbers, strings, "
                      f"None, and dicts and lists of them")


def _decode_state(skeleton: Any, arrays: Mapping[str, np.ndarray]) -> Any:
    """Inverse of :func:`_encode_state` (tuples come back as lists)."""
    if isinstance(skeleton, Mapping):
        if set(skeleton) == {_ARRAY}:
            return arrays[skeleton[_ARRAY]]
        return {k: _decode_state(v, arrays) for k, v in skeleton.items()}
    if isinstance(skeleton, list):
        return [_decode_state(v, arrays) for v in skeleton]
    return skeleton


def _checksum(attrs: Mapping[str, Any], arrays: Mapping[str, np.ndarray]) -> str:
    """``sha256:<hex>`` of a group's attributes (canonical JSON) and arrays (name, dtype, shape, bytes)."""
    h = hashlib.sha256(json.dumps(jsonable(dict(attrs)), sort_keys=True).encode())
    for k in sorted(arrays):
        a = np.ascontiguousarray(arrays[k])
        h.update(f"{k}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return "sha256:" + h.hexdigest()


def put_array(g: zarr.Group, name: str, value: np.ndarray, dims: tuple[str, ...], units: str) -> None:
    """Write ``value`` as array ``name`` of ``g`` (replacing one of that name) with its dimension names ``dims``
    and ``units`` in its attributes: the one way arrays go into the run store."""
    value = np.asarray(value)
    if name in g:
        del g[name]
    arr = g.create_array(name, shape=value.shape, dtype=value.dtype, dimension_names=dims,
                         attributes={"units": units})
    arr[...] = value


def encode_posterior(q: Any, estimator: EstimatorState | None, what: str) -> tuple[dict[str, np.ndarray],
                                                                                    dict[str, Any]]:
    """``(arrays, attrs)`` that keep the posterior ``q`` of ``what`` (e.g. ``"round 2"``): a
    :class:`MixtureOfGaussians` as its ``weights (C,)``, ``means (C, D)`` and ``scale_tril (C, D, D)`` (unit cube),
    any other ``q`` as the state of the ``estimator`` that gives it (every array of its state dict named in
    ``arrays``). Encoded before anything is written: a state that cannot be stored changes nothing.

    Raises:
        SchemaError: ``q`` is not a mixture and no ``estimator`` state is given, or the state holds a value
            other than NumPy arrays (or array-likes), numbers, strings, None, and dicts and lists of them.
    """
    if isinstance(q, MixtureOfGaussians):
        return {"weights": q.weights, "means": q.means, "scale_tril": q.scale_tril}, {"kind": "mixture"}
    if estimator is None:
        raise SchemaError(f"{what}: a posterior of type {type(q).__name__} is stored as the state of "
                          f"its estimator; pass estimator=EstimatorState(name, options, state_dict())")
    arrays: dict[str, np.ndarray] = {}
    attrs = {"kind": "estimator", "estimator": estimator.name, "options": jsonable(dict(estimator.options)),
             "state": _encode_state(estimator.state, arrays, f"{what}'s estimator state")}
    return arrays, attrs


def write_posterior(p: zarr.Group, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Any]) -> None:
    """Write :func:`encode_posterior`'s ``arrays`` and ``attrs`` into the empty ``posterior`` group ``p``, with
    the format and the checksum of the content."""
    if attrs["kind"] == "mixture":
        put_array(p, "weights", arrays["weights"], ("component",), "1")
        put_array(p, "means", arrays["means"], ("component", "parameter"), "unit cube")
        put_array(p, "scale_tril", arrays["scale_tril"], ("component", "parameter", "parameter2"), "unit cube")
    else:
        s = p.require_group("state")
        for name, a in arrays.items():
            put_array(s, name, a, tuple(f"dim_{i}" for i in range(a.ndim)), "")
    attrs = {**attrs, "format": POSTERIOR_FORMAT}
    attrs["checksum"] = _checksum(attrs, arrays)
    p.attrs.update(attrs)


def read_posterior_group(open_group: Callable[[], zarr.Group], where: str, fix: str,
                         written_by: str) -> MixtureOfGaussians | EstimatorState:
    """The posterior in the group ``open_group()`` returns: the mixture, or the :class:`EstimatorState` to
    restore the estimator from, after checking the stored checksum (version-1 runs: mixtures without kind or
    checksum).

    Args:
        where: what the posterior is, for the error (e.g. ``"run 'r': round 2's stored posterior"``).
        fix: what restores it. written_by: the softsbi version that wrote the run.

    Raises:
        PosteriorDamaged: the group is missing, cannot be read, or does not match its checksum (``where`` and ``fix``).
        SchemaError: a posterior format this softsbi does not read.
    """
    try:
        p = open_group()
        attrs = dict(p.attrs)
        kind = attrs.get("kind", "mixture")  # version-1 runs: mixtures without kind or checksum
        if attrs.get("format", POSTERIOR_FORMAT) != POSTERIOR_FORMAT:
            raise SchemaError(f"{where} has format {attrs['format']!r}, this softsbi reads {POSTERIOR_FORMAT}; "
                              f"install the softsbi version that wrote it ({written_by})")
        if kind == "mixture":
            arrays = {k: p[k][...] for k in ("weights", "means", "scale_tril")}
        else:
            s = p["state"]
            arrays = {k: s[k][...] for k in array_names(s)}
    except SchemaError:
        raise
    except Exception as exc:  # noqa: BLE001 - a deleted group/array (KeyError) or an unreadable chunk
        raise PosteriorDamaged(f"{where} is missing or cannot be read ({type(exc).__name__}: {exc})", fix) from None
    if "checksum" in attrs:
        content = {k: v for k, v in attrs.items() if k != "checksum"}
        if _checksum(content, arrays) != attrs["checksum"]:
            raise PosteriorDamaged(f"{where} does not match its checksum (a damaged or changed file)", fix)
    if kind == "mixture":
        return MixtureOfGaussians(arrays["weights"], arrays["means"], arrays["scale_tril"])
    return EstimatorState(str(attrs["estimator"]), dict(attrs.get("options") or {}),
                          _decode_state(attrs["state"], arrays))
