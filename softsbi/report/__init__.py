"""Every figure and animation softsbi draws (matplotlib, Agg backend).

:mod:`.figures` names every figure: those of a fit (:mod:`.fit_figures`), of check and compare
(:mod:`.check_figures`) and of the engines and scenarios (:mod:`.engine_figures`), in one look (:mod:`.style`).
They draw what they are given; the simulations they show run in :mod:`softsbi.workflows`.
"""
from softsbi.report.figures import (
    fit_label,
    chamfer_rounds_figure,
    plot_chamfer_rounds,
    pairs_figure,
    plot_pairs,
    clouds_figure,
    frames_figure,
    check_headline,
    check_figure,
    plot_check,
    compare_figure,
    plot_compare,
    plot_compare_backends,
    plot_rollout_preview,
    plot_scenario_overlay,
    ROLE_COLOURS,
    ENGINE_COLOURS,
    DPI,
    FS_TITLE,
    FS_SUB,
    FS_LABEL,
    FS_TICK,
    FS_LEGEND,
)

__all__ = ["fit_label", "chamfer_rounds_figure", "plot_chamfer_rounds", "pairs_figure", "plot_pairs", "clouds_figure", "frames_figure", "check_headline", "check_figure", "plot_check", "compare_figure", "plot_compare", "plot_compare_backends", "plot_rollout_preview", "plot_scenario_overlay", "ROLE_COLOURS", "ENGINE_COLOURS", "DPI", "FS_TITLE", "FS_SUB", "FS_LABEL", "FS_TICK", "FS_LEGEND"]
