"""The look every figure shares: one palette of roles, font sizes, resolution, and the headline and layout helpers.

Every figure uses one palette, :data:`ROLE_COLOURS` (Okabe & Ito's colour-blind-safe colours plus
greys): a colour means the same *role* in every figure. Each ``plot_*`` function saves a PNG;
the matching ``*_figure`` function builds the :class:`matplotlib.figure.Figure` without saving it
(tests inspect it).
"""
from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Any, Sequence

#: one colour per role, in every figure of a fit, of ``check``, ``compare`` and ``compare-backends``.
#: Measured data is neutral grey, everything simulated is coloured; the prior is a light grey;
#: the truth (hidden parameters of a simulated measurement) is vermillion.
ROLE_COLOURS: dict[str, str] = {
    "measured": "#5a5a5a",     # dark grey: the measurement (real or simulated with hidden parameters)
    "posterior": "#0072B2",    # blue: posterior samples, rollouts at the posterior
    "prior": "#b0b0b0",        # light grey: the prior box / prior rollouts
    "truth": "#D55E00",        # vermillion: hidden true parameters
    "gripper": "#000000",      # black: the gripper's position
    "nominal": "#E69F00",      # orange: run A of ``compare`` (before, e.g. the nominal model)
    "with_effect": "#009E73",  # bluish green: run B of ``compare`` (after, e.g. with the effect)
    "best_fit": "#AA3377",     # purple (Paul Tol's colour-blind-safe scheme): the fit's best fit and its rollout
    "obstacle": "#788096",     # slate grey: the scenario's rigid obstacles (a block, the winding's spool), as rendered
}
#: engines of ``compare-backends`` (no role: each engine is one simulation), in backend order:
#: sky blue, reddish purple, then brown and dark teal for a third and fourth engine.
ENGINE_COLOURS: tuple[str, ...] = ("#56B4E9", "#CC79A7", "#8C510A", "#01665E")

DPI = 120           # saved resolution of every figure
FS_TITLE = 11       # headline
FS_SUB = 9          # second headline line, axes titles
FS_LABEL = 9        # axis labels
FS_TICK = 8         # tick labels
FS_LEGEND = 8       # legends

def view_planes(view: str = "yz") -> list[tuple[int, int, str]]:
    """The two planes a figure of a scenario draws, the scenario's own first (:attr:`~softsbi.core.types.Scenario.view`:
    ``"xz"``, ``"yz"`` or ``"xy"``), each ``(horizontal axis, vertical axis, name)`` with axes 0-2 = x, y, z and the
    name ``"side view"`` or ``"top view"``: a side view is followed by the top view, the top view by the side view
    across y (x-z), where motion on the table shows its height."""
    side = {"xz": (0, 2, "side view"), "yz": (1, 2, "side view")}
    top = (0, 1, "top view")
    return [top, side["xz"]] if view == "xy" else [side[view], top]


def grip_label(n: int) -> str:
    """Legend text of ``n`` moving handles."""
    return "gripper" if n == 1 else f"{n} grippers"


def _plt():
    """``matplotlib.pyplot`` on the Agg backend, imported on the first figure (it takes a second: commands that
    draw nothing do not pay it)."""
    import matplotlib  # heavy: loaded on the first figure only
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: loaded on the first figure only
    return plt


def save_figure(fig: Any, path: str | Path, dpi: int = DPI) -> Path:
    """Save ``fig`` as a PNG at ``path`` (``dpi`` dots per inch) and close it; returns the path."""
    fig.savefig(path, dpi=dpi)
    _plt().close(fig)
    return Path(path)


def _unit(u: str) -> str:
    """Unit text for an axis label: ``N*m`` -> ``N·m``, ``kg/m^2`` -> ``kg/m²``, ``1`` -> ``-``."""
    if u in ("1", ""):
        return "-"
    return u.replace("*", "·").replace("^2", "²").replace("^3", "³")


def source_name(s: Any) -> str:
    """Short name of a measurement source: the folder/file name of a path, else the text itself."""
    s = str(s or "")
    return Path(s).name if "/" in s or "\\" in s else s


def fit_label(report: dict[str, Any]) -> str:
    """What a fit fitted: ``"mujoco-flex + wind"`` or ``"mujoco-flex (nominal)"``."""
    eff = list(report.get("effects") or [])
    backend = report.get("backend", "?")
    return f"{backend} + {' + '.join(eff)}" if eff else f"{backend} (nominal)"


def _header(fig: Any, lines: Sequence[tuple[str, dict[str, Any]]], pad_px: float = 6.0) -> float:
    """Write ``lines`` (text, text properties) centred at the top of ``fig``, each wrapped so that it
    fits the figure's width; returns the fraction of the figure height they take (for
    ``tight_layout(rect=(0, 0, 1, 1 - frac))``)."""
    renderer = fig.canvas.get_renderer()
    W, H = fig.bbox.width, fig.bbox.height
    y = H - pad_px
    for text, props in lines:
        if not text:
            continue
        props = {"fontsize": FS_SUB, **props}
        t = fig.text(0.5, y / H, text, ha="center", va="top", **props)
        chars = max(20, int(0.98 * W / (0.62 * props["fontsize"] * fig.dpi / 72)))
        while True:
            t.set_text("\n".join(textwrap.fill(p, chars) for p in text.split("\n")))
            bb = t.get_window_extent(renderer)
            if bb.width <= 0.97 * W or chars <= 20:
                break
            chars = int(chars * 0.9)
        y = bb.y0 - 3.0
    return min(0.5, (H - y + pad_px) / H)


def _layout(fig: Any, top_frac: float = 0.0, bottom_frac: float = 0.0) -> None:
    fig.tight_layout(rect=(0, bottom_frac, 1, 1 - top_frac), pad=0.6)


