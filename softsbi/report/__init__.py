"""Every figure and animation softsbi draws (matplotlib, Agg backend).

:mod:`.figures` holds the figures of a fit and of check, compare and compare-backends.
"""
from softsbi.report.figures import (
    fit_label,
    write_fit_plots,
    chamfer_rounds_figure,
    plot_chamfer_rounds,
    pairs_figure,
    plot_pairs,
    clouds_figure,
    plot_clouds,
    plot_frames,
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

__all__ = ["fit_label", "write_fit_plots", "chamfer_rounds_figure", "plot_chamfer_rounds", "pairs_figure", "plot_pairs", "clouds_figure", "plot_clouds", "plot_frames", "check_headline", "check_figure", "plot_check", "compare_figure", "plot_compare", "plot_compare_backends", "plot_rollout_preview", "plot_scenario_overlay", "ROLE_COLOURS", "ENGINE_COLOURS", "DPI", "FS_TITLE", "FS_SUB", "FS_LABEL", "FS_TICK", "FS_LEGEND"]
