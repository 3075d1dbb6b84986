"""Colour ranges, colour bars, soft lighting, the energy figure and trajectory video frames."""

from __future__ import annotations

import numpy as np
import pytest

from taichi_ndf.io import grid_mesh
from taichi_ndf.render.colour import (
    BAR_TICKS,
    ColourScale,
    bar_ticks,
    colormap,
    colour_bar,
    colour_range,
    colour_scale,
)
from taichi_ndf.render.energy_plot import energy_figure, segments
from taichi_ndf.render.figure import Obstacle, render_figure
from taichi_ndf.render.shaded import BACKGROUND_BGR, lambert_intensity
from taichi_ndf.render.trajectory import frame_repeats, trajectory_frames


def test_a_spike_does_not_set_the_colour_range_and_is_stated():
    """A pinned corner's singular value (one vertex of 1e6) would wash out every other vertex
    with a min-max range; the 1st-99th percentile keeps the rest spread, and the note says
    what the bar clips."""
    values = np.r_[np.linspace(0.0, 1.0, 999), 1e6]
    scale = colour_scale(values)
    assert 0.0 < scale.lo < 0.02 and 0.98 < scale.hi < 1.0
    assert scale.above == pytest.approx(0.011, abs=0.002) and scale.maximum == 1e6
    note = scale.clipped_note()
    assert "1st–99th percentile" in note and "max 1e+06" in note and "min 0" in note
    colours = colormap(values[:-1], scale)
    assert len(np.unique(colours, axis=0)) > 200  # the 999 ordinary values use the whole map
    assert colour_range(values) == (0.0, 1e6)  # the plain min-max range, kept for callers
    hand = colour_scale(values, value_range=(0.0, 2e6))
    assert hand.clipped_note() == "" and hand.percentiles is None
    assert colour_scale([np.nan, np.inf]).range == (0.0, 1.0)
    with pytest.raises(ValueError, match="finite lo <= hi"):
        ColourScale(1.0, 0.0)


@pytest.mark.parametrize("lo, hi", [(0.0, 1.0), (0.0086, 0.9933), (3.85, 13.9),
                                     (-0.071, 0.0), (1e-7, 3.3e-5), (-50430.4, -46347.2),
                                     (2.4236, 2.4237)])
def test_colour_bar_ticks_are_5_to_7_round_values_inside_the_range(lo, hi):
    ticks = bar_ticks(lo, hi)
    assert BAR_TICKS[0] <= len(ticks) <= BAR_TICKS[1], ticks
    span = hi - lo
    assert min(ticks) >= lo - 1e-9 * span and max(ticks) <= hi + 1e-9 * span
    steps = np.diff(ticks)
    np.testing.assert_allclose(steps, steps[0], rtol=1e-6)


def test_random_ranges_always_get_5_to_7_ticks():
    rng = np.random.default_rng(0)
    for _ in range(2000):
        lo = rng.normal() * 10 ** rng.uniform(-5, 5)
        hi = lo + 10 ** rng.uniform(-6, 6)
        assert BAR_TICKS[0] <= len(bar_ticks(lo, hi)) <= BAR_TICKS[1], (lo, hi)


