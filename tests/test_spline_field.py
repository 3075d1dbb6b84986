"""B-spline field: jets against an independent torch reference (Cox–de Boor) and finite
differences, partition of unity, periodic seams, exact refinement, the backward pass, state
dicts, checkpoints and f32/f64 agreement."""

import math
from pathlib import Path

import pytest
import torch

from taichi_ndf.field import SplineConfig, SplineField
from taichi_ndf.field.bspline import piece_coefficients
from taichi_ndf.minimise.checkpoint import load_checkpoint, save_checkpoint
from taichi_ndf.problem.optim import Adam, AdamConfig

ROOT = Path(__file__).resolve().parents[1]
F64 = torch.float64
DOMAIN = ((0.5, 2.5), (-1.0, 0.5))
CASES = [  # (degree, periodic, spans)
    (3, (False, False), (3, 4)),
    (4, (False, False), (4, 3)),
    (3, (True, False), (5, 2)),
    (4, (False, True), (2, 6)),
    (3, (True, True), (2, 1)),  # fewer spans than p + 1: indices repeat at a point
]


def random_field(degree, periodic, spans, seed=0, dtype=F64, domain=DOMAIN):
    field = SplineField(SplineConfig(spans=spans, degree=degree, domain=domain,
                                     periodic=periodic), dtype=dtype)
    g = torch.Generator().manual_seed(seed)
    field.coefficients.copy_(torch.randn(field.coefficients.shape, generator=g, dtype=F64))
    return field


def points(n, domain=DOMAIN, seed=1, dtype=F64):
    """n random points of the domain plus its four corners."""
    g = torch.Generator().manual_seed(seed)
    lo = torch.tensor([d[0] for d in domain], dtype=F64)
    hi = torch.tensor([d[1] for d in domain], dtype=F64)
    xi = lo + (hi - lo) * torch.rand(n, 2, generator=g, dtype=F64)
    corners = torch.tensor([[a, b] for a in domain[0] for b in domain[1]], dtype=F64)
    return torch.cat((xi, corners)).to(dtype)


# ---------------------------------------------------------------- the torch reference
def reference_basis_1d(x, lo, hi, spans, degree, periodic):
    """Values, first and second derivatives (3, N, m) of every coefficient's B-spline, by the
    Cox–de Boor recursion on the extended uniform knots t_i = lo + (i − p)h."""
    h = (hi - lo) / spans
    if periodic:
        x = lo + torch.remainder(x - lo, hi - lo)
    count = spans + degree  # open coefficients; a periodic direction folds them modulo spans
    knots = lo + (torch.arange(count + degree + 1, dtype=F64) - degree) * h
    order0 = ((x[:, None] >= knots[None, :-1]) & (x[:, None] < knots[None, 1:])).to(F64)
    levels = [order0]  # levels[q]: degree-q functions, (N, count + degree − q)
    for q in range(1, degree + 1):
        b = levels[-1]
        left = (x[:, None] - knots[None, : b.shape[1] - 1]) / (q * h) * b[:, :-1]
        right = (knots[None, q + 1 : q + b.shape[1]] - x[:, None]) / (q * h) * b[:, 1:]
        levels.append(left + right)
    p = degree
    value = levels[p]
    # Uniform knots: B'_{i,p} = (B_{i,p−1} − B_{i+1,p−1}) / h.
    first = (levels[p - 1][:, :-1] - levels[p - 1][:, 1:]) / h
    second = (levels[p - 2][:, :-2] - 2 * levels[p - 2][:, 1:-1] + levels[p - 2][:, 2:]) / h**2
    basis = torch.stack((value, first, second))
    if periodic:
        folded = torch.zeros(3, x.shape[0], spans, dtype=F64)
        folded.index_add_(2, torch.arange(count) % spans, basis)
        basis = folded
    return basis


def reference_jets(field, xi):
    c = field.config
    b1, b2 = (reference_basis_1d(xi[:, d].double(), *c.domain[d], c.spans[d], c.degree,
                                 c.periodic[d]) for d in range(2))
    grid = field.coefficients.double().view(*c.coefficient_counts, c.out_dim)
    pairs = [(0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)]
    return torch.stack([torch.einsum("ni,nj,ijc->nc", b1[a], b2[b], grid) for a, b in pairs],
                       dim=1)


