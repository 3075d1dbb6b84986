"""Spline + Gauss–Newton shape-from-template: the data terms' gradient and Gauss–Newton blocks,
recovery of a bent sheet, pins, the new motion families and the CLI's methods."""

import dataclasses
import json

import numpy as np
import pytest
import torch
from test_sft_reconstruct import bent_pair, exact_tracks, small_sequence

from inverse.cli import sft as sft_cli
from inverse.sft.camera import Camera
from inverse.sft.deformations import CornerLift, Wave
from inverse.sft.frame_fits import reconstruct_sequence
from inverse.sft.inputs import mesh_edges
from inverse.sft.least_squares import LeastSquaresData, Reprojection, VertexTerms
from inverse.sft.metrics import relative_error
from inverse.sft.settings import SplinePriorConfig
from inverse.sft.silhouette import silhouette_distance
from inverse.sft.synth import default_camera, flat_sheet
from taichi_ndf import jets


def data_term(seed=0, tracks=12, vertices=8):
    """A data term on tracks + vertices with some residuals beyond the Huber threshold and
    some vertices outside the mask; and displacement jets (N, 6, 3) to evaluate it at."""
    rng = np.random.default_rng(seed)
    camera = default_camera(160, 120, focal=150.0)
    rest = torch.from_numpy(rng.uniform([-0.1, -0.08, 0.4], [0.1, 0.08, 0.5],
                                        (tracks + vertices, 3)))
    pixels = camera.project(rest[:tracks]) + torch.from_numpy(rng.normal(0, 2.0, (tracks, 2)))
    mask = np.zeros((120, 160), bool)
    mask[30:90, 40:120] = True
    n = tracks + vertices
    term = LeastSquaresData(
        camera, torch.arange(tracks),
        Reprojection(rest[:tracks], pixels, torch.from_numpy(rng.uniform(0.5, 1, tracks)), 2.0),
        torch.arange(tracks, n),
        VertexTerms(rest[tracks:], rest[tracks:] + 0.002, 0.3, 0.01,
                    silhouette_distance(mask), 1.0))
    u = torch.zeros(n, jets.CHANNELS, 3, dtype=torch.float64)
    u[:, jets.VALUE] = torch.from_numpy(rng.normal(0, 0.003, (n, 3)))
    return term, u


def assert_gradient_matches(term, u, grad, points):
    """The data term's value-channel gradient at `points` against central differences."""
    step = 1e-7
    for point in points:
        for c in range(3):
            plus, minus = u.clone(), u.clone()
            plus[point, jets.VALUE, c] += step
            minus[point, jets.VALUE, c] -= step
            fd = (term.evaluate(None, plus, grad=False)[0]
                  - term.evaluate(None, minus, grad=False)[0]) / (2 * step)
            assert grad[point, jets.VALUE, c].item() == pytest.approx(fd, rel=1e-4, abs=1e-6)


def test_data_gradient_matches_central_differences():
    term, u = data_term()
    value, grad = term.evaluate(None, u)
    assert value > 0
    assert torch.count_nonzero(grad[:, 1:]) == 0  # the data act on the value only
    assert_gradient_matches(term, u, grad, range(u.shape[0]))


def test_gauss_newton_blocks_are_jtwj_of_the_residuals():
    """Inside the Huber threshold and the mask the blocks are 2 w JᵀJ of the projection (tracks)
    and 2 w_temp/(n h²) I (vertices): compared with central differences of the gradient."""
    term, u = data_term(seed=1)
    term.reprojection = Reprojection(term.reprojection.rest,
                                     term.camera.project(term.reprojection.rest + u[:12, 0])
                                     + 0.5, term.reprojection.confidence, 2.0)
    term.vertex = VertexTerms(term.vertex.rest, term.vertex.predicted, 0.3, 0.01)  # no mask
    blocks = term.hessian_blocks(None, u, steps=None)
    assert blocks.shape == (u.shape[0], 6, 3, 6, 3)
    value = blocks[:, jets.VALUE, :, jets.VALUE, :]
    assert torch.all(torch.linalg.eigvalsh(value) >= -1e-12 * float(value.abs().max()))
    step = 1e-7
    for c in range(3):
        plus, minus = u.clone(), u.clone()
        plus[:, jets.VALUE, c] += step
        minus[:, jets.VALUE, c] -= step
        fd = (term.evaluate(None, plus)[1] - term.evaluate(None, minus)[1])[:, jets.VALUE] / (
            2 * step)
        # Gauss–Newton drops the residual × second-derivative part: small at 0.5 px residuals.
        np.testing.assert_allclose(value[:, :, c].numpy(), fd.numpy(), rtol=0.02,
                                   atol=0.02 * float(value.abs().max()))
    motion = 2 * 0.3 / (8 * 0.01**2)
    np.testing.assert_allclose(value[12:].numpy(), np.broadcast_to(motion * np.eye(3),
                                                                   (8, 3, 3)), rtol=1e-12)


# One large jump from the flat template (e3D 0.054) needs more iterations than a video frame
# and spans as fine as the 8 x 6 cells.
JUMP = SplinePriorConfig(span_edges=1.0, max_iterations=20)


@pytest.fixture(scope="module")
def bent():
    camera = default_camera()
    template, bent = bent_pair()
    tracks = [exact_tracks(template, v, camera) for v in (template.vertices, bent)]
    return camera, template, bent, tracks


