"""The outline term (inverse.sft.outline, inverse.sft.least_squares): border vertices, the
visibility test, the frame-0 allowance, and the term's value, gradient and Gauss–Newton blocks."""

import numpy as np
import pytest
import torch
from test_sft_spline_prior import assert_gradient_matches

from inverse.sft.least_squares import LeastSquaresData, Reprojection, VertexTerms
from inverse.sft.outline import (
    FREE,
    border_vertices,
    outline_allowance,
    outline_offsets,
    visible_vertices,
)
from inverse.sft.silhouette import silhouette_distance
from inverse.sft.synth import default_camera
from taichi_ndf import jets


def grid(n=4, size=0.2, depth=0.5):
    """A flat n × n vertex grid facing the camera at `depth` [m], two triangles per cell."""
    s = np.linspace(-size / 2, size / 2, n)
    x, y = np.meshgrid(s, s)
    vertices = np.column_stack([x.ravel(), y.ravel(), np.full(n * n, depth)])
    faces = []
    for r in range(n - 1):
        for c in range(n - 1):
            i = r * n + c
            faces += [[i, i + 1, i + n + 1], [i, i + n + 1, i + n]]
    return vertices, np.array(faces)


def test_border_vertices_of_a_grid_are_its_outer_ring():
    vertices, faces = grid(4)
    border = border_vertices(faces, len(vertices))
    assert border.sum() == 12
    assert not border[[5, 6, 9, 10]].any()


def test_a_triangle_in_front_hides_the_vertex_behind_it():
    vertices, faces = grid(4)
    every = np.ones(len(vertices), bool)
    assert visible_vertices(vertices, faces, every, tolerance=0.01).all()
    # A triangle between the camera and vertex 0, 10 cm in front of it.
    v0 = vertices[0] * 0.8
    occluder = np.array([v0 + [-0.02, -0.02, 0], v0 + [0.03, -0.02, 0], v0 + [-0.02, 0.03, 0]])
    both = np.vstack([vertices, occluder])
    faces2 = np.vstack([faces, [[16, 17, 18]]])
    visible = visible_vertices(both, faces2, np.r_[every, False, False, False], tolerance=0.01)
    assert not visible[0]
    assert visible[1:16].all()


def test_allowance_is_frame_0_depth_inside_the_mask_of_visible_border_vertices():
    camera = default_camera(160, 120, focal=150.0)
    vertices, faces = grid(4, size=0.3)
    pixels = camera.project(vertices)
    mask = np.zeros((120, 160), bool)
    x0, y0 = np.floor(pixels.min(0)).astype(int)
    x1, y1 = np.ceil(pixels.max(0)).astype(int)
    mask[y0 - 5:y1 + 6, x0 - 5:x1 + 6] = True  # 5 px wider than the template on each side
    allowance = outline_allowance(vertices, faces, camera, silhouette_distance(mask),
                                  tolerance=0.01)
    border = border_vertices(faces, len(vertices))
    assert np.all(allowance[~border] == FREE)
    assert np.all((allowance[border] < -4) & (allowance[border] > -7.5))
    # The previous frame's mesh hides vertex 0 behind a triangle: no offset for it.
    v0 = vertices[0] * 0.8
    occluder = np.array([v0 + [-0.02, -0.02, 0], v0 + [0.03, -0.02, 0], v0 + [-0.02, 0.03, 0]])
    offsets = outline_offsets(np.r_[allowance, FREE, FREE, FREE], np.vstack([vertices, occluder]),
                              np.vstack([faces, [[16, 17, 18]]]), tolerance=0.01)
    assert offsets[0] == FREE and offsets[3] == allowance[3]


def _at_depth(camera, pixels: np.ndarray, depth: float) -> torch.Tensor:
    """Points (K, 3) [m] that `camera` sees at `pixels` (K, 2), at camera depth `depth` [m]."""
    return torch.from_numpy(np.column_stack([(pixels - [camera.cx, camera.cy])
                                             / [camera.fx, camera.fy] * depth,
                                             np.full(len(pixels), depth)]))


def _box_mask():
    """A 160 × 120 camera and a mask that is the box x 40–119, y 30–89 [px]."""
    camera = default_camera(160, 120, focal=150.0)
    mask = np.zeros((120, 160), bool)
    mask[30:90, 40:120] = True
    return camera, mask


def outline_term(offset):
    """Vertices of a term without tracks' influence: one deep inside the mask, one on its
    outline, one outside; allowance `offset` [px] for all three."""
    camera, mask = _box_mask()
    # pixels (54, 60) 14.5 px inside, (44, 60) 4.5 px inside the outline, (130, 60) outside
    pixels = np.array([[54.0, 60.0], [44.0, 60.0], [130.0, 60.0]])
    rest = _at_depth(camera, pixels, 0.5)
    n = 1 + 3
    term = LeastSquaresData(
        camera, torch.arange(1),
        Reprojection(rest[:1], camera.project(rest[:1]), torch.ones(1), 2.0),
        torch.arange(1, n),
        VertexTerms(rest, rest, 0.0, 0.01, silhouette_distance(mask), 0.0,
                    torch.full((3,), float(offset)), 1.0))
    u = torch.zeros(n, jets.CHANNELS, 3, dtype=torch.float64)
    return term, u


