"""The silhouette allowance from frame 0 (inverse.sft.silhouette.silhouette_allowance and
`VertexTerms.silhouette_allowance` in inverse.sft.least_squares): the allowance on a synthetic
mask, the silhouette term's value, gradient and Gauss–Newton blocks with it, and what the
frame-by-frame driver hands each frame."""

import dataclasses
import json
import math

import cv2
import numpy as np
import pytest
import torch
from test_sft_outline import _at_depth, _box_mask
from test_sft_reconstruct import bent_pair
from test_sft_sequential import run
from test_sft_spline_prior import assert_gradient_matches

from inverse.sft.correspondences import track_gaps
from inverse.sft.inputs import mean_edge_length
from inverse.sft.least_squares import LeastSquaresData, Reprojection, VertexTerms
from inverse.sft.outline import border_vertices
from inverse.sft.sequential import DataWeights
from inverse.sft.settings import SplinePriorConfig
from inverse.sft.silhouette import silhouette_allowance, silhouette_distance
from inverse.sft.synth import default_camera
from taichi_ndf import jets


def test_allowance_is_frame_0_distance_outside_the_mask_of_border_vertices():
    """Box mask x 40–119: its outline at x = 119.5. Pixels 4.5 and 8.5 px outside, one 10.5 px
    inside; the allowance is the distance outside at the border rows, 0 inside and elsewhere."""
    _, mask = _box_mask()
    pixels = np.array([[124.0, 60.0], [128.0, 50.0], [109.0, 60.0], [128.0, 70.0]])
    rows = np.array([True, True, True, False])
    allowance = silhouette_allowance(silhouette_distance(mask), pixels, rows)
    assert allowance == pytest.approx([4.5, 8.5, 0.0, 0.0], abs=1e-6)


def allowance_term(allowance):
    """Three vertices 4.5, 8.5 and 12.5 px right of the box mask's outline, the tracked point
    inside; silhouette weight 1, the given allowance (3,) [px]."""
    camera, mask = _box_mask()
    pixels = np.array([[124.0, 60.0], [128.0, 50.0], [132.0, 70.0]])
    rest = _at_depth(camera, pixels, 0.5)
    track = _at_depth(camera, np.array([[80.0, 60.0]]), 0.5)
    term = LeastSquaresData(
        camera, torch.arange(1),
        Reprojection(track, camera.project(track), torch.ones(1), 2.0),
        torch.arange(1, 4),
        VertexTerms(rest, rest, 0.0, 0.01, silhouette_distance(mask), 1.0,
                    silhouette_allowance=None if allowance is None
                    else torch.tensor(allowance, dtype=torch.float64)))
    u = torch.zeros(4, jets.CHANNELS, 3, dtype=torch.float64)
    return term, u


def test_the_allowance_is_not_charged_only_what_lies_beyond_it():
    u = allowance_term(None)[1]
    plain, _ = allowance_term(None)[0].evaluate(None, u)
    assert plain == pytest.approx((4.5**2 + 8.5**2 + 12.5**2) / 3, rel=1e-6)
    term = allowance_term([6.0, 6.0, 0.0])[0]
    value, grad = term.evaluate(None, u)
    # vertex 0 within its allowance: free; vertex 1 2.5 px beyond; vertex 2 none.
    assert value == pytest.approx((2.5**2 + 12.5**2) / 3, rel=1e-6)
    assert term.parts(u)["silhouette"] == pytest.approx(value, rel=1e-12)
    assert torch.count_nonzero(grad[1, jets.VALUE]) == 0
    assert grad[2, jets.VALUE, 0] > 0  # beyond the allowance, right of the mask: pulled left
    blocks = term.hessian_blocks(None, u, steps=None)[:, jets.VALUE, :, jets.VALUE, :]
    assert torch.count_nonzero(blocks[1]) == 0