def dense_jacobian(field, xi):
    """(N·6, m1·m2) Jacobian of every jet channel w.r.t. the coefficients, from local_basis."""
    index, basis = field.local_basis(xi)
    n, k = index.shape
    jac = torch.zeros(n, 6, field.config.num_coefficients, dtype=basis.dtype)
    jac.scatter_add_(2, index[:, None, :].expand(n, 6, k), basis)
    return jac.view(n * 6, -1)


# ---------------------------------------------------------------- configuration
@pytest.mark.parametrize(("kwargs", "message"), [
    ({"spans": (0, 3)}, "spans"),
    ({"spans": (2,)}, "spans"),
    ({"spans": (2.0, 3)}, "spans"),
    ({"spans": (2, 3), "degree": 2}, "degree"),
    ({"spans": (2, 3), "degree": True}, "degree"),
    ({"spans": (2, 3), "out_dim": 0}, "out_dim"),
    ({"spans": (2, 3), "domain": ((0, 1), (1, 1))}, r"domain\[1\]"),
    ({"spans": (2, 3), "periodic": (1, 0)}, "periodic"),
])
def test_config_rejects_bad_values(kwargs, message):
    with pytest.raises(ValueError, match=message):
        SplineConfig(**kwargs)


def test_config_counts_and_dict_round_trip():
    config = SplineConfig(spans=[4, 6], degree=4, domain=((0, 2), (0, 3)), periodic=(True, False))
    assert config.spans == (4, 6)
    assert config.coefficient_counts == (4, 10)
    assert config.num_coefficients == 40 and config.support == 25
    assert config.spacing == (0.5, 0.5)
    assert config.refined().spans == (8, 12)
    assert SplineConfig.from_dict(config.to_dict()) == config
    with pytest.raises(ValueError, match="unknown SplineConfig keys"):
        SplineConfig.from_dict({**config.to_dict(), "levels": 2})


def test_span_pieces_are_the_cardinal_bspline():
    # The cubic pieces (1/6)(1−u)³, (1/6)(3u³ − 6u² + 4), ... in monomial form.
    assert [[float(c) * 6 for c in row] for row in piece_coefficients(3)] == [
        [1, -3, 3, -1], [4, 0, -6, 3], [1, 3, 3, -3], [0, 0, 0, 1]]
    for degree in (3, 4):  # pieces sum to 1 as polynomials
        sums = [sum(row[k] for row in piece_coefficients(degree)) for k in range(degree + 1)]
        assert sums == [1] + [0] * degree


# ---------------------------------------------------------------- jets
@pytest.mark.parametrize(("degree", "periodic", "spans"), CASES)
def test_jets_match_the_cox_de_boor_reference(degree, periodic, spans):
    field = random_field(degree, periodic, spans)
    xi = points(300)
    jets = field.jets(xi)
    assert jets.shape == (304, 6, 3) and jets.dtype == F64
    torch.testing.assert_close(jets, reference_jets(field, xi), rtol=1e-12, atol=1e-11)


@pytest.mark.parametrize(("degree", "periodic", "spans"), CASES[:3])
def test_jets_match_central_differences(degree, periodic, spans):
    field = random_field(degree, periodic, spans)
    xi = points(50)
    jets = field.jets(xi)
    delta = 1e-6
    # Along ξ_d: the value gives channel 1 + d, the same first derivative the pure second
    # derivative (channel 3 or 5), the other first derivative the mixed one (channel 4).
    for d, pure, other in ((0, 3, 2), (1, 5, 1)):
        step = torch.zeros(2, dtype=F64)
        step[d] = delta
        diff = (field.jets(xi + step) - field.jets(xi - step)) / (2 * delta)
        torch.testing.assert_close(diff[:, 0], jets[:, 1 + d], rtol=1e-6, atol=1e-6)
        # The corners sit on knots, where the third derivative jumps: an O(δ/h³) error.
        torch.testing.assert_close(diff[:, 1 + d], jets[:, pure], rtol=1e-6, atol=1e-4)
        torch.testing.assert_close(diff[:, other], jets[:, 4], rtol=1e-6, atol=1e-4)


