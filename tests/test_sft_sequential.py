"""The frame-by-frame driver (inverse.sft.sequential) hands each field the same frame: tracks
on the template, the constant-velocity prediction, the silhouette and the outline offsets."""

from dataclasses import dataclass, field

import numpy as np
import pytest
import torch
from test_sft_reconstruct import bent_pair, exact_tracks

from inverse.sft.correspondences import track_gaps
from inverse.sft.frame_fits import reconstruct_sequence
from inverse.sft.inputs import mean_edge_length
from inverse.sft.outline import border_vertices
from inverse.sft.sequential import DataWeights, FittedFrame, reconstruct_frames
from inverse.sft.settings import SplinePriorConfig
from inverse.sft.surface import surface_positions
from inverse.sft.synth import default_camera
from taichi_ndf import progress

STEP = np.array([0.0, 0.0, 0.01])  # what the fake fit moves the sheet per frame [m]


@dataclass
class Recorder:
    """A FrameFit that records the frames it is given and moves the sheet by STEP per frame."""

    rest: np.ndarray
    weights: DataWeights
    frames: list = field(default_factory=list)

    def fit_frame(self, frame):
        self.frames.append(frame)
        return FittedFrame(self.rest + frame.index * STEP, {"index": frame.index}, 1)


def run(weights, masks=None, frames=3):
    camera = default_camera()
    template, bent = bent_pair()
    tracks = [exact_tracks(template, bent, camera, seed=i) for i in range(frames)]
    fit = Recorder(template.vertices, weights)
    return template, tracks, fit, reconstruct_frames(template, camera, tracks, fit, masks=masks)


def test_frames_carry_tracks_and_the_constant_velocity_prediction():
    template, tracks, fit, result = run(DataWeights(2.0, 0.1, 1.0, 1.0))
    assert [f.index for f in fit.frames] == [1, 2]
    np.testing.assert_array_equal(result.vertices[0], template.vertices)
    np.testing.assert_array_equal(result.vertices[2], template.vertices + 2 * STEP)
    assert result.iterations == [0, 1, 1] and result.losses[1:] == [{"index": 1}, {"index": 2}]
    assert len(result.seconds) == len(result.cpu_seconds) == 3
    first, second = fit.frames
    # Frame 1 has one frame of history: the prediction is frame 0; frame 2: 2 x_1 - x_0.
    np.testing.assert_allclose(first.predicted.numpy(), template.vertices)
    np.testing.assert_allclose(second.predicted.numpy(), template.vertices + 2 * STEP,
                               atol=1e-15)
    seen = tracks[2]
    np.testing.assert_allclose(second.track_rest.numpy(), surface_positions(
        template.vertices, template.faces, seen.face, seen.bary), atol=1e-15)
    np.testing.assert_array_equal(second.pixels.numpy(), seen.xy)
    assert second.track_xi.shape == (len(seen.face), 2)
    assert second.distance is None and second.outline_offset is None  # no masks


def test_masks_give_the_silhouette_and_outline_only_when_weighted():
    camera = default_camera()
    masks = [np.ones((camera.height, camera.width), bool)] * 3
    _, _, fit, _ = run(DataWeights(2.0, 0.1, 1.0, 1.0), masks=masks)
    assert all(f.distance is not None and f.outline_offset is not None for f in fit.frames)
    _, _, fit, _ = run(DataWeights(2.0, 0.1, 1.0), masks=masks)  # the SIREN's: no outline
    assert all(f.distance is not None and f.outline_offset is None for f in fit.frames)
    _, _, fit, _ = run(DataWeights(2.0, 0.1, 0.0, 1.0), masks=masks)
    assert all(f.distance is None and f.outline_offset is None for f in fit.frames)