def test_colour_bar_panel_has_the_bar_and_grows_with_the_note():
    plain = colour_bar((0.0, 1.0), "|κ| [1/m]", 300)
    noted = colour_bar(colour_scale(np.r_[np.linspace(0, 1, 999), 1e6]), "|κ| [1/m]", 300)
    assert plain.shape[0] == noted.shape[0] == 300 and noted.shape[1] > plain.shape[1]
    column = plain[:, 8 + 8]  # the middle of the 16-pixel bar at x = 8
    hues = {tuple(c // 40) for c in column[60:240]}
    assert len(hues) > 4  # viridis runs along the bar
    assert (plain < 100).all(axis=-1).sum() > 100  # dark text: ticks and the label


def test_soft_lighting_has_no_hard_terminator(monkeypatch):
    from taichi_ndf.render import shaded

    key = shaded._KEY
    side = np.cross(key, [1.0, 0.0, 0.0])
    side /= np.linalg.norm(side)
    angles = np.linspace(0.0, np.pi / 2, 50)  # from facing the key light to its terminator
    normals = np.cos(angles)[:, None] * key + np.sin(angles)[:, None] * side
    rays = np.tile([0.0, 0.0, 1.0], (50, 1))
    light = lambert_intensity(normals, rays)
    assert np.all((0 <= light) & (light <= 1)) and light[0] == light.max()
    assert light.min() > 0.2  # ambient, sky and fill: no black
    monkeypatch.setattr(shaded, "_KEY_WEIGHT", 0.0)
    without_key = lambert_intensity(normals, rays)
    assert light[-1] - without_key[-1] > 0.1  # the wrapped key light still reaches 90°


def test_render_figure_colours_by_robust_range_and_states_the_clipping():
    grid = grid_mesh(((0.0, 1.0), (0.0, 1.0)), 20)
    vertices = np.column_stack([grid.xi, 0.2 * grid.xi[:, 0] ** 2])
    scalars = grid.xi[:, 0].copy()
    scalars[0] = 1e4  # a singular vertex
    image = render_figure(vertices, grid.faces, scalars=scalars, scalar_label="|κ| [1/m]",
                          width=500, height=300, shadow=False)
    bar = colour_bar(colour_scale(scalars), "|κ| [1/m]", 300)
    surface = image[:, : 500 - bar.shape[1]]
    painted = surface[np.any(surface != BACKGROUND_BGR, axis=-1)]
    assert len(np.unique(painted // 16, axis=0)) > 20  # not one colour for all but the spike


def history(levels=((0, (4, 4)), (1, (8, 8))), loads=(0.5, 1.0), per=6):
    records, iteration = [], 0
    for level, spans in levels:
        for factor in loads:
            for k in range(per):
                records.append({"iteration": iteration, "load_factor": factor, "level": level,
                                "spans": list(spans), "energy": -factor * (1 - 0.5 ** k)})
                iteration += 1
    return records


def test_segments_split_the_history_at_load_steps_and_levels():
    assert segments(history()) == [(0, 6, 0.5, 0), (6, 12, 1.0, 0), (12, 18, 0.5, 1),
                                   (18, 24, 1.0, 1)]
    assert segments([{"iteration": 0, "load_factor": 1.0, "energy": 0.0}]) == [(0, 1, 1.0, 0)]


def test_energy_figure_panels_and_boundaries():
    refinement = {"spans": [[4, 4], [8, 8], [16, 16]],
                  "energy": {"values": [-1.0, -1.1, -1.12], "extrapolated": -1.125,
                             "estimated_error": 0.004, "order": 2.3, "order_basis": "observed"}}
    two = energy_figure(history())
    three = energy_figure(history(), refinement)
    assert two.shape[1] == three.shape[1] and three.shape[0] == 3 * two.shape[0] // 2
    # the level boundary is a solid dark vertical line through the top panel's plot area
    top = two[: two.shape[0] // 2]
    dark_columns = (top < 140).all(axis=-1).sum(axis=0)
    assert (dark_columns > 0.4 * top.shape[0]).sum() >= 3  # two axis spines and the boundary
    with pytest.raises(ValueError, match="no history"):
        energy_figure([])


def test_trajectory_frames_have_colour_obstacles_label_and_one_camera():
    grid = grid_mesh(((0.0, 1.0), (0.0, 1.0)), 10)
    reference = np.column_stack([grid.xi, np.zeros(len(grid.xi))])
    states = [reference + [0, 0, -0.3 * t] * grid.xi[:, :1] for t in (0.5, 1.0)]
    block = Obstacle(np.array([[0.2, 0.2, 0.1], [0.4, 0.2, 0.1], [0.2, 0.4, 0.1],
                               [0.2, 0.2, 0.3]]),
                     np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    frames = trajectory_frames(states, grid.faces, [0.5, 1.0], reference=reference,
                               obstacles=[(block,), (block,)], size=(320, 240))
    repeats = frame_repeats(2)
    assert repeats == 6 and len(frames) == 2 * repeats + 4  # 3 s of 2 states, 1 s held
    first, last = frames[0], frames[-1]
    assert first.shape == (240, 320, 3)
    assert (np.ptp(last.astype(int), axis=-1) < 4).sum() > 200  # the grey obstacle
    assert not np.array_equal(first[:40, :200], last[:40, :200])  # "step 1 of 2" / "2 of 2"
    assert np.array_equal(frames[1], first)
    with pytest.raises(ValueError, match="one load factor per state"):
        trajectory_frames(states, grid.faces, [1.0], reference=reference)


def test_video_frames_share_one_colour_bar_and_use_the_video_supersampling(monkeypatch):
    """The bar states the clipping over all states, drawn once: the same pixels in every
    frame, though only the second state has values beyond the range; the frames render with
    SUPERSAMPLE (2), not the still pictures' 3."""
    import taichi_ndf.render.trajectory as trajectory

    grid = grid_mesh(((0.0, 1.0), (0.0, 1.0)), 10)
    reference = np.column_stack([grid.xi, np.zeros(len(grid.xi))])
    states = [reference + [0, 0, -0.3] * grid.xi[:, :1],
              reference + [0, 0, -0.3] * grid.xi[:, :1] ** 4]
    states[1][0, 2] = -5.0  # a spike in the second state only
    used = []
    original = trajectory.render_figure

    def spy(*args, **kwargs):
        used.append(kwargs["supersample"])
        return original(*args, **kwargs)

    monkeypatch.setattr(trajectory, "render_figure", spy)
    frames = trajectory_frames(states, grid.faces, [0.5, 1.0], reference=reference,
                               size=(320, 240))
    assert used == [trajectory.SUPERSAMPLE] * 2 and trajectory.SUPERSAMPLE == 2
    first, last = frames[0], frames[-1]
    bar = slice(240 - 60, None), slice(200, None)  # the bar's lower part, its note
    assert not np.array_equal(first, last)
    assert np.array_equal(first[bar], last[bar])
    assert (np.ptp(first[bar].astype(int), axis=-1) > 30).any()  # the viridis bar is there


def test_render_figure_with_a_colour_scale_uses_it_as_it_is():
    grid = grid_mesh(((0.0, 1.0), (0.0, 1.0)), 8)
    vertices = np.column_stack([grid.xi, 0.1 * grid.xi[:, 0]])
    values = grid.xi[:, 0]
    scale = colour_scale(np.concatenate([values, [10.0]]))  # clips the 10 (not among values)
    stated = render_figure(vertices, grid.faces, scalars=values, scalar_range=scale,
                           width=400, height=300)
    own = render_figure(vertices, grid.faces, scalars=values, scalar_range=scale.range,
                        width=400, height=300)
    assert scale.above > 0
    assert not np.array_equal(stated, own)  # the given scale's note, not a new count's


def test_a_run_without_an_h264_encoder_keeps_its_outputs_and_says_why(tmp_path, monkeypatch,
                                                                       caplog):
    import sys

    from taichi_ndf.app.outputs import write_trajectory_video
    from taichi_ndf.io.output_dir import OutputDir

    grid = grid_mesh(((0.0, 1.0), (0.0, 1.0)), 4)
    reference = np.column_stack([grid.xi, np.zeros(len(grid.xi))])
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # not installed
    with OutputDir(tmp_path / "run") as out:
        assert not write_trajectory_video(out, [reference, reference + 0.1], grid.faces,
                                          [0.5, 1.0], reference=reference, up=(0.0, 0.0, 1.0))
    assert "trajectory.mp4 not written: H.264 video needs imageio-ffmpeg" in caplog.text
    assert not (tmp_path / "run" / "trajectory.mp4").exists()


def test_dynamic_video_plays_in_real_time():
    from taichi_ndf.render.trajectory import MAX_FPS, real_time_fps

    # 51 frames over 2 s: 25 frames per second; a shorter last interval changes little
    assert real_time_fps([0.04 * k for k in range(51)]) == pytest.approx(25.0)
    assert real_time_fps([0.0, 0.04, 0.08, 0.1]) == pytest.approx(30.0)
    assert real_time_fps([0.0, 1e-4, 2e-4]) == MAX_FPS
    assert real_time_fps([0.0, 5.0]) == 1.0
    assert real_time_fps([1.0]) == 1.0


def test_a_common_factor_of_the_ticks_goes_beside_the_label_not_over_it():
    # |u| up to 4e-5 m: matplotlib writes the ticks 0..4 and a factor 1e−5, which it drew at
    # the bar's top, over the label (the two-panel skirt's gallery picture)
    normal = colour_bar((0.0, 0.35), "|u| [m]", 480)
    small = colour_bar((0.0, 4.24e-5), "|u| [m]", 480)
    label = (normal[:30] < 100).all(axis=-1)  # the label's dark text in the top rows
    right = np.nonzero(label.any(axis=0))[0].max() + 2
    assert np.array_equal(small[:30, :right], normal[:30, :right])  # nothing drawn over it
    assert small.shape[1] > normal.shape[1]  # the factor beside it
    assert (small[:30, right:] < 100).all(axis=-1).sum() > 20


def test_energy_figure_counts_iterations_through_the_run_when_each_load_step_restarts():
    # a garment's history numbers its iterations per load step: 0, 1, 0, 1
    restarting = [{"load_factor": f, "iteration": i, "energy": -f - 0.1 * i}
                  for f in (0.5, 1.0) for i in (0, 1)]
    counted = [{**r, "iteration": k} for k, r in enumerate(restarting)]
    assert np.array_equal(energy_figure(restarting), energy_figure(counted))
    assert segments(restarting) == segments(counted)


def test_the_video_camera_sees_the_surface_in_front_of_the_obstacles(monkeypatch):
    """A vertical sheet (x = 0) with a wall just in front of one face (x = 0.3): the final
    state's widest silhouette (the old rule, `widest_azimuth`) looks from the wall's side
    (azimuth −15°) and sees none of the sheet; the video's camera (`visible_azimuth`) counts
    what the wall hides and looks from the open side, where the sheet fills its silhouette."""
    import taichi_ndf.render.trajectory as trajectory
    from taichi_ndf.render.camera import visible_cover, widest_azimuth
    from taichi_ndf.render.trajectory import visible_azimuth

    grid = grid_mesh(((-0.5, 0.5), (0.0, 1.0)), 8)
    reference = np.column_stack([np.zeros(len(grid.xi)), grid.xi])  # (0, y, z)
    states = [reference + [0.0, 0.0, -0.1 * t] for t in (0.0, 1.0)]
    wall = Obstacle(np.array([[0.3, -2.0, -1.0], [0.3, 2.0, -1.0], [0.3, 2.0, 1.5],
                              [0.3, -2.0, 1.5]]), np.array([[0, 1, 2], [0, 2, 3]]))
    obstacles = [(wall,), (wall,)]
    old = widest_azimuth(states[-1], grid.faces)
    new = visible_azimuth(states, grid.faces, obstacles)
    hidden, seen = visible_cover(states, grid.faces, obstacles, azimuths_deg=[old, new])
    assert old == -15.0 and hidden == 0.0  # the old rule: behind the wall
    assert np.cos(np.radians(new)) < -0.9  # from −x, the open side
    assert seen > 0.05  # the sheet, 2 states: about 4 % of the wall-framed image each
    azimuths = []
    original = trajectory.render_figure

    def spy(*args, **kwargs):
        azimuths.append(kwargs["azimuth_deg"])
        return original(*args, **kwargs)

    monkeypatch.setattr(trajectory, "render_figure", spy)
    trajectory_frames(states, grid.faces, [0.5, 1.0], reference=reference,
                      obstacles=obstacles, size=(160, 120))
    assert azimuths == [new, new]
    assert visible_azimuth(states, grid.faces) == old  # no obstacle: the widest view