@pytest.mark.parametrize(("degree", "periodic", "spans"), CASES)
def test_partition_of_unity(degree, periodic, spans):
    field = random_field(degree, periodic, spans)
    field.coefficients.fill_(1.0)
    jets = field.jets(points(200))
    torch.testing.assert_close(jets[:, 0], torch.ones_like(jets[:, 0]), rtol=0, atol=1e-13)
    torch.testing.assert_close(jets[:, 1:], torch.zeros_like(jets[:, 1:]), rtol=0, atol=1e-11)


def test_a_linear_function_is_reproduced_exactly():
    # Greville abscissae: coefficient j of an open uniform spline sits at lo + (j + 1 − (p+1)/2)h.
    for degree in (3, 4):
        field = random_field(degree, (False, False), (3, 5))
        config = field.config
        (lo1, _), (lo2, _) = config.domain
        h1, h2 = config.spacing
        m1, m2 = config.coefficient_counts
        g1 = lo1 + (torch.arange(m1, dtype=F64) + 1 - (degree + 1) / 2) * h1
        g2 = lo2 + (torch.arange(m2, dtype=F64) + 1 - (degree + 1) / 2) * h2
        field.coefficients[:, 0] = (2 * g1[:, None] - 3 * g2[None, :]).reshape(-1)
        xi = points(100)
        jets = field.jets(xi)
        torch.testing.assert_close(jets[:, 0, 0], 2 * xi[:, 0] - 3 * xi[:, 1], rtol=0,
                                   atol=1e-12)
        torch.testing.assert_close(jets[:, 1, 0], torch.full_like(xi[:, 0], 2.0), rtol=0,
                                   atol=1e-11)


@pytest.mark.parametrize("degree", [3, 4])
def test_periodic_direction_is_continuous_across_the_seam(degree):
    field = random_field(degree, (True, True), (5, 3))
    (lo1, hi1), (lo2, hi2) = DOMAIN
    t = torch.linspace(lo2, hi2, 7, dtype=F64)
    at_lo = field.jets(torch.stack((torch.full_like(t, lo1), t), dim=1))
    at_hi = field.jets(torch.stack((torch.full_like(t, hi1), t), dim=1))
    torch.testing.assert_close(at_lo, at_hi, rtol=1e-12, atol=1e-11)
    s = torch.linspace(lo1, hi1, 7, dtype=F64)
    at_lo = field.jets(torch.stack((s, torch.full_like(s, lo2)), dim=1))
    at_hi = field.jets(torch.stack((s, torch.full_like(s, hi2)), dim=1))
    torch.testing.assert_close(at_lo, at_hi, rtol=1e-12, atol=1e-11)
    # A whole period away is the same point.
    xi = points(50)
    shifted = xi + torch.tensor([hi1 - lo1, -(hi2 - lo2)], dtype=F64)
    torch.testing.assert_close(field.jets(shifted), field.jets(xi), rtol=1e-11, atol=1e-10)


def test_evaluate_matches_jets_in_any_chunks_and_keeps_no_state():
    field = random_field(3, (True, False), (5, 2))
    xi = points(101)
    jets = field.jets(xi)
    field.evaluate(points(7, seed=5))  # must not replace the tape
    values, first = field.evaluate(xi, derivatives=True, chunk=16)
    # Kernels for 1, 3 and 6 channels may round differently (fused multiply-adds).
    torch.testing.assert_close(values, jets[:, 0], rtol=1e-13, atol=1e-14)
    torch.testing.assert_close(first, jets[:, 1:3], rtol=1e-13, atol=1e-14)
    torch.testing.assert_close(field.evaluate(xi, chunk=1000), jets[:, 0], rtol=1e-13,
                               atol=1e-14)
    grad = torch.randn(jets.shape, dtype=F64)
    field.backward(grad)
    expected = dense_jacobian(field, xi).T @ grad.reshape(-1, 3)
    torch.testing.assert_close(field.gradients[0], expected, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="chunk"):
        field.evaluate(xi, chunk=0)


