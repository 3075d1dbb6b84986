from pathlib import Path

import numpy as np
import pytest
import torch

from taichi_ndf import jets
from taichi_ndf.geometry.mesh_surface import MeshSurface

DATA = Path(__file__).resolve().parents[1] / "data"
BOWL_RADIUS = 1.5  # data/make_templates.py


def read_obj(path):
    """Positions, UVs and faces of an OBJ written as 'f a/a b/b c/c', in file order."""
    v, vt, f = [], [], []
    for line in Path(path).read_text().splitlines():
        head, *rest = line.split() or [""]
        if head == "v":
            v.append([float(x) for x in rest])
        elif head == "vt":
            vt.append([float(x) for x in rest])
        elif head == "f":
            f.append([int(x.split("/")[0]) - 1 for x in rest])
    return np.array(v), np.array(vt), np.array(f)


def write_obj(path, vertices, uv, faces):
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in vertices.tolist()]
    if uv is not None:
        lines += [f"vt {a!r} {b!r}" for a, b in uv.tolist()]
        lines += [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in faces]
    else:
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")
    return path


def small_sheet(n=4):
    """A flat n × n vertex grid on [0, 1]² with UV = (x, y): positions, UVs, faces."""
    s, t = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="ij")
    uv = np.stack((s.ravel(), t.ravel()), 1)
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
            faces += [(a, b, c), (a, c, d)]
    return np.column_stack((uv, np.zeros(len(uv)))), uv, np.array(faces)


def random_uv(n, lo=0.0, hi=1.0, seed=0):
    gen = torch.Generator().manual_seed(seed)
    return lo + (hi - lo) * torch.rand(n, 2, dtype=torch.float64, generator=gen)


@pytest.mark.parametrize("name", ["napkin", "napkin_alt", "flag", "bowl"])
def test_templates_load_in_file_order(name):
    surface = MeshSurface.from_file(DATA / f"{name}.obj")
    v, vt, f = read_obj(DATA / f"{name}.obj")
    assert np.array_equal(surface.vertices.numpy(), v)
    assert np.array_equal(surface.uv.numpy(), vt)
    assert np.array_equal(surface.faces.numpy(), f)


@pytest.mark.parametrize(
    ("name", "tangents"),
    [
        ("napkin", ((1.0, 0, 0), (0, 1.0, 0))),
        ("napkin_alt", ((1.0, 0, 0), (0, 1.0, 0))),
        ("flag", ((1.5, 0, 0), (0, 1.0, 0))),
    ],
)
def test_flat_templates_are_reproduced_exactly(name, tangents):
    surface = MeshSurface.from_file(DATA / f"{name}.obj")
    assert surface.fit_error_max < 1e-12
    assert surface.domain.inside is None and surface.domain.area == pytest.approx(1.0, abs=1e-12)
    xi = random_uv(500)
    r = surface.jets(xi)
    expected = torch.zeros_like(r)
    expected[:, jets.VALUE] = xi @ torch.tensor(tangents, dtype=torch.float64)
    expected[:, jets.D1] = torch.tensor(tangents[0], dtype=torch.float64)
    expected[:, jets.D2] = torch.tensor(tangents[1], dtype=torch.float64)
    # Round-off, amplified by 1/h² in the second derivatives.
    torch.testing.assert_close(r[:, :3], expected[:, :3], rtol=0, atol=1e-10)
    torch.testing.assert_close(r[:, 3:], expected[:, 3:], rtol=0, atol=1e-8)


def test_fit_does_not_depend_on_the_triangulation():
    xi = random_uv(500, seed=1)
    regular = MeshSurface.from_file(DATA / "napkin.obj").jets(xi)
    irregular = MeshSurface.from_file(DATA / "napkin_alt.obj").jets(xi)
    torch.testing.assert_close(regular[:, :3], irregular[:, :3], rtol=0, atol=1e-11)
    torch.testing.assert_close(regular[:, 3:], irregular[:, 3:], rtol=0, atol=1e-9)


def test_bowl_fit_matches_the_sphere():
    surface = MeshSurface.from_file(DATA / "bowl.obj")
    # Measured: max 5.5e-8 m, rms 1.7e-8 m at the vertices (20 x 20 cells).
    assert surface.fit_error_max < 1e-6 and surface.fit_error_rms < 1e-7
    xi = random_uv(400, 0.1, 0.9, seed=2)
    r = surface.jets(xi)
    x, y = xi[:, 0] - 0.5, xi[:, 1] - 0.5
    z = BOWL_RADIUS - torch.sqrt(BOWL_RADIUS**2 - x**2 - y**2)
    assert (r[:, jets.VALUE] - torch.stack((x, y, z), 1)).abs().max() < 1e-6
    # Curvature of a sphere: K = 1/R², H = 1/R (measured: 6e-4 and 3e-4 relative).
    a1, a2 = r[:, jets.D1], r[:, jets.D2]
    normal = torch.linalg.cross(a1, a2)
    normal = normal / normal.norm(dim=1, keepdim=True)

    def form(u, v):
        return (u * v).sum(1)

    metric = torch.stack((form(a1, a1), form(a1, a2), form(a1, a2), form(a2, a2)), 1).view(-1, 2, 2)
    second = torch.stack(
        [form(r[:, k], normal) for k in (jets.D11, jets.D12, jets.D12, jets.D22)], 1
    ).view(-1, 2, 2)
    gauss = torch.linalg.det(second) / torch.linalg.det(metric)
    mean = 0.5 * torch.einsum("nab,nba->n", torch.linalg.inv(metric), second)
    assert (gauss * BOWL_RADIUS**2 - 1).abs().max() < 2e-3
    assert (mean * BOWL_RADIUS - 1).abs().max() < 1e-3


