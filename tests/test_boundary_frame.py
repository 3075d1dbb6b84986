"""Constraints in a tilted frame (`BoundaryConditions(frame=...)`): the composition is the
axis-aligned one turned by the frame, its adjoint is exact, and the quarter plate turned by
30° about z with tilted symmetry planes gives the axis-aligned quarter plate's deflection on
both paths (spline + projected Newton through the assembly, SIREN + Adam through backward);
a clamp split into the normal component clamped and the in-plane ones hinged leaves the
stretch across the edge free."""

import dataclasses
import math

import pytest
import torch

from taichi_ndf.boundary import BoundaryConditions, ClampedEdge, HingedEdge, SymmetryPlane
from taichi_ndf.field import FieldConfig, NeuralField
from taichi_ndf.geometry import Plane
from taichi_ndf.operator import DisplacementOperator
from taichi_ndf.scene import load_scene
from taichi_ndf.validation import SCENES_DIR, load_case, run_case

F64 = torch.float64
C, S = math.cos(math.radians(30)), math.sin(math.radians(30))
TURNED = ((C, S, 0.0), (-S, C, 0.0), (0.0, 0.0, 1.0))  # e_x, e_y, e_z turned 30° about z


def quarter_plate(frame):
    plate = Plane(bounds=((0.0, 2.0), (0.0, 1.0)), **({} if frame is None else {"frame": frame}))
    constraints = [HingedEdge("xi1_min", components="z"), SymmetryPlane("xi1_max", "x"),
                   ClampedEdge("xi2_min", components="z"),
                   HingedEdge("xi2_min", components="y", displacement=(0.0, 0.2, 0.0)),
                   SymmetryPlane("xi2_max", "y", antisymmetric=True)]
    boundary = BoundaryConditions(constraints, plate.domain, surface=plate, length=1.0,
                                  frame=frame)
    field = NeuralField(FieldConfig(width=8, hidden_layers=2, omega0=3.0, output_scale=0.1,
                                    domain=plate.domain.bounds), seed=1, dtype=F64)
    return DisplacementOperator(field, boundary)


def test_the_composition_in_a_turned_frame_is_the_aligned_one_turned():
    """Prescribed displacements are world vectors: the turned model's is given turned too."""
    xi = torch.rand(50, 2, dtype=F64, generator=torch.Generator().manual_seed(0)) * torch.tensor(
        [2.0, 1.0], dtype=F64)
    aligned = quarter_plate(None)
    turned = quarter_plate(TURNED)
    world = torch.tensor(TURNED, dtype=F64)
    turned_moves = [dataclasses.replace(c, displacement=tuple((torch.tensor(c.displacement,
                                                                            dtype=F64) @ world
                                                               ).tolist()))
                    if isinstance(c, HingedEdge) and c.components == "y" else c
                    for c in turned.boundary.constraints]
    turned = DisplacementOperator(turned.field, BoundaryConditions(
        turned_moves, turned.boundary.domain, surface=turned.boundary.surface, length=1.0,
        frame=TURNED))
    u_aligned, u_turned = aligned.jets(xi, t=0.7), turned.jets(xi, t=0.7)
    assert torch.allclose(u_turned, u_aligned @ world, atol=1e-13, rtol=0)
    # The adjoint: <g, u(N) − u(0)> = <compose_adjoint(g), N> for any raw jets N.
    raw = torch.randn(50, 6, 3, dtype=F64, generator=torch.Generator().manual_seed(1))
    grad = torch.randn(50, 6, 3, dtype=F64, generator=torch.Generator().manual_seed(2))
    b = turned.boundary
    linear = b.compose(xi, raw, t=0.7) - b.compose(xi, torch.zeros_like(raw), t=0.7)
    assert float((grad * linear).sum()) == pytest.approx(
        float((b.compose_adjoint(xi, grad) * raw).sum()), rel=1e-12)
    # A symmetry plane's normal displacement vanishes along the turned normal.
    edge = torch.stack((torch.full((9,), 2.0, dtype=F64), torch.linspace(0, 1, 9, dtype=F64)),
                       dim=1)
    assert float((turned.jets(edge)[:, 0] @ world[0]).abs().max()) < 1e-14


def test_the_last_layer_newton_refuses_a_frame():
    with pytest.raises(ValueError, match="frame"):
        quarter_plate(TURNED).output_layer_jacobian(torch.zeros(3, 2, dtype=F64))