def test_outline_charges_only_vertices_deeper_than_allowed():
    term, u = outline_term(-2.0)
    value, grad = term.evaluate(None, u)
    # vertex 1 (row 2) is 4.5 px inside: (-4.5 + 2)^2 / 3; vertex 0 is 14.5
    # px inside: (-14.5 + 2)^2 / 3; vertex 2 is outside: free.
    assert value == pytest.approx(((-14.5 + 2) ** 2 + (-4.5 + 2) ** 2) / 3, rel=1e-6)
    assert torch.count_nonzero(grad[3, jets.VALUE]) == 0  # outside the mask
    assert grad[2, jets.VALUE, 0] > 0  # deeper inside than allowed: pulled left, outwards
    assert term.parts(u)["outline"] == pytest.approx(value * 1.0, rel=1e-12)
    free, _ = outline_term(-1e9)[0].evaluate(None, u)
    assert free == pytest.approx(0.0, abs=1e-12)


def test_outline_gradient_and_blocks_match_central_differences():
    term, u = outline_term(-2.0)
    u[:, jets.VALUE] = torch.from_numpy(np.random.default_rng(0).normal(0, 0.002, (4, 3)))
    value, grad = term.evaluate(None, u)
    blocks = term.hessian_blocks(None, u, steps=None)[:, jets.VALUE, :, jets.VALUE, :]
    assert_gradient_matches(term, u, grad, range(1, 4))
    # Gauss–Newton: 2 s rowᵀrow, positive semi-definite, rank one where active.
    assert torch.all(torch.linalg.eigvalsh(blocks) >= -1e-9)
    assert torch.linalg.matrix_rank(blocks[1]) == 1


def silhouette_term(slope):
    """Three vertices outside a silhouette whose distance image is rough (random values), so
    the interpolant's own slope and the image's central differences differ."""
    camera = default_camera(160, 120, focal=150.0)
    distance = torch.from_numpy(np.random.default_rng(3).uniform(1.0, 6.0, (120, 160)))
    pixels = np.array([[50.3, 40.6], [81.7, 62.2], [120.45, 90.8]])
    rest = _at_depth(camera, pixels, 0.5)
    term = LeastSquaresData(
        camera, torch.arange(1),
        Reprojection(rest[:1], camera.project(rest[:1]), torch.ones(1), 2.0),
        torch.arange(1, 4), VertexTerms(rest, rest, 0.0, 0.01, distance, 1.0), slope=slope)
    return term, torch.zeros(4, jets.CHANNELS, 3, dtype=torch.float64)


def test_the_interpolant_slope_is_the_gradient_of_the_value_the_image_slope_is_not():
    """Adam's slope ("interpolant") is the value's own gradient; Newton's ("image": smooth
    central differences) is not, on a rough image — which is why the SIREN fit takes the
    first and the spline fit the second."""
    term, u = silhouette_term("interpolant")
    _, grad = term.evaluate(None, u)
    assert_gradient_matches(term, u, grad, range(1, 4))
    image_term, _ = silhouette_term("image")
    _, image_grad = image_term.evaluate(None, u)
    assert not torch.allclose(image_grad, grad, rtol=1e-2)
    with pytest.raises(ValueError, match="slope"):
        silhouette_term("autograd")


def test_silhouette_rows_leave_the_other_vertices_out_of_the_silhouette_term():
    """`VertexTerms.silhouette_rows`: the silhouette term (value, gradient, Gauss–Newton
    blocks) acts on the selected vertices only; all three lie 4.5 px outside the mask."""
    camera, mask = _box_mask()
    pixels = np.array([[124.0, 60.0], [124.0, 50.0], [124.0, 70.0]])
    rest = _at_depth(camera, pixels, 0.5)

    def term(rows):
        return LeastSquaresData(
            camera, torch.arange(1),
            Reprojection(rest[:1], camera.project(rest[:1]), torch.ones(1), 2.0),
            torch.arange(1, 4),
            VertexTerms(rest, rest, 0.0, 0.01, silhouette_distance(mask), 1.0,
                        silhouette_rows=rows))

    u = torch.zeros(4, jets.CHANNELS, 3, dtype=torch.float64)
    every, _ = term(None).evaluate(None, u)
    assert every == pytest.approx(3 * 4.5**2 / 3, rel=1e-6)
    chosen = term(torch.tensor([False, True, False]))
    value, grad = chosen.evaluate(None, u)
    assert value == pytest.approx(4.5**2 / 3, rel=1e-6)
    assert chosen.parts(u)["silhouette"] == pytest.approx(4.5**2 / 3, rel=1e-6)
    assert torch.count_nonzero(grad[[1, 3], jets.VALUE]) == 0
    assert grad[2, jets.VALUE, 0] > 0  # outside on the right: pulled left, inwards
    blocks = chosen.hessian_blocks(None, u, steps=None)[:, jets.VALUE, :, jets.VALUE, :]
    assert torch.count_nonzero(blocks[[1, 3]]) == 0 and torch.count_nonzero(blocks[2]) > 0
