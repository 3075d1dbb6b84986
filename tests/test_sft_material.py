"""Material from video (`inverse.sft.material_from_video`, `ndf-sft --estimate-material`): the
grid template's coordinates, a coarse hanging sheet of known bending length recovered from its
equilibria (the project's forward solve on another grid and degree), and the command line's
refusal of bad options (exit 2) before any work."""

import json

import numpy as np
import pytest

from inverse.cli.sft import main
from inverse.sft.hanging import SheetGrid
from inverse.sft.hanging_synth import HangingConfig, equilibrium_shapes, template_grid
from inverse.sft.material_from_video import MaterialFromVideoConfig, estimate_material
from taichi_ndf.io import grid_mesh, write_obj


def test_sheet_grid_of_both_index_orders():
    """ndf-sim's grid order (ξ¹ fastest) and PGSfT's (ξ² fastest, held corners 0 and 992 of a
    32 × 32 grid) give the same surface coordinates; a held pair that is not one grid edge's
    two ends is refused."""
    grid = grid_mesh(((0.0, 0.3), (0.0, 0.2)), (6, 4))
    vertices = np.column_stack([grid.xi, np.zeros(len(grid.xi))])
    sheet = SheetGrid.from_template(vertices, grid.faces, (0, 6))
    assert sheet.size == pytest.approx((0.3, 0.2))
    assert np.allclose(sheet.xi, grid.xi)
    # the same grid stored column-major (the PGSfT layout): vertex k = i * 5 + j
    order = np.arange(len(vertices)).reshape(5, 7).T.ravel()  # new index -> old index
    inverse = np.argsort(order)
    transposed = SheetGrid.from_template(vertices[order], inverse[grid.faces], (0, 30))
    assert np.allclose(transposed.xi, grid.xi[order])
    with pytest.raises(ValueError, match="not the two ends of one edge"):
        SheetGrid.from_template(vertices, grid.faces, (0, 34))


def test_defaults_are_the_measured_settings():
    """The estimate's defaults are the settings measured to recover B (quartic splines on
    grids chosen from the bending length, D estimated beside B, the flat size from the
    template), and the command line sets each of them."""
    config = MaterialFromVideoConfig()
    assert (config.degree, config.spans, config.membrane_stiffness, config.sheet_size) == \
        (4, None, None, None)
    assert config.estimate_membrane
    assert (config.observed, config.sheet_size_from) == ("3d", "equilibrium")
    held = MaterialFromVideoConfig(membrane_stiffness=100.0)
    assert not held.estimate_membrane and held.start_material.membrane_stiffness == 100.0
    from inverse.cli.sft import build_parser
    from inverse.cli.sft_material import material_config

    base = ["--frames", "f", "--camera", "c", "--template", "t", "--texture", "x", "--out", "o",
            "--estimate-material"]
    parser = build_parser()
    assert material_config(parser.parse_args(base)) == MaterialFromVideoConfig()
    set_ = material_config(parser.parse_args(base + [
        "--material-degree", "3", "--material-spans", "5", "6", "--membrane-stiffness", "250",
        "--sheet-size", "0.3", "0.2", "--material-observed", "ray", "--sheet-size-from",
        "template", "--material-frame-weights", "equal", "--material-corners", "held",
        "--material-quasi-static", "0.05"]))
    assert (set_.degree, set_.spans, set_.membrane_stiffness, set_.sheet_size) == \
        (3, (5, 6), 250.0, (0.3, 0.2))
    assert (set_.observed, set_.sheet_size_from) == ("ray", "template")
    assert (config.frame_weights, set_.frame_weights) == ("misfit", "equal")
    assert (config.corners, set_.corners) == ("fitted", "held")
    assert (config.quasi_static_limit, set_.quasi_static_limit) == (None, 0.05)
    grid = grid_mesh(((0.0, 0.3), (0.0, 0.2)), (6, 4))
    sheet = SheetGrid.from_template(np.column_stack([grid.xi, np.zeros(len(grid.xi))]),
                                    grid.faces, (0, 6)).with_size((0.6, 0.1))
    assert sheet.size == (0.6, 0.1) and np.allclose(sheet.xi, grid.xi * [2.0, 0.5])


