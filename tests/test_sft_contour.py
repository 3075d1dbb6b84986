"""The cover term (inverse.sft.contour): the mask's outline points, the border curve's points,
the term's value on a sheet that leaves part of the outline uncovered, the allowance and the
reach, and its gradient and Gauss–Newton blocks against central differences."""

import numpy as np
import pytest
import torch
from test_sft_outline import _at_depth, _box_mask

from inverse.sft.contour import BorderCurve, CoverTerm, outline_points, tukey, visible_points
from inverse.sft.silhouette import silhouette_distance
from taichi_ndf import jets

DEPTH = 0.5


def grid_sheet(camera, left, right, top, bottom, nx=6, ny=5):
    """A flat sheet at DEPTH [m] seen as the pixel rectangle [left, right] × [top, bottom]: a
    regular nx × ny vertex grid (vertices (n, 3) [m], faces (F, 3), uvs (n, 2))."""
    xs, ys = np.linspace(left, right, nx), np.linspace(top, bottom, ny)
    px = np.array([[x, y] for y in ys for x in xs])
    vertices = _at_depth(camera, px, DEPTH).numpy()
    uvs = np.array([[i / (nx - 1), 1 - j / (ny - 1)] for j in range(ny) for i in range(nx)])
    faces = []
    for j in range(ny - 1):
        for i in range(nx - 1):
            a = j * nx + i
            faces += [[a, a + 1, a + nx + 1], [a, a + nx + 1, a + nx]]
    return vertices, np.array(faces), uvs


def test_outline_points_lie_half_way_between_mask_and_background():
    """Box x 40–119, y 30–89: its outline at x = 39.5 and 119.5 (60 rows each), y = 29.5 and
    89.5 (80 columns each), where the signed distance image is 0."""
    _, mask = _box_mask()
    distance = silhouette_distance(mask)
    points = outline_points(distance)
    assert len(points) == 2 * 60 + 2 * 80
    on_x = np.isin(points[:, 0], [39.5, 119.5])
    assert set(points[on_x, 1]) == set(range(30, 90))
    assert set(points[~on_x, 1]) == {29.5, 89.5}
    # a mask cut by the image's edge: no outline along that edge
    cut = mask.copy()
    cut[30:90, 40:] = True
    assert len(outline_points(silhouette_distance(cut))) == 60 + 2 * 120


def test_border_curve_points_lie_on_the_border_edges():
    camera, _ = _box_mask()
    vertices, faces, uvs = grid_sheet(camera, 50, 100, 40, 80)
    curve = BorderCurve.of(vertices, faces, uvs, per_edge=4)
    assert len(curve.xi) == 4 * 2 * (5 + 4)  # border edges of a 6 × 5 grid, 4 points each
    pixels = camera.project(curve.rest).numpy()
    on_border = (np.isclose(pixels[:, 0], 50) | np.isclose(pixels[:, 0], 100)
                 | np.isclose(pixels[:, 1], 40) | np.isclose(pixels[:, 1], 80))
    assert on_border.all()
    a, b = curve.ends[:, 0], curve.ends[:, 1]
    t = np.linalg.norm(curve.rest.numpy() - vertices[a], axis=1) / np.linalg.norm(
        vertices[b] - vertices[a], axis=1)
    assert np.allclose(np.sort(t[:4]), [0.125, 0.375, 0.625, 0.875])


def cover_term(inset, *, allowance=None, reach=30.0, u=None, visible=None, slack=0.0):
    """The box mask and a sheet `inset` [px] inside its outline on every side; the term's
    start is the sheet as it is (u = 0) unless `u` is given."""
    camera, mask = _box_mask()
    vertices, faces, uvs = grid_sheet(camera, 39.5 + inset, 119.5 - inset, 29.5 + inset,
                                      89.5 - inset)
    curve = BorderCurve.of(vertices, faces, uvs, per_edge=8)
    k = len(curve.xi)
    u_jets = torch.zeros(k, jets.CHANNELS, 3, dtype=torch.float64)
    if u is not None:
        u_jets[:, jets.VALUE] = u
    start = camera.project(curve.rest + u_jets[:, jets.VALUE]).numpy()
    term = CoverTerm(camera, torch.arange(k), curve, silhouette_distance(mask),
                     visible=np.ones(k, bool) if visible is None else visible,
                     allowance=None if allowance is None else torch.full((k,), allowance,
                                                                         dtype=torch.float64),
                     start=start, weight=1.0, reach=reach, slack=slack)
    return term, u_jets


def test_an_uncovered_outline_is_charged_a_covered_one_is_not():
    """A sheet 5 px inside the box on every side: the outline points along the sides are 5 px
    from the border curve (more near the corners); one 0.01 px inside: ≈ 0."""
    term, u = cover_term(5.0)
    parts = term.parts(u)
    assert parts["cover_points"] == 280
    r = term._residual(u[:, jets.VALUE])[3]
    assert np.median(r.numpy()) == pytest.approx(5.0, abs=0.2)
    assert parts["cover"] == pytest.approx(float(tukey(r, 30.0).mean()), rel=1e-12)
    assert parts["cover"] > tukey(torch.tensor([4.9]), 30.0).item()
    close, u0 = cover_term(0.01)
    assert close.parts(u0)["cover"] < 0.3  # the curve's points are ~1.2 px apart along it


