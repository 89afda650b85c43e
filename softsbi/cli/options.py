"""What several commands' options share: one help text per quantity, the parse-time bounds (typer callbacks) and the
parsers of ``name=value`` lists."""
from __future__ import annotations

import math
import re
from enum import Enum
from typing import Any

import typer

from softsbi.core.errors import SoftsbiError
from softsbi.core import defaults as D
from softsbi.core.defaults import Bound

#: help texts shared by several commands (one option name and one text per quantity)
H_JSON = "print one JSON document on stdout (results, or the error) instead of tables"
H_WORKERS = "simulation worker processes (default: one per core)"
H_SEED = "random seed: fixes every parameter draw and every simulation"
H_N_EVAL = "rollouts at posterior samples (the posterior-predictive check's sample size)"
H_MAX_NULL = ("cap of the adaptive null: when 1/(n+1) > alpha and the first n posterior-predictive rollouts give "
              "p <= 0.1, simulate up to this many before deciding (p is never printed below 1/(cap+1))")
H_RECOMPUTE = "compute again even when the run holds this command's result for the same fit and settings"
H_ALPHA = "family-wise significance level of the verdicts (the tolerated false-alarm rate)"
H_BACKEND = "simulator plugin: mujoco-flex or pybullet-massspring built in (`softsbi plugins` lists the installed ones)"
H_ESTIMATOR = ("posterior estimator plugin: rkhs (the paper's), mdnn, flow, mdrff, bayeszoom-rkhs, nn-bulk, gp-bulk, "
               "sbi-npe (`softsbi plugins` lists the installed ones)")
H_PROPOSAL = ("how later rounds draw parameters: truncated (TSNPE: from the prior truncated to the posterior's "
              "99.9% region; robust in many dimensions) or corrected (the paper's BayesSim: from the posterior "
              "p/p~*q)")


class Proposal(str, Enum):
    """Choices of ``--proposal`` (listed by ``--help``)."""
    corrected = "corrected"
    truncated = "truncated"


def checked(limit: Bound):
    """A typer option callback that refuses, when the flags are parsed (before any work), a value outside ``limit``
    (:class:`~softsbi.core.defaults.Bound`: the words the workflows refuse it with too): "Invalid value for
    '--n-null': must be >= 5 (got 1): why", exit code 2. ``None`` (an unset optional flag) passes."""

    def check(ctx: typer.Context, param: typer.CallbackParam, value: float | None) -> float | None:
        why = limit.problem(value)
        if why is not None:
            raise typer.BadParameter(why, ctx=ctx, param=param)
        return value
    return check


def bound(low: float, why: str = "", strict: bool = False):
    """:func:`checked` for a float flag without a bound of its own in :mod:`~softsbi.core.defaults`: a finite number
    at least ``low`` (more than it when ``strict``)."""
    return checked(Bound("", low, why, strict))


def setting(settings: type, name: str, help: str) -> Any:
    """The typer option of setting ``name`` of a settings class (:class:`~softsbi.core.defaults.CheckSettings`,
    :class:`~softsbi.core.defaults.DiagnoseSettings`): its flag, default and bound are the class's, so the
    command and the Python API cannot disagree."""
    limit = settings.BOUNDS[name]
    return typer.Option(settings.__dataclass_fields__[name].default, limit.flag, help=help, callback=checked(limit))


#: the option callbacks shared by several commands
WORKERS_OK = checked(D.WORKERS_BOUND)
SEED_OK = checked(D.SEED_BOUND)
ROUNDS_OK = checked(D.ROUNDS_BOUND)
SIMS_OK = checked(D.SIMS_BOUND)
POINTS_OK = checked(D.POINTS_BOUND)
IMAGE_SIZE_OK = checked(D.IMAGE_SIZE_BOUND)


def names(items: list[str] | None, flag: str) -> list[str]:
    """The names of a repeatable, comma-separated option (``--effect wind --effect a,b`` -> ``[wind, a, b]``), every
    command's (``flag``: the option, e.g. ``--effect``, ``--candidate``, which the refusal names).

    Raises:
        SoftsbiError: an item that names nothing (``''``, ``,``), which would otherwise be dropped silently (and
            e.g. ``fit --effect ''`` fit the nominal model, ``diagnose --candidate ''`` weigh the default
            candidates)."""
    out = []
    for it in items or []:
        got = [n for n in it.split(",") if n.strip()]
        if not got:
            raise SoftsbiError(f"{flag} '{it}' names nothing: give a name (several comma-separated), or leave {flag} "
                               f"out")
        out += got
    return out


def parse_kv(items: list[str] | None, what: str) -> dict[str, Any]:
    """``name=value`` items of option ``what`` (repeatable, comma-separated; lists as ``name=[1,2]``) as a dict of
    numbers, booleans or strings. Raises SoftsbiError naming ``what`` on an item without ``=`` or a value that is NaN
    or infinite."""
    out: dict[str, Any] = {}
    for it in items or []:
        for part in re.split(r",(?![^\[]*\])", it):  # commas inside [..] belong to a list value
            if not part:
                continue
            if "=" not in part:
                raise SoftsbiError(f"{what} '{part}' must look like name=value (lists as name=[1,2])")
            k, v = part.split("=", 1)
            out[k.strip()] = _num(v.strip(), f"{what} '{part}'")
    return out


def _num(v: str, where: str) -> Any:
    if v.startswith("[") and v.endswith("]"):
        return [_num(x.strip(), where) for x in v[1:-1].split(",") if x.strip()]
    for cast in (int, float):
        try:
            x = cast(v)
        except ValueError:
            continue
        return _finite(x, where)
    return {"true": True, "false": False}.get(v.lower(), v)


def _finite(x: float, where: str) -> float:
    """``x``, or SoftsbiError naming ``where`` when it is NaN or infinite (Python's float() reads 'nan', 'inf')."""
    if isinstance(x, float) and not math.isfinite(x):
        raise SoftsbiError(f"{where}: {x} is not a finite number; give a number")
    return x


def parse_bounds(items: list[str] | None) -> dict[str, tuple[float, float]]:
    """``--bounds name=low:high`` items (repeatable, comma-separated) as ``{name: (low, high)}``. Raises SoftsbiError
    on an item of another shape, or a bound that is NaN or infinite."""
    out = {}
    for it in items or []:
        for part in it.split(","):
            try:
                k, rng = part.split("=", 1)
                lo, hi = rng.split(":")
                out[k.strip()] = (float(lo), float(hi))
            except ValueError:
                raise SoftsbiError(f"--bounds '{part}' must look like name=low:high (e.g. friction=0.1:1.5)") from None
            for x in out[k.strip()]:
                _finite(x, f"--bounds '{part}'")
    return out
