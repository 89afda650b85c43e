"""Figures: readable pair plots at D = 2..8, the prior box and truth drawn, headlines that fit the
figure, one role palette across the figures."""
import dataclasses
from types import SimpleNamespace
from unittest import mock

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.colors import to_rgba
from matplotlib.patches import Rectangle
from matplotlib.text import Text

from result_helpers import REGIONS, check_result, joint
from softsbi.core.results.comparison import CompareResult
from softsbi.core.types import Param, ParamSpace
from softsbi.report import figures as R

PARAMS = [Param("bend", 1e-6, 1e-3, "N*m", log=True), Param("stretch", 5.0, 1000.0, "N/m", log=True),
          Param("friction", 0.05, 1.5, "1"), Param("scale", 0.20, 0.34, "m"), Param("mass", 0.1, 0.35, "kg/m^2"),
          Param("wind_x", -2.0, 2.0, "m/s"), Param("wind_y", -2.0, 2.0, "m/s"),
          Param("grip_timeconst", 0.008, 0.3, "s", log=True)]


def _space_samples(D, n=2000, seed=0):
    sp = ParamSpace(PARAMS[:D])
    rng = np.random.default_rng(seed)
    th = sp.from_unit(np.clip(rng.normal(0.4, 0.12, (n, D)), 0, 1))
    truth = sp.as_dict(sp.from_unit(np.full(D, 0.45)))
    return sp, th, truth


def _drawn_texts(fig):
    """``(text, window extent)`` of every non-empty text the renderer actually draws."""
    drawn = []
    orig = Text.draw

    def record(self, renderer):
        orig(self, renderer)
        if self.get_visible() and self.get_text().strip():
            drawn.append((self, self.get_window_extent(renderer)))

    with mock.patch.object(Text, "draw", record):
        fig.canvas.draw()
    return drawn


def _assert_texts_inside(fig, min_pt=7.0):
    W, H = fig.bbox.width, fig.bbox.height
    texts = _drawn_texts(fig)
    assert texts
    for t, bb in texts:
        assert bb.x0 >= -1 and bb.y0 >= -1 and bb.x1 <= W + 1 and bb.y1 <= H + 1, \
            f"text {t.get_text()!r} at {bb} is clipped by the {W}x{H} figure"
        assert t.get_fontsize() >= min_pt, f"text {t.get_text()!r} has font size {t.get_fontsize()} < {min_pt} pt"


def _same_colour(a, b):
    return np.allclose(to_rgba(a)[:3], to_rgba(b)[:3])


def test_pairs_d7_draws_prior_box_truth_and_few_outer_ticks(tmp_path):
    D = 7
    sp, th, truth = _space_samples(D)
    fig = R.pairs_figure(sp, th, truth, subtitle="fit: mujoco-flex + wind; measurement: simulated:mujoco-flex+wind")
    axes = np.array(fig.axes).reshape(D, D)
    prior, tc = R.ROLE_COLOURS["prior"], R.ROLE_COLOURS["truth"]
    for i in range(D):
        for j in range(D):
            ax = axes[i, j]
            if j > i:
                assert not ax.axison
                continue
            # at most 3 ticks per axis, labels only on the outer row / column
            assert len(ax.get_xticks()) <= 3 and (i == j or len(ax.get_yticks()) <= 3)
            assert any(tk.label1.get_visible() for tk in ax.xaxis.get_major_ticks()) == (i == D - 1)
            if i == j:
                assert not ax.get_yticks().size
                assert any(_same_colour(c.get_facecolor()[0], prior) for c in ax.collections), "prior band"
                assert any(_same_colour(ln.get_color(), tc) for ln in ax.lines), "truth line"
            else:
                assert any(tk.label1.get_visible() for tk in ax.yaxis.get_major_ticks()) == (j == 0)
                boxes = [p for p in ax.patches if isinstance(p, Rectangle) and _same_colour(p.get_edgecolor(), prior)]
                assert boxes, "prior box outline"
                lo, hi = ax.get_xlim()
                assert lo < PARAMS[j].low and hi > PARAMS[j].high, "the prior box shows inside the axes"
                assert any(_same_colour(ln.get_color(), tc) for ln in ax.lines), "truth marker"
                assert _same_colour(ax.collections[0].get_facecolor()[0], R.ROLE_COLOURS["posterior"])
    legend = axes[0, -1].get_legend()
    labels = [t.get_text() for t in legend.get_texts()]
    assert any(lab.startswith("prior") for lab in labels) and any(lab.startswith("truth") for lab in labels)
    assert fig.get_figwidth() <= 13 and fig.get_figheight() <= 13.5
    _assert_texts_inside(fig)
    plt.close(fig)
    path = R.plot_pairs(tmp_path / "pairs.png", sp, th, truth)
    assert path.stat().st_size > 20_000