def test_the_silhouette_acts_on_border_vertices_only_far_from_every_track():
    camera = default_camera()
    masks = [np.ones((camera.height, camera.width), bool)] * 3
    template, _, fit, _ = run(DataWeights(2.0, 0.1, 1.0, 1.0), masks=masks)
    assert all(f.silhouette_rows is None for f in fit.frames)  # the default: every vertex
    border = border_vertices(template.faces, len(template.vertices))
    _, _, fit, _ = run(DataWeights(2.0, 0.1, 1.0, 1.0, silhouette_border_gap=np.inf),
                       masks=masks)
    np.testing.assert_array_equal(fit.frames[0].silhouette_rows.numpy(), ~border)
    _, tracks, fit, _ = run(DataWeights(2.0, 0.1, 1.0, 1.0, silhouette_border_gap=0.5),
                            masks=masks)
    mean_edge = mean_edge_length(template.vertices, template.faces)
    for frame in fit.frames:
        far = track_gaps(template.vertices, template.faces, tracks[frame.index], mean_edge) > 0.5
        assert (border & far).any() and (border & ~far).any()  # both kinds present
        np.testing.assert_array_equal(frame.silhouette_rows.numpy(), ~border | far)
        assert frame.data_term(torch.arange(1), torch.arange(1, 1 + len(border))) \
            .vertex.silhouette_rows is frame.silhouette_rows


def test_the_data_term_sits_on_the_rows_the_fit_names():
    _, _, fit, _ = run(DataWeights(2.0, 0.1, 1.0))
    frame = fit.frames[0]
    m, n = len(frame.track_xi), len(frame.rest)
    term = frame.data_term(torch.arange(n, n + m), torch.arange(n))  # vertices first
    u = torch.zeros(n + m, 6, 3, dtype=torch.float64)
    value, gradient = term.evaluate(None, u)
    swapped = frame.data_term(torch.arange(m), torch.arange(m, m + n))
    u_swapped = torch.zeros_like(u)
    value_swapped, gradient_swapped = swapped.evaluate(None, u_swapped)
    assert value == value_swapped
    torch.testing.assert_close(gradient[:n], gradient_swapped[m:], rtol=0, atol=0)


def test_one_entry_picks_the_field_from_its_settings():
    """`reconstruct_sequence` solves on the field its settings name and refuses what it cannot
    use: unknown settings, initial guesses for the spline field."""
    camera = default_camera()
    template, bent = bent_pair()
    tracks = [exact_tracks(template, v, camera) for v in (template.vertices, bent)]
    with pytest.raises(TypeError, match="no SfT field"):
        reconstruct_sequence(template, camera, tracks, DataWeights(2.0, 0.1, 0.0))
    with pytest.raises(ValueError, match="initial guesses"):
        reconstruct_sequence(template, camera, tracks, SplinePriorConfig(),
                             initial=[template.vertices, bent])
    result = reconstruct_sequence(template, camera, tracks, SplinePriorConfig(max_iterations=2))
    assert len(result.vertices) == 2 and result.iterations[1] > 0


def test_the_frames_run_through_the_continuation_loop_with_its_callbacks_and_progress():
    calls, reports = [], []

    class Seen:
        def on_start(self, solver):
            calls.append(("start", solver))

        def on_load_step(self, solver, value):
            calls.append(("frame", value, len(solver.frames)))

        def on_end(self, solver):
            calls.append(("end", solver))

    camera = default_camera()
    template, bent = bent_pair()
    tracks = [exact_tracks(template, bent, camera, seed=i) for i in range(3)]
    fit = Recorder(template.vertices, DataWeights(2.0, 0.1, 1.0))
    with progress.listening(reports.append):
        reconstruct_frames(template, camera, tracks, fit, callbacks=[Seen()])
    # After each frame's fit: its index, with the fit (the loop's subject) done with it.
    assert calls == [("start", fit), ("frame", 1, 1), ("frame", 2, 2), ("end", fit)]
    frames = [r for r in reports if r.stage == "SfT reconstruction, frames"]
    assert [(r.step, r.total, r.done) for r in frames] == [(0, 2, False), (1, 2, False),
                                                           (2, 2, False), (2, 2, True)]


@pytest.mark.parametrize("extra, named", [
    (["--silhouette-border-gap", "-1"], "silhouette_border_gap"),
    (["--field", "siren", "--silhouette-border-gap", "2"], "--silhouette-border-gap"),
    (["--field", "siren", "--extrapolate"], "--extrapolate")])
def test_the_cli_refuses_a_bad_silhouette_border_gap_before_any_work(tmp_path, capsys, extra,
                                                                     named):
    from inverse.cli import sft as sft_cli

    status = sft_cli.main(["--frames", str(tmp_path / "none"), "--camera", "c.json",
                           "--template", "t.obj", "--texture", "x.png", "--out",
                           str(tmp_path / "out"), "--precision", "f64", *extra])
    assert status == 2
    assert named in capsys.readouterr().err