def test_grid_from_the_bending_length():
    """The coarse grid's spans are at most 1.5 c long, 7 to 16 per side: a 0.3 m sheet of
    c = 5 cm or 3 cm keeps the 7 × 7 measured on them, the median fabric's c = 2 cm gets
    10 × 10 (7 × 7 left B undetermined even on noise-free truth meshes), a softer sheet is
    capped with a note. The choice follows the guess, then the coarse estimate, and is
    refined only when the estimate asks for a finer grid; stated spans are kept."""
    from inverse.sft.material_grid import GridChoice, spans_for_bending_length

    size = (0.3, 0.3)
    assert spans_for_bending_length(size, 0.05) == ((7, 7), False)
    assert spans_for_bending_length(size, 0.03) == ((7, 7), False)
    assert spans_for_bending_length(size, 0.02) == ((10, 10), False)
    assert spans_for_bending_length((0.6, 0.3), 0.02) == ((16, 10), True)
    weight = 0.2 * 9.81
    choice = GridChoice(MaterialFromVideoConfig(areal_density=0.2,
                                                start_bending_length=0.02), 9.81)
    assert choice.first(size) == (10, 10)
    assert choice.next(size, weight * 0.05 ** 3, "coarse estimate") == (7, 7)
    assert choice.next(size, weight * 0.04 ** 3, "estimate", only_finer=(7, 7)) is None
    assert choice.next(size, weight * 0.015 ** 3, "estimate", only_finer=(7, 7)) == (14, 14)
    assert [s["spans"] for s in choice.steps] == [[10, 10], [7, 7], [7, 7], [14, 14]]
    assert not choice.notes
    choice.next(size, weight * 0.005 ** 3, "estimate")
    assert "capped at 16" in choice.notes[0]
    stated = GridChoice(MaterialFromVideoConfig(spans=(5, 6)), 9.81)
    assert stated.first(size) == (5, 6) and stated.next(size, 1e-6, "estimate") is None


@pytest.mark.slow
def test_coarse_hanging_sheet_bending_length_recovered():
    """Three frames of a 0.3 m sheet (c = 5 cm, ρ_A = 0.2 kg/m², D = 100 N/m) held at its
    moving top corners, solved on 12 × 12 quartic spans; estimated at the defaults (quartic
    7 × 7 / 14 × 14 spans, another grid: no inverse crime; B and D both unknown) from a start
    of c = 2 cm with the stated areal density, the flat sheet from the template: B within 5 %
    and within 2 standard errors (measured −1.5 % ± 8.1 %, D 101.7 ± 4.3 N/m with equal frame
    weights; +0.65 % ± 3.0 %, D 102.1 ± 6.4 N/m with the misfit weights, the default since
    2026-12-06 10:20; with every frame's held corners fitted — the default since 13:45 for a
    template that is not frame 0's shape — −2.36 % ± 6.7 % on the stored truth meshes;
    benchmarks/RESULTS.md, Material from video)."""
    truth = HangingConfig(frames=3, cells=(12, 12), bending_length=0.05, spans=(12, 12))
    shapes = equilibrium_shapes(truth)
    grid, _, held = template_grid(truth)
    config = MaterialFromVideoConfig(areal_density=0.2, frames=0)
    flat = np.column_stack([grid.xi, np.zeros(len(grid.xi))])
    material = estimate_material(shapes, grid.faces, held, config, rest=flat)
    b = material["bending_stiffness"]
    true_b = truth.material.bending_stiffness
    assert "B / (ρ_A g)" in material["identifiability"]
    assert b["determined"]
    assert abs(b["value"] - true_b) < 0.05 * true_b
    assert abs(b["value"] - true_b) < 2 * b["standard_error"]
    assert [g["spans"] for g in material["grids"]] == [[7, 7], [14, 14]]
    d = material["membrane_stiffness"]
    assert not d["held"] and abs(d["value"] - 100.0) < 2 * d["standard_error"]