def turned_scene(tmp_path) -> None:
    """square_plate_quarter.toml and a copy turned 30° about z (plate and boundary frame)."""
    text = (SCENES_DIR / "square_plate_quarter.toml").read_text()
    frame = f"frame = {[list(r) for r in TURNED]}\n"
    turned = text.replace('type = "plane"\n', 'type = "plane"\n' + frame).replace(
        "[boundary]\n", "[boundary]\n" + frame)
    assert turned.count("frame =") == 2
    (tmp_path / "aligned.toml").write_text(text)
    (tmp_path / "turned.toml").write_text(turned)


def centre_deflection(tmp_path, scene: str, field: str | None = None, solver=None) -> float:
    case = dataclasses.replace(
        load_case(SCENES_DIR.parent / "examples" / "square_plate_quarter.toml"), scene=scene)
    (row,) = run_case(case, quick=True, field=field, solver=solver, scenes_dir=tmp_path).rows
    return row.computed


def test_turned_quarter_plate_on_the_spline_path(tmp_path):
    """Measured: 0.48745353604 both, 2.6e-13 apart (the turned problem is the aligned one
    in frame components)."""
    turned_scene(tmp_path)
    aligned = centre_deflection(tmp_path, "aligned.toml", "spline")
    turned = centre_deflection(tmp_path, "turned.toml", "spline")
    assert turned == pytest.approx(aligned, rel=1e-3)
    assert aligned == pytest.approx(0.4875, rel=0.02)


def test_turned_quarter_plate_with_adam(tmp_path):
    """30 Adam steps from the same initial field: the same trajectory in frame components.
    Measured: 0.44786493196 both, 1.6e-11 apart."""
    turned_scene(tmp_path)
    config = dataclasses.replace(load_scene(tmp_path / "aligned.toml").solver,
                                 newton_iterations=0, samples=256, monitor_samples=256,
                                 monitor_every=10).with_iterations(30)
    aligned = centre_deflection(tmp_path, "aligned.toml", solver=config)
    turned = centre_deflection(tmp_path, "turned.toml", solver=config)
    assert turned == pytest.approx(aligned, rel=1e-3)
    assert abs(aligned) > 1e-3


STRIP = """
name = "strip"
[geometry]
type = "plane"
bounds = [[0.0, 2.0], [0.0, 1.0]]
[material]
type = "linear"
young_modulus = 1.0e4
poisson_ratio = 0.0
thickness = 0.01
areal_density = 1.0
[loads]
[[loads.line]]
edge = "xi1_max"
force = [0.01, 0.0, 0.0]
[boundary]
length = 1.0
{clamp}
[field]
type = "spline"
spans = [8, 4]
[training]
method = "newton"
"""
CARTESIAN_CLAMP = """[[boundary.constraint]]
type = "clamped_edge"
edge = "xi1_min"
"""
EDGE_FRAME_CLAMP = CARTESIAN_CLAMP + 'components = "z"\n' + """[[boundary.constraint]]
type = "hinged_edge"
edge = "xi1_min"
components = "xy"
"""


def root_stretch(tmp_path, clamp: str) -> float:
    """ε₁₁ = u_x,1 at the clamped root's midpoint of a strip pulled along x (linear regime:
    force 0.01 N/m against D = 100 N/m, ν = 0), solved on the spline path."""
    from taichi_ndf import jets
    from taichi_ndf.minimise.assembly import displacement_at
    from taichi_ndf.spline_solver import solve_spline

    (tmp_path / "strip.toml").write_text(STRIP.format(clamp=clamp))
    scene = load_scene(tmp_path / "strip.toml")
    run = solve_spline(scene.model, scene.field, dataclasses.replace(scene.solver,
                                                                     progress=False))
    t, coefficients = run.steps[-1]
    operator = DisplacementOperator(run.field, scene.model.boundary)
    root = torch.tensor([[0.0, 0.5]], dtype=F64)
    return float(displacement_at(operator, root, coefficients, t)[0, jets.D1, 0])


def test_a_clamp_in_the_edges_frame_leaves_the_stretch_across_the_edge_free(tmp_path):
    """The uniform strain is f/D = 1e-4. Measured at the root: Cartesian clamp exactly 0
    (pinned), normal clamped + in-plane hinged 0.99987e-4. The plate's edge frame is the world
    axes; a tilted edge takes a `[boundary] frame` with z along its normal."""
    assert abs(root_stretch(tmp_path, CARTESIAN_CLAMP)) < 1e-12
    assert root_stretch(tmp_path, EDGE_FRAME_CLAMP) == pytest.approx(1e-4, rel=0.01)
