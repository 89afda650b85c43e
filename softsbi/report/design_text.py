"""The table and the sentence of ``softsbi design RUN`` (which motion to record next), rendered from its typed result
(:class:`~softsbi.core.results.design.Design`). Pure functions: tested against fixed result objects."""
from __future__ import annotations

from softsbi.core.defaults import INFORMED_MAX_RATIO
from softsbi.core.results.design import TRAINED, Design

#: the first columns of :func:`design_rows` (one more per motion, best first)
DESIGN_COLUMNS = ["candidate", "undecided because"]


def design_columns(d: Design) -> list[str]:
    """The table's columns: the candidate, why it is undecided, then one per motion, best first (the fit's own
    marked, or a rig's recorded ones)."""
    mark = " (recorded)" if d.recorded else " (this fit)"
    return DESIGN_COLUMNS + [m + (mark if m in d.recorded_motions else "") for m in d.motions]


def design_rows(d: Design) -> list[list[str]]:
    """One row per undecided candidate: its name, why it is undecided, and per motion the predicted 90% interval
    width over the prior's (``"0.12"``; ``"0.12 (trained)"`` where a trained task measured it; ``"failed"`` where it
    could not be estimated); a last row counts the candidates each motion informs."""
    rows = []
    for e, why in d.undecided.items():
        cells = []
        for m in d.motions:
            c = d.cell(m, e)
            cells.append("-" if c is None else "failed" if c.width_ratio is None else
                         f"{c.width_ratio:.2f}{' (trained)' if c.source == TRAINED else ''}")
        rows.append([e, why, *cells])
    rows.append(["informed", f"at {INFORMED_MAX_RATIO:g} or less",
                 *(f"{len(d.informed(m))} of {len(d.undecided)}" for m in d.motions)])
    return rows


def _names(effects: tuple[str, ...] | list[str]) -> str:
    e = list(effects)
    return e[0] if len(e) == 1 else ", ".join(e[:-1]) + " and " + e[-1]


def design_advice(d: Design) -> str:
    """The one sentence: which motion to record next and which undecided candidates it informs that no recorded
    motion does, or why none is advised."""
    if not d.undecided:
        return "Nothing is undecided: the diagnosis names one effect or finds nothing missing."
    own = set(d.informed_already)
    recorded = _names([f"the {m}" for m in d.recorded_motions])
    one = len(d.recorded_motions) == 1
    best = d.best
    if best is None:
        left = [e for e in d.undecided if e not in own]
        return (f"No motion weighed informs {_names(left)} beyond what {recorded} do{'es' if one else ''}: record a "
                f"motion that excites {'it' if len(left) == 1 else 'them'} (one with a scenario file: --scenario "
                f"FILE)." if left else
                f"{recorded[0].upper()}{recorded[1:]} already inform{'s' if one else ''} every undecided candidate: "
                f"more recordings (`softsbi diagnose RUN RUN RUN --out DIR`) decide between them.")
    new = [e for e in d.informed(best) if e not in own]
    return (f"Record a {best}: it informs {_names(new)}, which {recorded} do{'es' if one else ''} not (a 90% "
            f"interval under {INFORMED_MAX_RATIO:g} of the prior's).")


def design_text(d: Design) -> list[str]:
    """The advice, then how the widths were found."""
    trained = sum(c.source == TRAINED for c in d.cells)
    how = (f"Each cell is the undecided candidate's predicted 90% interval width over its prior's after one recording "
           f"of the motion (its best-informed parameter; informed at {INFORMED_MAX_RATIO:g} or less): "
           + (f"{trained} from trained tasks' reports (the median over their held-out simulations), " if trained else "")
           + (f"{len(d.cells) - trained} by the linear estimate at this fit's cloth ({d.simulations} simulations: the "
              f"Fisher information of the check's summaries plus the prior's, a bound a trained estimator does not "
              f"reach; " + (f"scaled by {d.efficiency:.2g}, the trained task's widths over the bound on the "
                             f"{d.motion}, the median over the candidates both measure)" if d.efficiency else
                             "no trained task of this motion scales it, so it is optimistic)")
              if len(d.cells) > trained else "")
           + ".")
    return [design_advice(d), how]