@pytest.mark.parametrize("D", [2, 4, 8])
def test_pairs_readable_for_every_dimension(D):
    sp, th, truth = _space_samples(D, n=500)
    fig = R.pairs_figure(sp, th, truth if D != 4 else None)
    assert 5.5 <= fig.get_figwidth() <= 13
    labels = [t for t in fig.axes[-1].get_xticklabels() if t.get_visible() and t.get_text()]
    assert 1 <= len(labels) <= 3
    _assert_texts_inside(fig)
    if D == 4:  # no truth: no truth legend entry
        assert not any("truth" in t.get_text() for t in fig.axes[D - 1].get_legend().get_texts())
    plt.close(fig)


def test_param_ticks_are_round_and_labels_consistent():
    assert R._param_ticks(Param("b", 1e-6, 1e-3, log=True)) == [1e-6, 1e-4]
    assert R._param_ticks(Param("s", 80.0, 600.0, log=True)) == [100.0, 200.0, 500.0]
    assert R._param_ticks(Param("w", -2.0, 2.0)) == [-2.0, 0.0, 2.0]
    assert R._tick_texts([1e-6, 1e-4]) == ["$10^{-6}$", "$10^{-4}$"]
    assert R._tick_texts([10.0, 100.0, 1000.0]) == ["10", "100", "1000"]
    assert R._tick_texts([-2.0, 0.0, 2.0]) == ["\u22122", "0", "2"]


@pytest.mark.parametrize("long", [False, True])
def test_check_headline_gives_the_verdict_and_fits_the_figure(tmp_path, long):
    out = check_result(long=long)
    fig = R.check_figure(out)
    texts = [t.get_text() for t in fig.texts]
    head = texts[0].replace("\n", " ")
    assert f"{out.chamfer_mean_m * 100:.2f} cm" in head and "late phase" in head and "p ≤ 2/201" in head
    assert "NOT" in head
    _assert_texts_inside(fig)
    plt.close(fig)
    assert R.plot_check(tmp_path / "check.png", out).stat().st_size > 10_000


def test_compare_uses_the_before_after_roles(tmp_path):
    a, b = check_result(), check_result(test=joint(12, 20, n=30))
    res = CompareResult(run_a="a", run_b="b", label_a="mujoco-flex (nominal)", label_b="mujoco-flex + wind", rows=(), same_sensor=True, check_a=a, check_b=b)
    fig = R.compare_figure(res)
    assert "p ≤ 2/201 → p = 0.84 (30 sims)" in fig.texts[0].get_text().replace("\n", " ")
    cols = [ln.get_color() for ln in fig.axes[0].lines]
    assert _same_colour(cols[0], R.ROLE_COLOURS["nominal"]) and _same_colour(cols[1], R.ROLE_COLOURS["with_effect"])
    bars = fig.axes[1].patches
    assert _same_colour(bars[0].get_facecolor(), R.ROLE_COLOURS["nominal"])
    assert _same_colour(bars[-1].get_facecolor(), R.ROLE_COLOURS["with_effect"])
    _assert_texts_inside(fig)
    plt.close(fig)
    assert R.plot_compare(tmp_path / "compare.png", res).stat().st_size > 10_000


def _scenario(T=12, name="lift", view="yz"):
    t = np.linspace(0, 1, T)
    return SimpleNamespace(name=name, n_frames=T, times=t, view=view,
                           gripper=np.stack([np.zeros(T), 0.1 - 0.1 * t, 0.08 + 0.3 * t], 1))