def test_input_errors():
    field = random_field(3, (False, False), (2, 2))
    with pytest.raises(ValueError, match="no conditioning"):
        field.jets(points(3), torch.zeros(7, 1, dtype=F64))
    with pytest.raises(ValueError, match=r"shape \(N, 2\)"):
        field.jets(torch.zeros(4, 3, dtype=F64))
    with pytest.raises(RuntimeError, match="preceding jets"):
        SplineField(field.config).backward(torch.zeros(1, 6, 3, dtype=F64))
    field.jets(points(3))
    with pytest.raises(ValueError, match="grad_jets must have shape"):
        field.backward(torch.zeros(8, 6, 3, dtype=F64))
    assert field.jets(torch.zeros(0, 2, dtype=F64)).shape == (0, 6, 3)


# ---------------------------------------------------------------- refinement
@pytest.mark.parametrize(("degree", "periodic", "spans"), CASES)
def test_refinement_reproduces_the_function_exactly(degree, periodic, spans):
    field = random_field(degree, periodic, spans, domain=((0.0, 1.0), (0.0, 1.0)))
    xi = points(400, domain=((0.0, 1.0), (0.0, 1.0)))
    coarse = field.jets(xi)
    fine = field.refined()
    assert fine.config.spans == (2 * spans[0], 2 * spans[1])
    finer = fine.refined()
    # Per channel (second derivatives scale as 1/h²); one span periodic: constant, d2 = 0.
    scale = coarse.abs().amax(dim=(0, 2), keepdim=True).clamp(min=1.0)
    for refined in (fine, finer):
        assert ((refined.jets(xi) - coarse).abs() / scale).max() <= 1e-12
    p = field.prolongation()
    assert p.shape == (fine.config.num_coefficients, field.config.num_coefficients)
    assert p.is_sparse
    # Each coarse function is a combination of fine ones with weights Σ 2⁻ᵖ C(p+1, r) = 2;
    # open directions drop fine functions without support in the domain.
    column_sums = torch.sparse.sum(p, dim=0).to_dense()
    assert float(column_sums.max()) == 4.0
    torch.testing.assert_close(torch.sparse.mm(p, field.coefficients), fine.coefficients,
                               rtol=0, atol=0)


def test_cubic_refinement_masks_are_the_textbook_ones():
    field = SplineField(SplineConfig(spans=(4, 1), periodic=(True, True)))
    p = field.prolongation().to_dense()
    # Fine coefficients along ξ¹: midpoint averages (c_i + c_{i+1})/2 and vertex masks
    # (1, 6, 1)/8; along ξ² one periodic span becomes two with the same (constant) value.
    assert p.shape == (16, 4)
    rows = [tuple(sorted(r.tolist())) for r in p]
    assert rows.count((0.0, 0.0, 0.5, 0.5)) == 8
    assert rows.count((0.0, 0.125, 0.125, 0.75)) == 8


# ---------------------------------------------------------------- backward
@pytest.mark.parametrize(("degree", "periodic", "spans"), CASES)
def test_backward_is_the_adjoint_of_the_dense_jacobian(degree, periodic, spans):
    field = random_field(degree, periodic, spans)
    xi = points(120)
    jets = field.jets(xi)
    jac = dense_jacobian(field, xi)
    torch.testing.assert_close((jac @ field.coefficients).view(-1, 6, 3), jets, rtol=1e-12,
                               atol=1e-12)
    grad = torch.randn(jets.shape, generator=torch.Generator().manual_seed(3), dtype=F64)
    field.backward(grad)
    torch.testing.assert_close(field.gradients[0], jac.T @ grad.reshape(-1, 3), rtol=1e-12,
                               atol=1e-12)


def test_backward_matches_finite_differences_of_a_scalar():
    field = random_field(4, (True, False), (3, 2))
    xi = points(60)
    weights = torch.rand(xi.shape[0], 6, 3, generator=torch.Generator().manual_seed(4),
                         dtype=F64)

    def loss():
        return (weights * torch.sin(field.jets(xi))).sum()

    jets = field.jets(xi)
    field.backward(weights * torch.cos(jets))
    gradient = field.gradients[0].clone()
    flat = field.get_flat()
    delta = 1e-6
    for i in torch.randperm(flat.numel(), generator=torch.Generator().manual_seed(5))[:12]:
        step = torch.zeros_like(flat)
        step[i] = delta
        field.set_flat(flat + step)
        plus = loss()
        field.set_flat(flat - step)
        minus = loss()
        fd = (plus - minus) / (2 * delta)
        assert float(fd) == pytest.approx(float(gradient.view(-1)[i]), rel=1e-7, abs=1e-8)
    field.set_flat(flat)