@pytest.mark.slow
def test_flat_size_from_a_hanging_template():
    """The template is frame 0's hanging shape, whose grid lines gravity stretched (0.4 %):
    taken as the flat size it put B 15 % high (benchmarks/RESULTS.md); unstretched by the
    fitted frame-0 equilibrium (the default `sheet_size_from="equilibrium"`) the flat size
    comes out within 0.05 % of the true 0.3 m and B within 5 % (measured −0.55 %)."""
    truth = HangingConfig(frames=3, cells=(12, 12), bending_length=0.05, spans=(12, 12))
    shapes = equilibrium_shapes(truth)
    grid, _, held = template_grid(truth)
    config = MaterialFromVideoConfig(areal_density=0.2, frames=0)
    material = estimate_material(shapes, grid.faces, held, config, rest=shapes[0])
    assert material["sheet_size_from"] == "equilibrium"
    assert np.allclose(material["sheet_size_m"], truth.sheet_size, rtol=5e-4)
    assert material["sheet_size_passes"][0]["change"] > 2e-3  # the stretch it removed
    b = material["bending_stiffness"]
    true_b = truth.material.bending_stiffness
    assert abs(b["value"] - true_b) < 0.05 * true_b
    assert abs(b["value"] - true_b) < 2 * b["standard_error"]


@pytest.mark.parametrize("extra, message", [
    (["--areal-density", "0.2"], "needs --estimate-material"),
    (["--estimate-material"], "needs the two held corners"),
    (["--estimate-material", "--held-corners", "0", "5"], "not the two ends of one edge"),
    (["--estimate-material", "--held-corners", "0", "4", "--areal-density", "-1"],
     "areal_density must be positive"),
    (["--estimate-material", "--held-corners", "0", "4", "--material-frames", "1"],
     "frames must be 0"),
    (["--material-spans", "7", "7"], "--material-spans needs --estimate-material"),
    (["--estimate-material", "--held-corners", "0", "4", "--material-degree", "5"],
     "degree must be 3 or 4"),
    (["--estimate-material", "--held-corners", "0", "4", "--membrane-stiffness", "0"],
     "membrane_stiffness must be positive"),
    (["--estimate-material", "--held-corners", "0", "4", "--sheet-size", "0.3", "-1"],
     "sheet_size must be positive"),
    (["--estimate-material", "--held-corners", "0", "4", "--membrane-stiffness", "nan"],
     "must be finite"),
    (["--estimate-material", "--held-corners", "0", "4", "--material-quasi-static", "-0.1"],
     "quasi_static_limit must be positive"),
])
def test_cli_rejects_bad_material_options(tmp_path, capsys, extra, message):
    """Each bad option: exit 2 and one line naming it, before tracking (no output folder)."""
    grid = grid_mesh(((0.0, 0.2), (0.0, 0.2)), (4, 4))
    vertices = np.column_stack([grid.xi - 0.1, np.full(len(grid.xi), 0.5)])
    uvs = np.column_stack([grid.uv[:, 0], 1.0 - grid.uv[:, 1]])
    write_obj(tmp_path / "template.obj", vertices, grid.faces, uvs=uvs)
    frames = tmp_path / "frames"
    frames.mkdir()
    import cv2
    texture = (np.random.default_rng(0).random((64, 64, 3)) * 255).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "texture.png"), texture)
    cv2.imwrite(str(frames / "000000.png"), np.zeros((120, 160, 3), np.uint8))
    (tmp_path / "camera.json").write_text(json.dumps(
        {"fx": 150.0, "fy": 150.0, "cx": 79.5, "cy": 59.5, "width": 160, "height": 120}))
    out = tmp_path / "out"
    try:  # a value argparse refuses exits from the parser, the others return 2
        code = main(["--frames", str(frames), "--camera", str(tmp_path / "camera.json"),
                     "--template", str(tmp_path / "template.obj"),
                     "--texture", str(tmp_path / "texture.png"), "--out", str(out), *extra])
    except SystemExit as exit_:
        code = exit_.code
    err = capsys.readouterr().err
    assert code == 2
    assert message in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