def test_clouds_use_the_palette_and_one_legend():
    sc = _scenario()
    rng = np.random.default_rng(0)
    dense = rng.normal(0, 0.05, (sc.n_frames, 300, 3))
    sim = rng.normal(0, 0.05, (sc.n_frames, 400, 3))
    fig = R.clouds_figure(sc, dense, sim, (0, 4, 8, 11), title="fit: mujoco-flex (nominal); measurement: x")
    ax = fig.axes[0]
    assert _same_colour(ax.collections[0].get_facecolor()[0], R.ROLE_COLOURS["measured"])
    assert _same_colour(ax.collections[1].get_facecolor()[0], R.ROLE_COLOURS["posterior"])
    assert [t.get_text() for t in fig.legends[0].get_texts()] == ["measured", "simulated at the posterior median",
                                                                  "gripper"]
    _assert_texts_inside(fig)
    plt.close(fig)


def test_chamfer_rounds_is_titled_with_the_fit_not_the_measurement():
    rep = {"observed": "simulated:mujoco-flex+wind", "backend": "mujoco-flex", "effects": [],
           "chamfer_prior_m": 0.07, "chamfer_prior_std_m": 0.01,
           "per_round": [{"round": 0, "chamfer_posterior_m": 0.06, "chamfer_posterior_std_m": 0.005},
                         {"round": 1, "chamfer_posterior_m": 0.05, "chamfer_posterior_std_m": 0.004}]}
    fig = R.chamfer_rounds_figure(rep)
    head, sub = (t.get_text() for t in fig.texts)
    assert "mujoco-flex (nominal)" in head and "wind" not in head
    assert sub == "measurement: simulated:mujoco-flex+wind"
    _assert_texts_inside(fig)
    plt.close(fig)
    fig = R.chamfer_rounds_figure({**rep, "effects": ["wind"]})
    assert "mujoco-flex + wind" in fig.texts[0].get_text()
    plt.close(fig)