def test_backward_refers_to_the_last_jets_call_of_any_size():
    field = random_field(3, (False, False), (3, 3))
    grad = torch.randn(40, 6, 3, generator=torch.Generator().manual_seed(8), dtype=F64)
    for xi in (points(36, seed=1), points(36, seed=2), points(20, seed=3), points(36, seed=4)):
        jets = field.jets(xi)  # the tape's buffers are reused while N stays the same
        torch.testing.assert_close(jets, reference_jets(field, xi), rtol=1e-12, atol=1e-11)
        field.backward(grad[: len(xi)])
        expected = dense_jacobian(field, xi).T @ grad[: len(xi)].reshape(-1, 3)
        torch.testing.assert_close(field.gradients[0], expected, rtol=1e-12, atol=1e-12)


def test_backward_is_deterministic():
    field = random_field(3, (False, False), (6, 6))
    xi = points(5000)
    grad = torch.randn(xi.shape[0], 6, 3, generator=torch.Generator().manual_seed(6), dtype=F64)
    field.jets(xi)
    field.backward(grad)
    first = field.gradients[0].clone()
    field.backward(grad)
    assert torch.equal(first, field.gradients[0])


# ---------------------------------------------------------------- state, dtypes, checkpoints
def test_parameters_state_dict_and_flat_vectors():
    field = random_field(3, (False, True), (2, 3))
    assert field.parameter_names == ["coefficients"]
    assert field.num_parameters == 5 * 3 * 3
    assert SplineField(field.config).get_flat().abs().max() == 0  # starts undeformed
    other = SplineField(field.config)
    other.load_state_dict(field.state_dict())
    xi = points(20)
    assert torch.equal(other.jets(xi), field.jets(xi))
    other.set_flat(2 * field.get_flat())
    torch.testing.assert_close(other.jets(xi), 2 * field.jets(xi), rtol=1e-14, atol=0)
    with pytest.raises(ValueError, match="shape"):
        other.load_state_dict({"coefficients": torch.zeros(3, 3, dtype=F64)})
    with pytest.raises(ValueError, match="missing"):
        other.load_state_dict({})


@pytest.mark.parametrize("degree", [3, 4])
def test_float32_agrees_with_float64(degree):
    f64 = random_field(degree, (True, False), (6, 4))
    f32 = SplineField(f64.config, dtype=torch.float32)
    f32.load_state_dict(f64.state_dict())
    xi = points(500)
    jets64 = f64.jets(xi)
    jets32 = f32.jets(xi)
    assert jets32.dtype == torch.float32
    scale = jets64.abs().amax(dim=(0, 2), keepdim=True)
    assert ((jets32.double() - jets64).abs() / scale).max() < 1e-5
    grad = torch.randn(jets64.shape, generator=torch.Generator().manual_seed(7), dtype=F64)
    f64.backward(grad)
    f32.backward(grad.float())
    g64 = f64.gradients[0]
    assert ((f32.gradients[0].double() - g64).abs().max() / g64.abs().max()) < 1e-5


def test_checkpoint_round_trip_with_adam(tmp_path):
    field = random_field(4, (True, False), (3, 2))
    adam = Adam(field.parameters, field.gradients, config=AdamConfig(lr=1e-2))
    xi = points(40)
    for _ in range(3):
        field.backward(field.jets(xi))
        adam.step()
    path = save_checkpoint(tmp_path / "ckpt.pt", field, adam, extra={"iteration": 3})
    assert torch.load(path, weights_only=True)["field_type"] == "spline"
    loaded = load_checkpoint(path)
    assert isinstance(loaded.field, SplineField) and loaded.field.config == field.config
    assert torch.equal(loaded.field.jets(xi), field.jets(xi))
    other = SplineField(field.config)
    other_adam = Adam(other.parameters, other.gradients, config=AdamConfig(lr=1e-2))
    load_checkpoint(path, other, optimiser=other_adam)
    for f, a in ((field, adam), (other, other_adam)):
        f.backward(f.jets(xi))
        a.step()
    assert torch.equal(other.get_flat(), field.get_flat())
    coarser = SplineField(SplineConfig(spans=(2, 2), degree=4, domain=DOMAIN,
                                       periodic=(True, False)))
    with pytest.raises(ValueError, match=r"spans: checkpoint \(3, 2\), field \(2, 2\)"):
        load_checkpoint(path, coarser)