def test_gradient_and_blocks_with_the_allowance_match_central_differences():
    """The gradient against central differences of the value; the Gauss–Newton block
    2 s JᵀJ of the residual r = D − a against the same: 2 s r J = gradient, so the block is
    g gᵀ / (2 s r²) (s = w_sil / n)."""
    allowance = [3.0, 6.0, 10.0]
    term, u = allowance_term(allowance)
    u[1:, jets.VALUE] = torch.from_numpy(np.random.default_rng(0).normal(0, 3e-4, (3, 3)))
    _, grad = term.evaluate(None, u)
    assert_gradient_matches(term, u, grad, range(1, 4))
    blocks = term.hessian_blocks(None, u, steps=None)[:, jets.VALUE, :, jets.VALUE, :]
    s = 1.0 / 3
    pixels = term.camera.project(term.vertex.rest + u[1:, jets.VALUE])
    residual = term._silhouette_residual(pixels)
    assert torch.all(residual > 0.5)
    for v in range(3):
        g = grad[v + 1, jets.VALUE]
        expected = torch.outer(g, g) / (2 * s * residual[v] ** 2)
        assert torch.allclose(blocks[v + 1], expected, rtol=1e-6, atol=1e-9)


def test_the_settings_are_checked_and_their_defaults_go_into_result_json():
    assert not SplinePriorConfig().silhouette_allowance
    with pytest.raises(ValueError, match="silhouette_allowance"):
        SplinePriorConfig(silhouette_allowance=1)
    with pytest.raises(ValueError, match="allowance_reach"):
        SplinePriorConfig(allowance_reach=math.inf)
    # result.json is strict JSON: an infinite default broke every run (measured, then fixed).
    json.dumps(dataclasses.asdict(SplinePriorConfig()), allow_nan=False)


def test_the_driver_hands_every_frame_frame_0s_allowance_near_tracks_only_with_a_reach():
    """`reconstruct_frames` with a mask 3 px inside the template's outline all round: the
    border vertices' allowance from frame 0 in every frame, cut to 0 far from the frame's
    tracks with `allowance_reach`; none without the setting."""
    camera = default_camera()
    template, _ = bent_pair()
    pixels = camera.project(torch.from_numpy(template.vertices)).numpy()
    image = np.zeros((camera.height, camera.width), np.uint8)
    for triangle in np.rint(pixels[template.faces]).astype(np.int32):
        cv2.fillConvexPoly(image, triangle, 1)
    mask = cv2.erode(image, np.ones((7, 7), np.uint8)).astype(bool)  # 3 px narrower
    border = border_vertices(template.faces, len(template.vertices))
    expected = silhouette_allowance(silhouette_distance(mask), pixels, border)
    assert (expected[border] > 1).sum() > border.sum() / 2 and not expected[~border].any()
    _, _, fit, _ = run(DataWeights(2.0, 0.1, 1.0, 1.0), masks=[mask] * 3)
    assert all(f.silhouette_allowance is None for f in fit.frames)
    _, _, fit, _ = run(DataWeights(2.0, 0.1, 1.0, 1.0, silhouette_allowance=True),
                       masks=[mask] * 3)
    _, _, gapped, _ = run(DataWeights(2.0, 0.1, 1.0, 1.0, silhouette_border_gap=0.5,
                                      silhouette_allowance=True), masks=[mask] * 3)
    for frame in fit.frames + gapped.frames:
        np.testing.assert_allclose(frame.silhouette_allowance.numpy(), expected)
        assert frame.data_term(torch.arange(1), torch.arange(1, 1 + len(border))) \
            .vertex.silhouette_allowance is frame.silhouette_allowance
    _, tracks, fit, _ = run(DataWeights(2.0, 0.1, 1.0, 1.0, silhouette_allowance=True,
                                        allowance_reach=0.5), masks=[mask] * 3)
    mean_edge = mean_edge_length(template.vertices, template.faces)
    for frame in fit.frames:
        near = track_gaps(template.vertices, template.faces, tracks[frame.index],
                          mean_edge) <= 0.5
        assert (border & near & (expected > 0)).any() and (border & ~near & (expected > 0)).any()
        np.testing.assert_allclose(frame.silhouette_allowance.numpy(), expected * near)


@pytest.mark.parametrize("extra, named", [
    (["--allowance-reach", "-1"], "allowance_reach"),
    (["--field", "siren", "--silhouette-allowance"], "--silhouette-allowance")])
def test_the_cli_refuses_a_bad_allowance_before_any_work(tmp_path, capsys, extra, named):
    from inverse.cli import sft as sft_cli

    status = sft_cli.main(["--frames", str(tmp_path / "none"), "--camera", "c.json",
                           "--template", "t.obj", "--texture", "x.png", "--out",
                           str(tmp_path / "out"), "--precision", "f64", *extra])
    assert status == 2
    assert named in capsys.readouterr().err