def test_chamfer_rounds_tells_proposal_rollouts_from_the_posterior_predictive():
    """Under truncated proposals a round's rollouts come from the truncated prior, not the posterior:
    the figure must not call them "posterior"; the last point is the posterior predictive (the reported
    number)."""
    rep = {"observed": "x", "backend": "mujoco-flex", "effects": [], "proposal": "truncated",
           "chamfer_prior_m": 0.043, "chamfer_prior_std_m": 0.013, "chamfer_posterior_m": 0.0163,
           "per_round": [{"round": r, "chamfer_posterior_m": m, "chamfer_posterior_std_m": 0.008}
                         for r, m in enumerate([0.040, 0.034, 0.0163])]}
    fig = R.chamfer_rounds_figure(rep)
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert "next round's rollouts, from the truncated prior: mean ± std" in labels
    assert "posterior predictive: mean ± std (1.63 cm)" in labels
    _assert_texts_inside(fig)
    plt.close(fig)
    fig = R.chamfer_rounds_figure({**rep, "proposal": "corrected"})
    assert "next round's rollouts, from the posterior: mean ± std" in [
        t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    plt.close(fig)


def test_palette_is_colour_blind_safe_and_engines_have_no_role_colour(tmp_path):
    roles = {k: to_rgba(v) for k, v in R.ROLE_COLOURS.items()}
    assert {"measured", "posterior", "prior", "truth", "gripper", "nominal", "with_effect"} <= set(roles)
    assert roles["measured"] != roles["posterior"] and roles["nominal"] != roles["with_effect"]
    assert not {to_rgba(c) for c in R.ENGINE_COLOURS[:2]} & set(roles.values())
    # the compare-backends figure, with one failed engine
    from softsbi.report import plot_compare_backends as compare_png
    sc = _scenario()
    rng = np.random.default_rng(1)
    ros = {"mujoco-flex": SimpleNamespace(ok=True, vertices=rng.normal(0, 0.05, (sc.n_frames, 49, 3))),
           "pybullet-massspring": SimpleNamespace(ok=False, vertices=rng.normal(0, 0.05, (5, 49, 3)))}
    rep = {"chamfer_m": {"mujoco-flex|pybullet-massspring": None}, "mean_chamfer_m": {"mujoco-flex|pybullet-massspring": None},
           "backends": {"mujoco-flex": {"reason": ""}, "pybullet-massspring": {"reason": "diverged"}}}
    assert compare_png(sc, ros, rep, tmp_path / "cb.png").stat().st_size > 10_000


def _two_grip_scenario():
    """A 3 x 3 grid cloth held by two moving grippers (corners 0 and 1) and one pinned corner (2); the second
    path is commanded 5 cm off its corner (the backends shift it there). Its figures' view is y-z, across the two
    grippers."""
    from softsbi.core.types import Handle, Scenario
    T = 4
    up = np.linspace(0, 0.2, T)
    p0 = np.stack([np.zeros(T), np.zeros(T), up], 1)
    p1 = np.stack([np.zeros(T), np.full(T, 0.25), up], 1)
    handles = [Handle("left", {"corner": 0}, p0), Handle("right", {"corner": 1}, p1), Handle("held", {"corner": 2})]
    sc = Scenario(name="two", times=np.arange(T) * 0.1, gripper=p0, table_z=0.0,
                  object={"kind": "cloth", "size": 0.2}, handles=handles, options={"keyframe_times": [0.0, 0.15, 0.3]},
                  view="yz")
    xs = np.linspace(0, 0.2, 3)
    rest = np.array([[x, y, 0.0] for x in xs for y in xs])  # x-major: corner 0 (0,0), 1 (0,0.2), 2 (0.2,0.2)
    verts = np.repeat(rest[None], T, 0)
    verts[:, 0, 2] = verts[:, 2, 2] = up
    return sc, verts


def _markers(fig, marker):
    return [(ln.get_xdata(), ln.get_ydata()) for ax in fig.axes for ln in ax.get_lines() if ln.get_marker() == marker
            and len(ln.get_xdata())]


def test_every_handle_is_drawn_where_it_holds_the_cloth(tmp_path):
    """With two grippers, preview.png, clouds.png and view.gif drew only the first one and its path."""
    from softsbi.core.types import Rollout
    from softsbi.report.animation import draw_gif
    sc, verts = _two_grip_scenario()
    ro = Rollout(times=sc.times, gripper=sc.gripper, vertices=verts, faces=np.array([[0, 1, 3]]))
    fig = R.rollout_preview_figure(ro, "two grippers", sc)
    grips = _markers(fig, "+")
    assert len(grips) == 2 * 5  # both grippers in the view from above and each of the 4 side views
    assert sorted(float(x[0]) for x, _ in grips[2:4]) == pytest.approx([0.0, 0.2])  # y of corners 0 and 1
    assert len(_markers(fig, "x")) == 5  # the pinned corner
    assert "2 grippers" in [t.get_text() for t in fig.legends[0].get_texts()]
    plt.close(fig)
    fig = R.clouds_figure(sc, verts, verts, [0, 3], vertices=verts)
    assert len(_markers(fig, "+")) == 2 * 2 * 2 * 2 and len(_markers(fig, "x")) == 2 * 2  # white halo + cross
    plt.close(fig)
    view = SimpleNamespace(path="run", config=SimpleNamespace(backend="toy"), effects=[], scenario=sc, dense=verts,
                           record=SimpleNamespace(observed_source=""))
    from matplotlib.animation import PillowWriter
    frames, grab = [], PillowWriter.grab_frame

    def record(self, **kw):
        frames.append(_markers(self.fig, "+") + _markers(self.fig, "x"))
        return grab(self, **kw)
    with mock.patch.object(PillowWriter, "grab_frame", record):
        draw_gif(view, [SimpleNamespace(vertices=verts, faces=ro.faces)], np.zeros((1, 4)), tmp_path / "view.gif",
                 fps=5)
    first = frames[0]
    assert sum(len(x) for x, _ in first) == 2 * (2 + 1)  # side and top view: two grippers, one held corner
    side = [(list(x), list(y)) for x, y in first][0]
    assert sorted(side[0]) == pytest.approx([0.0, 0.2])  # the second gripper where its corner is, not 5 cm off


def test_the_preview_shows_the_rest_pose_from_above_with_corners_and_handles_labelled():
    """Placing a cloth by hand needs to see where corners 0-3 and each handle are at rest, from above (a scenario's
    side views alone do not show it)."""
    from softsbi.backends.common import grid_corners
    from softsbi.core.types import Rollout
    sc, verts = _two_grip_scenario()
    ro = Rollout(times=sc.times, gripper=sc.gripper, vertices=verts, faces=np.array([[0, 1, 3]]),
                 info={"corners": grid_corners(3)})
    fig = R.rollout_preview_figure(ro, "two grippers", sc)
    top = fig.axes[0]
    assert top.get_title() == "rest pose from above" and (top.get_xlabel(), top.get_ylabel()) == ("x [m]", "y [m]")
    labels = {t.get_text(): t.xy for t in top.texts}
    assert labels == {"corner 0, left": pytest.approx((0.0, 0.0)), "corner 1, right": pytest.approx((0.0, 0.2)),
                      "corner 2, held": pytest.approx((0.2, 0.2)), "corner 3": pytest.approx((0.2, 0.0))}
    _assert_texts_inside(fig)
    plt.close(fig)


def _drag_scenario(view):
    """A 3 x 3 cloth dragged 0.6 m along +x on the table by corner 0 (it never rises): the motion is in the table's
    plane."""
    from softsbi.core.types import Handle, Scenario
    T = 5
    p0 = np.stack([np.linspace(0, 0.6, T), np.zeros(T), np.full(T, 0.003)], 1)
    sc = Scenario(name="drag", times=np.arange(T) * 0.2, gripper=p0, table_z=0.0, object={"kind": "cloth", "size": 0.2},
                  handles=[Handle("belt", {"corner": 0}, p0)], view=view)
    xs = np.linspace(0, 0.2, 3)
    rest = np.array([[x, y, 0.003] for x in xs for y in xs])
    return sc, rest[None] + np.stack([p0[:, 0], np.zeros(T), np.zeros(T)], 1)[:, None]


def test_the_figures_honour_the_scenario_s_view_and_give_the_top_view_room_for_motion_on_the_table(tmp_path):
    """A cloth dragged along +x with ``view: xy``: preview.png drew y-z side views (the drag invisible), clouds.png
    its y-z side view first, and view.gif's top view was a thumbnail beside a flat side view."""
    from softsbi.core.types import Rollout
    from softsbi.report.animation import draw_gif, panel_ratios
    from softsbi.report.style import view_planes
    sc, verts = _drag_scenario("xy")
    ro = Rollout(times=sc.times, gripper=sc.gripper, vertices=verts, faces=np.array([[0, 1, 3]]))
    fig = R.rollout_preview_figure(ro, "drag", sc)
    for ax in fig.axes[1:]:
        assert (ax.get_xlabel(), ax.get_ylabel()) == ("x [m]", "y [m]") and ax.get_title().endswith("(top view)")
    assert fig.axes[-1].get_title() == "frame 4, t = 0.80 s (top view)"  # frames numbered from 0, as everywhere
    plt.close(fig)
    fig = R.clouds_figure(sc, verts, verts, [0, 4], vertices=verts)
    assert [a.get_ylabel() for a in fig.axes[:4:2]] == ["top view\ny [m]", "side view\nz [m]"]
    plt.close(fig)
    assert [p[:2] for p in view_planes("xy")] == [(0, 1), (0, 2)] and view_planes("xz")[0][:2] == (0, 2)
    # the GIF: the scenario's view first; the second panel neither wider than the first nor a thumbnail
    assert panel_ratios([2.2, 12.0]) == [2.2, 2.2] and panel_ratios([12.0, 2.2]) == [12.0, 6.0]
    assert panel_ratios([1.0, 0.9]) == [1.0, 0.9]
    from matplotlib.animation import PillowWriter
    seen, grab = [], PillowWriter.grab_frame

    def record(self, **kw):
        seen.append(([(a.get_title(), a.get_position().width) for a in self.fig.axes[:2]],
                     self.fig._suptitle.get_text()))
        return grab(self, **kw)
    view = SimpleNamespace(path="run", config=SimpleNamespace(backend="toy"), effects=[], scenario=sc, dense=verts,
                           record=SimpleNamespace(observed_source=""))
    with mock.patch.object(PillowWriter, "grab_frame", record):
        draw_gif(view, [SimpleNamespace(vertices=verts, faces=ro.faces)], np.zeros((1, 5)), tmp_path / "view.gif",
                 fps=5)
    (top, w_top), (side, w_side) = seen[0][0]
    assert top == "top view (x-y)" and side == "side view (x-z)" and w_top >= w_side
    assert "frame 0 (of 0-4)" in seen[0][1] and "frame 4 (of 0-4)" in seen[-1][1]


def test_check_names_the_grasp_its_regions_count_from_and_cuts_phases_at_the_keyframes():
    from softsbi.workflows.criticism.check import grasp_handle, motion_phases
    sc, _ = _two_grip_scenario()
    assert grasp_handle(sc) == "left"
    assert [(p["phase"], p["frames"]) for p in motion_phases(sc)] == [("move 1", [0, 1]), ("move 2", [2, 3])]
    sc.options.pop("keyframe_times")
    assert [p["phase"] for p in motion_phases(sc)] == ["early", "middle", "late"]
    out = dataclasses.replace(check_result(T=4, test=joint(150, 150)), grasp_handle="left", phases_at_keyframes=True)
    fig = R.check_figure(out)
    assert fig.axes[1].get_ylabel() == "region of the object (R1 nearest the grasp of handle 'left')"
    assert "the scenario's keyframes" in fig.axes[0].get_title()
    plt.close(fig)


def test_the_check_heat_map_s_colour_scale_does_not_make_a_passing_run_look_hot():
    """A passing control with region errors below a centimetre: its own maximum set the top of the scale, so it
    looked as "hot" as a failing run. The scale now runs to at least 5 cm; a larger error extends it."""
    from softsbi.report.check_figures import HEATMAP_MIN_CM
    small = check_result(test=joint(150, 150))
    small = dataclasses.replace(small, region_error_m=tuple(tuple(0.1 * v for v in row) for row in small.region_error_m))
    assert np.max(small.region_error_m) * 100 < 3 and HEATMAP_MIN_CM == 5.0
    for out, top in ((small, 5.0), (check_result(), float(np.max(check_result().region_error_m)) * 100)):
        fig = R.check_figure(out)
        assert fig.axes[1].images[0].get_clim() == pytest.approx((0.0, top)), top
        plt.close(fig)
    assert top > 5.0


def test_check_phase_labels_stay_readable_when_the_phases_are_short():
    """Seven phases of three or four frames (a scenario with many keyframes): side by side their labels ran into
    each other; they are tilted, and parallel tilted labels lie more than a label's height apart."""
    import math

    from softsbi.core.results import Phase
    base = check_result()
    t, mean = np.array(base.times_s), np.array(base.chamfer.mean)
    cuts = [0, 3, 6, 9, 12, 15, 18, 25]
    names = [f"move {k + 1}" for k in range(6)] + ["after the last move"]
    phases = tuple(Phase(phase=n, frames=(a, b - 1), t_s=(float(t[a]), float(t[b - 1])),
                         chamfer_m=float(mean[a:b].mean()), chamfer_one_sided_m=None, in_fit=True,
                         worst_region=REGIONS[8]) for n, a, b in zip(names, cuts[:-1], cuts[1:]))
    fig = R.check_figure(dataclasses.replace(base, phases=phases))
    fig.canvas.draw()
    top = next(a for a in fig.axes[0].child_axes)
    labels = [lab for lab in top.get_xticklabels() if lab.get_text()]
    assert labels[0].get_text().startswith("move 1") and labels[-1].get_text().startswith("after the last move")
    r = fig.canvas.get_renderer()
    boxes = [lab.get_window_extent(r) for lab in labels]
    overlap = any(a.x1 > b.x0 for a, b in zip(boxes, boxes[1:]))
    if overlap:
        angle = math.radians(labels[0].get_rotation())
        assert angle > 0 and all(lab.get_rotation() == labels[0].get_rotation() for lab in labels)
        height = max(lab.get_fontsize() for lab in labels) * 2 * 1.1 * fig.dpi / 72  # two lines, in pixels
        xs = [float(top.transData.transform((x, 0))[0]) for x in top.get_xticks()]
        assert min(np.diff(xs)) * math.sin(angle) > height
    _assert_texts_inside(fig)
    plt.close(fig)