def test_checkpoint_refuses_a_field_of_the_other_type(tmp_path):
    from taichi_ndf.field import FieldConfig, NeuralField

    path = save_checkpoint(tmp_path / "ckpt.pt", random_field(3, (False, False), (2, 2)))
    with pytest.raises(ValueError, match="field type: checkpoint SplineConfig"):
        load_checkpoint(path, NeuralField(FieldConfig(width=4, hidden_layers=1)))


def test_basis_has_the_documented_size():
    for degree in (3, 4):
        field = random_field(degree, (False, False), (2, 2))
        index, basis = field.local_basis(points(9))
        assert index.dtype == torch.int64 and index.shape == (13, (degree + 1) ** 2)
        assert basis.shape == (13, 6, (degree + 1) ** 2)
        assert int(index.min()) >= 0
        assert int(index.max()) < field.config.num_coefficients
        assert math.isclose(float(basis[:, 0].sum(1).mean()), 1.0, rel_tol=1e-13)


# ---------------------------------------------------------------- outputs and ndf-export
def test_export_of_a_spline_checkpoint_at_any_resolution(tmp_path):
    import numpy as np

    from taichi_ndf.app.outputs import deformed_mesh
    from taichi_ndf.cli import export
    from taichi_ndf.scene.reader import load_scene

    scene_path = ROOT / "scenes" / "napkin.toml"  # a free pin: the field is also read at ξ₀
    scene = load_scene(scene_path)
    domain = scene.model.surface.domain
    field = random_field(3, domain.periodic, (4, 4), domain=domain.bounds)
    field.coefficients.mul_(0.01)
    path = save_checkpoint(tmp_path / "ckpt.pt", field,
                           extra={"scene": scene.document, "scene_dir": str(scene_path.parent)})
    meshes = {}
    for resolution in (8, 32):
        out = tmp_path / f"mesh{resolution}.obj"
        assert export.main([str(path), "--resolution", str(resolution), "--out", str(out),
                            "--precision", "f64"]) == 0
        meshes[resolution] = np.loadtxt([ln for ln in out.read_text().splitlines()
                                         if ln.startswith("v ")], usecols=(1, 2, 3))
    expected = deformed_mesh(scene.model, field, (32, 32))
    np.testing.assert_allclose(meshes[32], expected.deformed, rtol=0, atol=1e-8)  # OBJ digits
    xi = torch.from_numpy(expected.xi)
    np.testing.assert_allclose(expected.deformed - expected.reference,
                               scene.model.displacement(field, xi).numpy(), rtol=0, atol=1e-14)
    i, j = np.meshgrid(np.arange(9), np.arange(9))
    shared = (4 * j * 33 + 4 * i).ravel()  # grid vertex (i, j) is j (n + 1) + i
    np.testing.assert_allclose(meshes[32][shared], meshes[8], rtol=0, atol=1e-8)


def test_adam_solver_runs_unchanged_on_a_spline_field(tmp_path):
    import dataclasses

    from taichi_ndf.minimise.callbacks import CheckpointWriter
    from taichi_ndf.scene.reader import load_scene
    from taichi_ndf.solve.solver import Solver

    scene = load_scene(ROOT / "scenes" / "napkin.toml")
    domain = scene.model.surface.domain
    field = SplineField(SplineConfig(spans=(4, 4), domain=domain.bounds,
                                     periodic=domain.periodic))
    config = dataclasses.replace(scene.quick_solver.with_iterations(40), progress=False,
                                 samples=512, monitor_every=20, monitor_samples=1024,
                                 lbfgs_iterations=0, newton_iterations=0)
    solver = Solver(scene.model, field, config)
    result = solver.run(callbacks=[CheckpointWriter(tmp_path / "ckpt.pt")])
    energies = [record.energy for record in result.history]
    assert energies[-1] < energies[0] < 1e-12  # a hanging napkin: Π falls below 0 from 0
    assert isinstance(load_checkpoint(tmp_path / "ckpt.pt").field, SplineField)