def test_jets_are_the_derivatives_of_the_fit():
    surface = MeshSurface.from_file(DATA / "bowl.obj")
    xi = random_uv(50, seed=3).requires_grad_(True)
    r = surface.jets(xi)
    for c in range(3):
        (g,) = torch.autograd.grad(r[:, jets.VALUE, c].sum(), xi, create_graph=True)
        (h1,) = torch.autograd.grad(g[:, 0].sum(), xi, retain_graph=True)
        (h2,) = torch.autograd.grad(g[:, 1].sum(), xi, retain_graph=True)
        expected = torch.stack((g[:, 0], g[:, 1], h1[:, 0], h1[:, 1], h2[:, 1]), 1)
        torch.testing.assert_close(r[:, 1:, c], expected, rtol=1e-12, atol=1e-12)


def test_masked_chart(tmp_path):
    vertices, uv, faces = small_sheet(5)
    # Remove the triangles of the upper-right quarter (an L-shaped chart) and the vertices
    # no triangle uses any more.
    faces = faces[uv[faces].mean(axis=1).min(axis=1) < 0.5]
    used, faces = np.unique(faces, return_inverse=True)
    path = write_obj(tmp_path / "l.obj", vertices[used], uv[used], faces.reshape(-1, 3))
    surface = MeshSurface.from_file(path)
    domain = surface.domain
    assert domain.inside is not None and domain.area == pytest.approx(0.75, rel=1e-12)
    inside = domain.contains(torch.tensor([[0.25, 0.25], [0.75, 0.75], [0.5, 0.75], [1.0, 0.5]]))
    assert inside.tolist() == [True, False, True, True]
    samples = domain.sample(400, torch.Generator().manual_seed(0))
    assert not ((samples[:, 0] > 0.5) & (samples[:, 1] > 0.5)).any()
    assert surface.fit_error_max < 1e-12


def test_ply_with_uvs_loads(tmp_path):
    vertices, uv, faces = small_sheet(4)
    header = [
        "ply",
        "format ascii 1.0",
        f"element vertex {len(vertices)}",
        "property double x",
        "property double y",
        "property double z",
        "property double s",
        "property double t",
        f"element face {len(faces)}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    body = [f"{x} {y} {z} {s} {t}" for (x, y, z), (s, t) in zip(vertices, uv, strict=True)]
    body += [f"3 {a} {b} {c}" for a, b, c in faces]
    path = tmp_path / "sheet.ply"
    path.write_text("\n".join(header + body) + "\n")
    surface = MeshSurface.from_file(path)
    assert np.array_equal(surface.vertices.numpy(), vertices)
    assert np.array_equal(surface.uv.numpy(), uv)
    assert surface.fit_error_max < 1e-12


def broken(kind):
    vertices, uv, faces = small_sheet(4)
    if kind == "no UV":
        uv = None
    elif kind == "NaN":
        vertices[5, 2] = np.nan
    elif kind == "degenerate":
        uv[5] = uv[4]  # vertices 4 and 5 share a UV: their triangles collapse
    elif kind == "flipped":
        uv[5] = (0.8, 0.2)  # an interior vertex pushed across the edge between 4 and 9
    elif kind == "non-manifold":
        # A fin: a third triangle on the interior edge 5–10, with its own vertex.
        vertices = np.vstack((vertices, [0.5, 0.5, 0.3]))
        uv = np.vstack((uv, [0.45, 0.6]))
        faces = np.vstack((faces, [5, 10, 16]))
    elif kind == "overlap":
        # A second, lifted copy of the sheet on the same UVs.
        faces = np.vstack((faces, faces + len(vertices)))
        vertices = np.vstack((vertices, vertices + [0, 0, 0.1]))
        uv = np.vstack((uv, uv))
    return vertices, uv, faces


@pytest.mark.parametrize(
    ("kind", "message"),
    [
        ("no UV", "no UV coordinates"),
        ("NaN", "non-finite"),
        ("degenerate", "degenerate UV triangles"),
        ("flipped", "flipped UV triangles"),
        ("non-manifold", "non-manifold edges"),
        ("overlap", "overlapping UV triangles"),
    ],
)
def test_invalid_meshes_are_refused(tmp_path, kind, message):
    vertices, uv, faces = broken(kind)
    path = write_obj(tmp_path / f"{kind.replace(' ', '_')}.obj", vertices, uv, faces)
    with pytest.raises(ValueError, match=message):
        MeshSurface.from_file(path)


def test_missing_file_is_reported(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        MeshSurface.from_file(tmp_path / "absent.obj")