class _Stub:
    """A forward model whose equilibrium is `positions` and whose sensitivity to the one
    outer coordinate is `sensitivity` (the interface `outer_fit.residuals` reads)."""

    def __init__(self, positions, sensitivity):
        import torch

        self.field = type("F", (), {"parameters": [torch.zeros(1, dtype=torch.float64)]})()
        self._x, self._dx = positions, sensitivity

    def positions(self, xi):
        return self._x

    def position_sensitivity(self, xi, sensitivity):
        return self._dx


def test_ray_rows_leave_the_depth_out_of_the_residual():
    """`observed="ray"`: a reconstruction's error along the camera rays (depth) does not reach
    the residuals or their Jacobian, an error across them does; with all three coordinates
    (the old residual) the depth error is in the residual. The material fit therefore cannot
    move B to explain a depth bias."""
    import torch

    from inverse.material.observations import Observation, ray_rows
    from inverse.material.outer_fit import residuals
    from inverse.sft.hanging import hanging_across, hanging_model

    gen = torch.Generator().manual_seed(0)
    truth = torch.rand((20, 3), generator=gen, dtype=torch.float64) * 0.3 + \
        torch.tensor([-0.15, -0.15, 0.8], dtype=torch.float64)
    rows = ray_rows(truth)
    ray = truth / truth.norm(dim=1, keepdim=True)
    assert torch.allclose(torch.einsum("mkj,mlj->mkl", rows, rows),
                          torch.eye(2, dtype=torch.float64).expand(20, 2, 2), atol=1e-12)
    assert torch.einsum("mkj,mj->mk", rows, ray).abs().max() < 1e-12
    depth_bias = truth + 0.002 * (1 + truth[:, :1]) * ray  # smooth, along the rays only
    corners = truth[:2].numpy()
    model = hanging_model((0.3, 0.3), MaterialFromVideoConfig().start_material, corners,
                          hanging_across(corners, np.array([0.0, 9.81, 0.0])),
                          np.array([0.0, 9.81, 0.0]))
    xi = torch.full((20, 2), 0.1, dtype=torch.float64)
    dx = torch.rand((20, 3, 1), generator=gen, dtype=torch.float64)
    stub = _Stub(truth, dx)
    r3, j3 = residuals(stub, Observation(model, depth_bias, xi), 8, torch.zeros(1))
    assert np.abs(r3).max() > 1e-3 and j3.shape == (60, 1)
    r2, j2 = residuals(stub, Observation(model, depth_bias, xi, rows), 8, torch.zeros(1))
    assert r2.shape == (40,) and np.abs(r2).max() < 1e-12
    assert np.allclose(j2.reshape(20, 2), torch.einsum("mkj,mj->mk", rows, dx[..., 0]).numpy())
    across = truth + 0.002 * rows[:, 0]
    r2, _ = residuals(stub, Observation(model, across, xi, rows), 8, None)
    assert np.allclose(np.abs(r2.reshape(20, 2)), [[0.002, 0.0]] * 20, atol=1e-12)
    assert Observation(model, depth_bias, xi, rows).components == 2
    with pytest.raises(ValueError, match="need correspondence"):
        Observation(model, depth_bias, None, rows)
    with pytest.raises(ValueError, match="observed must be one of"):
        MaterialFromVideoConfig(observed="depth")


def test_clustered_error_counts_a_shared_error_once_per_frame():
    """Residuals that share an error within each observation (a reconstruction's smooth
    error, the frame's held corners) are one draw per observation: the cluster-robust error
    is several times the Fisher error, which counts every residual as independent; with
    independent residuals the two agree (within the spread of 40 clusters)."""
    from inverse.material.outer_fit import clustered_std

    rng = np.random.default_rng(0)
    frames, points = 40, 200
    jacobian = rng.standard_normal((frames * points, 1)) + 1.0
    clusters = [np.arange(f * points, (f + 1) * points) for f in range(frames)]

    def fisher(r):
        return np.sqrt(r @ r / (len(r) - 1) / float((jacobian.T @ jacobian)[0, 0]))

    independent = rng.standard_normal(frames * points)
    assert 0.7 < clustered_std(jacobian, independent, clusters)[0] / fisher(independent) < 1.3
    shared = np.repeat(rng.standard_normal(frames), points) + 0.1 * independent
    assert clustered_std(jacobian, shared, clusters)[0] > 5 * fisher(shared)


