"""Every PNG figure softsbi draws, by one name: the shared look (:mod:`.style`), the figures of a fit
(:mod:`.fit_figures`), of ``check`` and ``compare`` (:mod:`.check_figures`) and of the engines and scenarios
(:mod:`.engine_figures`: ``compare-backends``, ``simulate``'s preview, a measured frame over a scenario)."""
from softsbi.report.check_figures import (PHASE_LABEL_ROTATION, check_figure, check_headline, compare_figure,
                                          plot_check, plot_compare, short_p)
from softsbi.report.engine_figures import (PREVIEW_LABEL_ROOM, plot_compare_backends, plot_rollout_preview,
                                           plot_scenario_overlay, rollout_preview_figure)
from softsbi.report.fit_figures import (_param_ticks, _tick_texts, chamfer_rounds_figure, clouds_figure,  # noqa: F401
                                        frames_figure, pairs_figure, plot_chamfer_rounds, plot_pairs)
from softsbi.report.style import (DPI, ENGINE_COLOURS, FS_LABEL, FS_LEGEND, FS_SUB, FS_TICK, FS_TITLE, ROLE_COLOURS,
                                  fit_label, grip_label, save_figure, source_name)

__all__ = ["DPI", "ENGINE_COLOURS", "FS_LABEL", "FS_LEGEND", "FS_SUB", "FS_TICK", "FS_TITLE", "PHASE_LABEL_ROTATION",
           "PREVIEW_LABEL_ROOM", "ROLE_COLOURS", "chamfer_rounds_figure", "check_figure", "check_headline",
           "clouds_figure", "compare_figure", "fit_label", "frames_figure", "grip_label", "pairs_figure",
           "plot_chamfer_rounds", "plot_check", "plot_compare", "plot_compare_backends", "plot_pairs",
           "plot_rollout_preview", "plot_scenario_overlay", "rollout_preview_figure", "save_figure", "short_p",
           "source_name"]