def test_the_allowance_and_the_reach_leave_points_out():
    u = cover_term(5.0)[1]
    inside, _ = cover_term(5.0, allowance=8.0)  # the template lay 8 px from mask 0's outline
    assert inside.parts(u)["cover"] == 0.0
    slack, _ = cover_term(5.0, allowance=2.0, slack=3.5)  # 5 px uncovered, 5.5 tolerated
    assert slack.parts(u)["cover"] < cover_term(5.0, allowance=2.0)[0].parts(u)["cover"] / 10
    near, _ = cover_term(5.0, reach=3.0)  # no outline point within 3 px of the start
    assert near.parts(u)["cover_points"] == 0
    assert near.evaluate(None, u)[0] == 0.0
    # hidden border points do not cover: only the left side's are visible
    term, u = cover_term(5.0)
    left = np.isclose(term.camera.project(term.curve.rest).numpy()[:, 0], 44.5)
    half, _ = cover_term(5.0, visible=left)
    assert half.parts(u)["cover"] > term.parts(u)["cover"]


def test_gradient_and_blocks_match_central_differences():
    """The gradient against central differences of the value (nearest points fixed: a small
    random displacement); the Gauss–Newton block Σ_j 2 s w_j J_jᵀ J_j of the residuals
    r_j against their central-difference rows J_j (s = w / m, w_j Tukey's weight)."""
    rng = np.random.default_rng(0)
    u = torch.from_numpy(rng.normal(0, 2e-4, (8 * 2 * 9, 3)))
    term, u_jets = cover_term(4.0, allowance=1.0, u=u)
    value, grad = term.evaluate(None, u_jets)
    assert value > 0
    assert torch.count_nonzero(grad[:, 1:]) == 0
    step = 1e-7
    points = np.flatnonzero(grad[:, jets.VALUE].abs().sum(1).numpy() > 0)[:6]
    assert len(points) == 6
    _, _, _, r0, k0 = term._residual(u_jets[:, jets.VALUE])
    blocks = term.hessian_blocks(None, u_jets, steps=None)
    assert torch.count_nonzero(blocks[:, 1:]) == 0 and torch.count_nonzero(blocks[:, :, :, 1:]) == 0
    for point in points:
        rows = []
        for c in range(3):
            plus, minus = u_jets.clone(), u_jets.clone()
            plus[point, jets.VALUE, c] += step
            minus[point, jets.VALUE, c] -= step
            fd = (term.evaluate(None, plus, grad=False)[0]
                  - term.evaluate(None, minus, grad=False)[0]) / (2 * step)
            assert grad[point, jets.VALUE, c].item() == pytest.approx(fd, rel=1e-5, abs=1e-9)
            rp = term._residual(plus[:, jets.VALUE])
            rm = term._residual(minus[:, jets.VALUE])
            assert torch.equal(rp[4], k0) and torch.equal(rm[4], k0)
            rows.append(((rp[3] - rm[3]) / (2 * step)).numpy())
        jac = np.stack(rows, 1)  # (m, 3): d r_j / d x_point
        s = (1 - (r0.numpy() / term.reach) ** 2) ** 2 * (r0.numpy() > 0)
        expected = 2 * term.scale * np.einsum("m,mi,mj->ij", s, jac, jac)
        assert blocks[point, jets.VALUE, :, jets.VALUE, :].numpy() == pytest.approx(
            expected, rel=1e-5, abs=1e-6)


def test_visible_points_need_both_ends_seen():
    camera, _ = _box_mask()
    vertices, faces, uvs = grid_sheet(camera, 50, 100, 40, 80)
    curve = BorderCurve.of(vertices, faces, uvs, per_edge=2)
    offsets = torch.full((len(vertices),), -np.inf, dtype=torch.float64)
    assert not visible_points(curve, offsets).any()
    offsets[[0, 1, 2]] = 0.0  # the first three vertices of the top row
    seen = visible_points(curve, offsets)
    assert seen.sum() == 2 * 2  # edges 0–1 and 1–2
    assert visible_points(curve, None).all()


@pytest.mark.parametrize("extra, named", [
    (["--cover-weight", "-1"], "cover_weight"),
    (["--cover-slack", "nan"], "cover_slack"),
    (["--allowance-fade", "0"], "allowance_fade"),
    (["--field", "siren", "--cover-weight", "1"], "--cover-weight")])
def test_the_cli_refuses_bad_border_options_before_any_work(tmp_path, capsys, extra, named):
    from inverse.cli import sft as sft_cli

    status = sft_cli.main(["--frames", str(tmp_path / "none"), "--camera", "c.json",
                           "--template", "t.obj", "--texture", "x.png", "--out",
                           str(tmp_path / "out"), "--precision", "f64", *extra])
    assert status == 2
    assert named in capsys.readouterr().err