def test_planar_template_is_the_flat_sheet():
    """`sheet_size_from="equilibrium"` unstretches only a template that is a hanging shape:
    a planar template (in any orientation) is the flat sheet itself."""
    from inverse.sft.material_from_video import planar

    grid = grid_mesh(((0.0, 0.3), (0.0, 0.2)), (6, 4))
    flat = np.column_stack([grid.xi, np.zeros(len(grid.xi))])
    rotation = np.linalg.qr(np.random.default_rng(1).standard_normal((3, 3)))[0]
    assert planar(flat) and planar(flat @ rotation.T + [0.1, 0.2, 0.8])
    sagging = flat + np.column_stack([0 * grid.xi, 0.01 * np.sin(np.pi * grid.xi[:, 0] / 0.3)])
    assert not planar(sagging)
    with pytest.raises(ValueError, match="sheet_size_from must be one of"):
        MaterialFromVideoConfig(sheet_size_from="frame0")


def test_misfit_weights_count_each_frame_by_its_own_misfit():
    """`frame_weights="misfit"`: each frame's residuals are scaled by σ̄ / σ_f, σ_f its
    coarse-grid rms misfit — a frame twice as far from the model counts with a quarter of the
    weight in the squared residuals; σ̄ is their rms, so equal misfits give unit weights;
    σ_f is floored (a frame that the model fits exactly does not take all the weight). The
    weights reach the residuals through `Observation.rows` (all three coordinates scaled)."""
    import torch

    from inverse.material.outer_fit import residuals
    from inverse.sft.material_from_video import MISFIT_FLOOR, frame_observations, misfit_weights

    w = misfit_weights(np.array([1e-3, 2e-3, 4e-3]))
    assert np.allclose(w[0] / w[1], 2.0) and np.allclose(w[1] / w[2], 2.0)
    assert np.isclose(np.sqrt(np.mean((np.array([1e-3, 2e-3, 4e-3]) * w) ** 2)),
                      np.sqrt(np.mean(np.array([1e-3, 2e-3, 4e-3]) ** 2)))
    assert np.allclose(misfit_weights(np.full(4, 3e-4)), 1.0)
    assert np.isfinite(misfit_weights(np.array([0.0, 1e-3]))).all()
    assert misfit_weights(np.array([0.0, 1e-3]))[0] == \
        pytest.approx(misfit_weights(np.array([MISFIT_FLOOR, 1e-3]))[0])

    grid_ = grid_mesh(((0.0, 0.3), (0.0, 0.3)), (4, 4))
    flat = np.column_stack([grid_.xi - 0.15, np.full(len(grid_.xi), 0.6)])
    sheet = SheetGrid.from_template(flat, grid_.faces, (0, 4))
    shift = np.array([0.0, 0.0, 1e-3])
    frames = [flat, flat + shift, flat + 2 * shift]
    config = MaterialFromVideoConfig(frame_weights="misfit")
    weighted = frame_observations(frames, sheet, config, [0, 1, 2], np.array([2.0, 1.0, 0.5]))
    plain = frame_observations(frames, sheet, config, [0, 1, 2])
    assert all(o.rows is None for o in plain)
    stub = _Stub(torch.from_numpy(flat), torch.zeros((len(flat), 3, 1), dtype=torch.float64))
    for k, scale in enumerate([2.0, 1.0, 0.5]):
        r_w, _ = residuals(stub, weighted[k], 8, None)
        r_p, _ = residuals(stub, plain[k], 8, None)
        assert r_w.shape == r_p.shape == (3 * len(flat),)
        assert np.allclose(r_w, scale * r_p)
    assert np.abs(residuals(stub, weighted[2], 8, None)[0]).max() == pytest.approx(1e-3)
    with pytest.raises(ValueError, match="frame_weights must be one of"):
        MaterialFromVideoConfig(frame_weights="depth")
