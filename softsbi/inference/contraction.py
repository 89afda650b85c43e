"""Posterior contraction per parameter, in the parameter's own scale.

For each inferred parameter: the width of the posterior's central 90 % interval divided by the
width of the prior's (uniform over the prior box), both measured in the parameter's own scale,
log for log-scaled parameters (the unit coordinates of :class:`~softsbi.core.types.ParamSpace`).
1 means the data taught nothing about it, 0.1 that they narrowed it to a tenth.

A parameter is marked **not informed** when the ratio is above :data:`INFORMED_MAX_RATIO` (0.5):
its 90 % interval then still spans more than half of the prior's, so a value drawn at random from
the prior lands inside it with probability above 0.45. "The hidden value is inside the 90 %
interval" is then nearly automatic and says little about the fit; it is informative only for
parameters that contracted.

Summaries: mean and standard deviation for linear parameters; for log-scaled ones the geometric
mean ``exp(mean(log theta))`` and the multiplicative spread ``exp(std(log theta))`` (read
``g ×/÷ s``: about two thirds of the mass in ``[g / s, g * s]``), since a mean ± std of a
quantity spread over decades is meaningless (e.g. 189.8 ± 224 N/m).
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from softsbi.core.defaults import INFORMED_MAX_RATIO  # width ratio above which a parameter is not informed
from softsbi.core.types import ParamSpace, unit_suffix

__all__ = ["BOUND_MASS_MIN", "BOUND_SLAB", "INFORMED_MAX_RATIO", "WIDEN_FRACTION", "bound_pressure", "bound_sentence",
           "contraction", "contraction_from_report", "format_estimate", "slab_masses", "widened_bounds"]

#: the prior's central 90 % interval spans 0.9 of the box in the parameter's own scale
_PRIOR_WIDTH = 0.9
#: width of the slab next to each prior bound, as a fraction of the range in the parameter's own scale
BOUND_SLAB = 0.05
#: posterior mass in a bound's slab (:data:`BOUND_SLAB`) from which the posterior "presses against" that bound:
#: four times what a posterior the data left flat puts there. Chosen on the statistical benchmark's stored fits:
#: the largest slab mass of any parameter in 24
#: correctly specified fits was 0.08; 6 of 111 misspecified nominal fits and 9 of 24 refitted effect parameters
#: whose hidden value lay within 10% of a bound reached 0.2
BOUND_MASS_MIN = 0.2


def slab_masses(u: np.ndarray, slab: float = BOUND_SLAB) -> np.ndarray:
    """``(D, 2)``: per parameter, the share of the draws ``u`` (``(S, D)`` in unit coordinates, the parameters' own
    scale) in the slab of width ``slab`` next to the lower and the upper prior bound (a flat posterior: ``slab``)."""
    return np.stack([(u <= slab).mean(0), (u >= 1 - slab).mean(0)], axis=1)


def contraction(space: ParamSpace, samples: np.ndarray) -> dict[str, dict[str, Any]]:
    """Per parameter ``{"scale", "center", "spread", "q05", "q95", "width_ratio", "informed", "slab_mass",
    "unit_mean", "unit_std"}`` from
    posterior samples ``(S, D)`` in physical units (module docstring): ``scale`` ``"log"`` or
    ``"linear"``; ``center``/``spread`` the geometric mean and multiplicative spread (log) or the
    mean and standard deviation (linear); ``width_ratio`` the 90 % width ratio to the prior's; ``slab_mass``
    ``[lower, upper]``, the posterior's mass in the slab of width :data:`BOUND_SLAB` next to each prior bound (a
    flat posterior puts :data:`BOUND_SLAB` in each); ``unit_mean``/``unit_std`` the mean and standard deviation in
    unit coordinates (the prior box mapped to [0, 1] in the parameter's own scale: what "switched on" measures its
    distance from an off value in, :func:`~softsbi.workflows.criticism.statistics.off_distance`)."""
    samples = np.atleast_2d(np.asarray(samples, float))
    u = space.to_unit(samples)
    q05, q95 = np.quantile(samples, 0.05, axis=0), np.quantile(samples, 0.95, axis=0)
    uq = np.quantile(u, [0.05, 0.95], axis=0)
    slabs = slab_masses(u)
    out: dict[str, dict[str, Any]] = {}
    for d, p in enumerate(space):
        ratio = float((uq[1, d] - uq[0, d]) / _PRIOR_WIDTH)
        if p.log:
            lg = np.log(samples[:, d])
            center, spread = float(np.exp(lg.mean())), float(np.exp(lg.std()))
        else:
            center, spread = float(samples[:, d].mean()), float(samples[:, d].std())
        out[p.name] = {"scale": "log" if p.log else "linear", "center": center, "spread": spread,
                       "q05": float(q05[d]), "q95": float(q95[d]), "width_ratio": ratio,
                       "informed": bool(ratio <= INFORMED_MAX_RATIO),
                       "slab_mass": [float(m) for m in slabs[d]],
                       "unit_mean": float(u[:, d].mean()), "unit_std": float(u[:, d].std())}
    return out


def contraction_from_report(report: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """``report["contraction"]``, or for a ``report.json`` written before it existed the same entries
    rebuilt from its 90 % intervals (center/spread: the mean and std it stored; for log parameters
    the geometric midpoint of the interval and no spread; no ``slab_mass``)."""
    if report.get("contraction"):
        return dict(report["contraction"])
    space = ParamSpace.from_json(report["parameters"])
    q05 = np.array([[report["posterior_q05"][n] for n in space.names]])
    q95 = np.array([[report["posterior_q95"][n] for n in space.names]])
    u05, u95 = space.to_unit(q05)[0], space.to_unit(q95)[0]
    out = {}
    for d, p in enumerate(space):
        ratio = float((u95[d] - u05[d]) / _PRIOR_WIDTH)
        center = float(np.sqrt(q05[0, d] * q95[0, d])) if p.log else float(report["posterior_mean"][p.name])
        spread = None if p.log else float(report["posterior_std"][p.name])
        out[p.name] = {"scale": "log" if p.log else "linear", "center": center, "spread": spread,
                       "q05": float(q05[0, d]), "q95": float(q95[0, d]), "width_ratio": ratio,
                       "informed": bool(ratio <= INFORMED_MAX_RATIO)}
    return out


def bound_pressure(space: ParamSpace, samples: np.ndarray, slab: float = BOUND_SLAB,
                   min_mass: float = BOUND_MASS_MIN) -> list[dict[str, Any]]:
    """Parameters whose posterior presses against a prior bound.

    A posterior that piles up at the edge of the prior box says that the data would put the parameter
    beyond it: the prior is too narrow for this measurement, or the model compensates there for something
    it lacks (a misspecified fit pushing friction to its upper bound). For each parameter and each bound,
    the share of posterior samples in the slab of width ``slab`` (fraction of the range, in the
    parameter's own scale: log for log-scaled ones) next to the bound; a flat posterior puts ``slab``
    there, so ``min_mass`` (:data:`BOUND_MASS_MIN`) is a pile-up, not a wide posterior.

    Args:
        space: the inferred parameters (their prior box).
        samples: ``(S, D)`` posterior draws in physical units, ``S >= 1``.
        slab, min_mass: fractions in ``(0, 1)``.

    Returns:
        one ``{"param", "side" ("lower"/"upper"), "bound" (physical units), "unit", "mass", "suggested_bounds"}``
        per bound pressed, largest mass first; ``[]`` when none. ``suggested_bounds``: ``[low, high]``, the prior
        with this bound moved half the range outward (:func:`widened_bounds`), or None when the bound is the
        parameter's physical limit (no wider prior can help).

    Raises:
        ValueError: ``samples`` not ``(S, space.dim)`` or ``slab``/``min_mass`` outside ``(0, 1)``.
    """
    samples = np.atleast_2d(np.asarray(samples, float))
    if samples.shape[1] != space.dim or len(samples) == 0:
        raise ValueError(f"bound_pressure needs samples of shape (S, {space.dim}), got {samples.shape}")
    if not (0 < slab < 1 and 0 < min_mass < 1):
        raise ValueError(f"slab and min_mass must lie in (0, 1), got {slab} and {min_mass}")
    slabs = slab_masses(space.to_unit(samples), slab)
    out = []
    for d, p in enumerate(space):
        for side, mass, bound in (("lower", float(slabs[d, 0]), p.low), ("upper", float(slabs[d, 1]), p.high)):
            if mass >= min_mass:
                e = {"param": p.name, "side": side, "bound": float(bound), "unit": p.unit, "mass": mass}
                wide = widened_bounds(space, [e]).get(p.name)
                # the prior :func:`widened_bounds` would try next, or None when the bound is a physical limit
                e["suggested_bounds"] = [wide[0], wide[1]] if wide else None
                out.append(e)
    return sorted(out, key=lambda e: -e["mass"])


#: how far :func:`widened_bounds` moves a pressed prior bound outward: this fraction of the prior's range, in the
#: parameter's own scale (log for log-scaled ones). Chosen, not tuned: half the range puts the old bound at a third
#: (or two thirds) of the new one, inside it with room on both sides, while the prior stays as informative as
#: the user's guess allows (one widening, not a search)
WIDEN_FRACTION = 0.5


def widened_bounds(space: ParamSpace, pressed: Sequence[Mapping[str, Any]], keep: Mapping[str, float] | None = None,
                   fraction: float = WIDEN_FRACTION) -> dict[str, tuple[float, float]]:
    """Prior bounds widened where a posterior presses against them (:func:`bound_pressure`'s entries).

    Each pressed bound moves outward by ``fraction`` of the parameter's prior range in its own scale (log for
    log-scaled parameters), clipped to its physical limits (:attr:`~softsbi.core.types.Param.physical_limits`).
    A bound is not moved when it equals ``keep[param]`` (an effect's switched-off value: no noise, a rigid grasp
    is an edge of what the effect can be, not a guess) or a physical limit.

    Args:
        space: the prior (physical units).
        pressed: ``{"param", "side" ("lower"/"upper"), ...}`` entries; parameters not in ``space`` are ignored.
        keep: values whose bound stays where it is, by parameter name.
        fraction: in ``(0, 10]``.

    Returns:
        ``{param: (low, high)}`` in physical units for the parameters widened; ``{}`` when none can be.

    Raises:
        ValueError: ``fraction`` outside ``(0, 10]`` or a side other than ``"lower"``/``"upper"``.
    """
    if not 0 < fraction <= 10:
        raise ValueError(f"fraction must lie in (0, 10], got {fraction}")
    keep = dict(keep or {})
    out: dict[str, tuple[float, float]] = {}
    for e in pressed:
        if e["param"] not in space.names:
            continue
        if e["side"] not in ("lower", "upper"):
            raise ValueError(f"side must be 'lower' or 'upper', got {e['side']!r}")
        p = space[e["param"]]
        lo, hi = out.get(p.name, (p.low, p.high))
        bound = p.low if e["side"] == "lower" else p.high
        limit = p.physical_limits[0] if e["side"] == "lower" else p.physical_limits[1]
        if (p.name in keep and np.isclose(keep[p.name], bound)) or bound == limit:
            continue
        t0, t1 = (np.log(p.low), np.log(p.high)) if p.log else (p.low, p.high)
        step = fraction * (t1 - t0)
        if e["side"] == "lower":
            new = float(np.exp(t0 - step)) if p.log else t0 - step
            lo = max(new, limit)
        else:
            new = float(np.exp(t1 + step)) if p.log else t1 + step
            hi = min(new, limit)
        out[p.name] = (float(lo), float(hi))
    return out


def bound_sentence(e: Mapping[str, Any], slab: float = BOUND_SLAB) -> str:
    """One entry of :func:`bound_pressure` in words, with the fix (``--bounds``)."""
    unit = unit_suffix(e.get("unit"))
    head = (f"{e['param']}'s posterior presses against its {e['side']} prior bound {e['bound']:.4g}{unit} "
            f"({e['mass'] * 100:.0f}% of its mass within {slab * 100:.0f}% of the range from it): the data would put "
            f"it beyond; ")
    suspect = "an effect the model lacks and compensates for here (softsbi check, softsbi diagnose)"
    if "suggested_bounds" in e and e["suggested_bounds"] is None:
        return head + f"the bound is the parameter's physical limit, so no wider prior can help: suspect {suspect}"
    if e.get("suggested_bounds"):
        lo, hi = e["suggested_bounds"]
        widen = f"{lo:.4g}:{hi:.4g}"
    else:  # entries stored before the suggestion was
        widen = "LOW:HIGHER" if e["side"] == "upper" else "LOWER:HIGH"
    return head + (f"widen the prior (--bounds {e['param']}={widen}) if such values are physical, or suspect "
                   f"{suspect}")


def format_estimate(c: Mapping[str, Any]) -> str:
    """``"1.9e+02 ×/÷ 3.1"`` (log) or ``"0.52 ± 0.11"`` (linear) for one entry of :func:`contraction`."""
    if c.get("spread") is None:
        return f"{c['center']:.4g}"
    if c["scale"] == "log":
        return f"{c['center']:.4g} ×/÷ {c['spread']:.3g}"
    return f"{c['center']:.4g} ± {c['spread']:.3g}"