def test_recovers_bent_sheet_from_tracks(bent):
    camera, template, target, tracks = bent
    result = reconstruct_sequence(template, camera, tracks, config=JUMP)
    np.testing.assert_array_equal(result.vertices[0], template.vertices)
    before = relative_error(template.vertices, target)
    after = relative_error(result.vertices[1], target)
    assert after < 0.1 * before, (before, after)
    assert result.losses[1]["reprojection"] < 0.1
    assert result.losses[1]["energy"] > 0
    assert 1 <= result.iterations[1] <= JUMP.max_iterations


def test_without_the_prior_depth_is_free(bent):
    """Exact tracks fit either way, but only the prior fixes the depth between them."""
    camera, template, target, tracks = bent
    prior = reconstruct_sequence(template, camera, tracks, config=JUMP).vertices[1]
    free = reconstruct_sequence(template, camera, tracks, config=dataclasses.replace(
        JUMP, physics_weight=0.0)).vertices[1]
    assert relative_error(prior, target) < relative_error(free, target)


def test_pinned_vertices_stay_at_the_template(bent):
    camera, template, _, tracks = bent
    pinned = np.array([0, 5])
    result = reconstruct_sequence(template, camera, tracks, pinned=pinned,
                                config=SplinePriorConfig(max_iterations=2))
    moved = np.linalg.norm(result.vertices[1] - template.vertices, axis=1)
    assert moved[pinned].max() < 1e-9
    assert moved.max() > 1e-3


@pytest.mark.parametrize("name, value", [("physics_weight", -1.0), ("span_edges", 0.0),
                                         ("max_iterations", 0), ("material", "silk"),
                                         ("degree", 2), ("silhouette_border_gap", -1.0),
                                         ("silhouette_border_gap", float("nan"))])
def test_config_refuses_bad_values(name, value):
    with pytest.raises(ValueError, match=name if name != "material" else "linear"):
        SplinePriorConfig(**{name: value})


@pytest.mark.parametrize("motion", [CornerLift(), Wave()])
def test_new_motions_are_isometric_and_start_flat(motion):
    """Edge lengths converge to the flat ones under refinement (chords of curved arcs)."""
    errors = []
    for cells in ((28, 21), (112, 84)):
        points, faces, _ = flat_sheet((0.28, 0.21), cells)
        edges = mesh_edges(faces)
        flat = np.linalg.norm(points[edges[:, 0]] - points[edges[:, 1]], axis=1)
        start = motion.shape(points, 0.0, sheet_width=0.28)
        np.testing.assert_allclose(start[:, :2], points, atol=1e-12)
        np.testing.assert_allclose(start[:, 2], 0.0, atol=1e-12)
        moved = motion.shape(points, 0.5, sheet_width=0.28)
        assert np.abs(moved[:, 2]).max() > 0.005  # it does deform
        length = np.linalg.norm(moved[edges[:, 0]] - moved[edges[:, 1]], axis=1)
        errors.append(np.abs(length / flat - 1).max())
    assert errors[1] < 0.1 * errors[0] and errors[1] < 1e-3, errors


def test_corner_lift_drops_back():
    points, _, _ = flat_sheet((0.28, 0.21), (14, 10))
    np.testing.assert_allclose(CornerLift().shape(points, 1.0, sheet_width=0.28)[:, 2], 0.0,
                               atol=1e-12)


def cli_args(seq, out, *extra):
    return ["--frames", str(seq / "frames"), "--camera", str(seq / "camera.json"),
            "--template", str(seq / "template.obj"), "--texture", str(seq / "texture.png"),
            "--masks", str(seq / "masks"), "--gt", str(seq / "gt"), "--out", str(out), *extra]


@pytest.mark.parametrize("method, stages", [
    ("prior", {"load", "tracking", "reconstruction", "output"}),
    ("baseline", {"load", "tracking", "baseline", "output"})])
def test_cli_methods(tmp_path, method, stages):
    seq = small_sequence(tmp_path)
    assert sft_cli.main(cli_args(seq, tmp_path / "out", "--method", method)) == 0
    assert len(list((tmp_path / "out" / "meshes").glob("*.obj"))) == 3
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    assert result["method"] == method and set(result["timings"]["total"]) == stages
    assert result["metrics"]["e3d"] < 0.05


def test_cli_refuses_spline_in_single_precision(tmp_path, capsys):
    status = sft_cli.main(cli_args(tmp_path, tmp_path / "out", "--precision", "f32"))
    assert status == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--precision f64" in err


def test_camera_projection_jacobian_matches_differences():
    camera = Camera(fx=500.0, fy=480.0, cx=10.0, cy=5.0, width=64, height=48)
    points = np.array([[0.1, -0.05, 0.5], [-0.2, 0.1, 0.8]])
    jac = camera.projection_jacobian(points)
    step = 1e-7
    for c in range(3):
        shift = np.zeros(3)
        shift[c] = step
        fd = (camera.project(points + shift) - camera.project(points - shift)) / (2 * step)
        np.testing.assert_allclose(jac[:, :, c], fd, rtol=1e-6, atol=1e-6)
    torch_jac = camera.projection_jacobian(torch.from_numpy(points))
    np.testing.assert_allclose(torch_jac.numpy(), jac)
