"""benchmarks/dynamics_peer.py (issue 29's NVIDIA Newton peer) without a long run: the material
mapping, the energies it evaluates for Newton's cloth (numpy only: VBD's formulas), our scene
it writes being a valid scene, bad input refused in one line, and one short Newton run where
newton is importable (skipped otherwise: it lives in its own environment, NEWTON_PYTHON)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.scripts import load_script

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benchmarks"


def _module(name: str):
    return load_script(f"benchmarks/{name}.py")


def test_material_mapping_and_strip_load():
    peer = _module("dynamics_peer")
    vbd = peer.vbd_material(0.02)
    # ν = 0: μ = D/2, λ = 0, so the plane-stress modulus λ + 2μ is D; edge_ke = B/Δ.
    assert vbd["tri_ke"] + 2 * vbd["tri_ka"] == pytest.approx(peer.MEMBRANE / 2)
    assert 2 * vbd["tri_ke"] + vbd["tri_ka"] == pytest.approx(peer.MEMBRANE)
    assert vbd["edge_ke"] == pytest.approx(peer.BENDING / 0.02)
    g = peer.strip_gravity()
    length = peer.STRIP["bounds"][0][1]
    assert peer.DENSITY * g * length ** 4 / (8 * peer.BENDING) == pytest.approx(
        peer.STRIP_SAG * length)


def test_newton_energies_match_the_linear_laws():
    """The membrane energy evaluated for VBD's Neo-Hookean triangle is the plane-stress
    energy ½ (λ + 2μ) ε² A of a small uniaxial stretch ε, 0 at rest; the dihedral spring's is
    ½ k |e| θ² of a hinge folded by θ."""
    newton_side = _module("dynamics_peer_newton")
    rest = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    triangles = np.array([[0, 1, 2], [0, 2, 3]])
    mu, lmbd, eps = 2000.0, 300.0, 1e-5
    assert newton_side.membrane_energy(rest, rest, triangles, mu, lmbd) == pytest.approx(
        0.0, abs=1e-12)
    stretched = rest * [1 + eps, 1.0, 1.0]  # ε₁₁ = ε, ε₂₂ = 0 (laterally held)
    energy = newton_side.membrane_energy(stretched, rest, triangles, mu, lmbd)
    assert energy == pytest.approx(0.5 * (lmbd + 2 * mu) * eps ** 2 * 1.0, rel=1e-3)
    # Two triangles on the edge (0,0,0)-(0,1,0), opposite vertices on either side; the second
    # turned by θ about the edge.
    theta = 0.3
    hinge = np.array([[-1.0, 0.5, 0.0], [np.cos(theta), 0.5, np.sin(theta)],
                      [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    edges = np.array([[0, 1, 2, 3], [-1, 0, 2, 3]])  # the second: a boundary edge, skipped
    energy = newton_side.bending_energy(hinge, edges, np.array([1.0, 1.0]), 0.7)
    assert energy == pytest.approx(0.5 * 0.7 * 1.0 * theta ** 2, rel=1e-9)


def test_our_scene_is_a_valid_dynamic_scene(tmp_path):
    from taichi_ndf.scene.reader import load_scene

    peer = _module("dynamics_peer")
    path = tmp_path / "flag.toml"
    path.write_text(peer.scene_text("peer_flag", peer.FLAG, (0.0, -9.81, 0.0), "hinged_edge",
                                    (0.01, 1.0)))
    scene = load_scene(path)
    assert scene.dynamics.dt == 0.01 and scene.dynamics.duration == 1.0
    assert scene.model.material.bending_stiffness == pytest.approx(peer.BENDING)
    assert scene.model.material.poisson_ratio == 0.0


def test_bad_cells_refused_in_one_line():
    proc = subprocess.run([sys.executable, str(BENCH / "dynamics_peer.py"), "--cells", "30",
                           "30"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "square cells" in proc.stderr


def _newton_python() -> str | None:
    python = os.environ.get("NEWTON_PYTHON", sys.executable)
    probe = subprocess.run([python, "-c", "import warp, newton"], capture_output=True)
    return python if probe.returncode == 0 else None


@pytest.mark.skipif(_newton_python() is None, reason="NVIDIA Newton (warp-lang, newton) not "
                    "importable; set NEWTON_PYTHON to an environment that has them")
def test_newton_hinged_sheet_falls_from_rest(tmp_path):
    """Three steps of the flag in VBD: the result's shape, the masses summing to ρ_A × area,
    the hinge held, and the sheet falling under gravity from rest."""
    peer = _module("dynamics_peer")
    job = peer.newton_job(peer.FLAG, (6, 4), (0.0, 0.0, -9.81), 1, 0.01, 3, 10)
    (tmp_path / "job.json").write_text(json.dumps(job))
    subprocess.run([_newton_python(), str(BENCH / "dynamics_peer_newton.py"),
                    str(tmp_path / "job.json"), str(tmp_path / "out.json")], check=True,
                   capture_output=True, timeout=1800)
    result = json.loads((tmp_path / "out.json").read_text())
    assert result["particles"] == 7 * 5 and result["held"] == 5
    assert result["mass"] == pytest.approx(peer.DENSITY * 0.6 * 0.4, rel=1e-6)
    assert len(result["times"]) == 4 and result["kinetic"][0] == 0.0
    assert result["probes"]["fly_top"][-1][2] < 0 and result["kinetic"][-1] > 0
    assert result["bending_modes"]["x"] == pytest.approx(5 / 6, rel=1e-3)


def test_newton_wind_forces_are_the_projects_wind_law_on_a_mesh():
    """The wind's nodal forces that the Newton child applies (numpy) are the project's own
    (objective/wind.py `wind_term`, problem/wind.py's law) on the same mesh at the same
    velocities: each triangle one sample point (x_,1 = b − a, x_,2 = c − a, parameter area ½),
    its velocity the mean of its vertices', the project's force at v' = v₀, a third to each
    vertex; to 1e-6 relative (float64: ~1e-15)."""
    import torch

    from taichi_ndf import jets
    from taichi_ndf.objective.wind import wind_term
    from taichi_ndf.problem.sampling import SurfaceSamples
    from taichi_ndf.problem.wind import Wind

    newton_side = _module("dynamics_peer_newton")
    rng = np.random.default_rng(7)
    gx, gy = np.meshgrid(np.linspace(0.0, 0.6, 5), np.linspace(-0.2, 0.2, 4), indexing="ij")
    x = np.stack([gx.ravel(), gy.ravel(), 0.05 * rng.standard_normal(gx.size)], axis=1)
    x[:, :2] += 0.01 * rng.standard_normal((gx.size, 2))
    v = rng.uniform(-6.0, 6.0, x.shape)  # m/s: some triangles overtake the air
    index = np.arange(gx.size).reshape(gx.shape)
    quads = [(index[i, j], index[i + 1, j], index[i + 1, j + 1], index[i, j + 1])
             for i in range(gx.shape[0] - 1) for j in range(gx.shape[1] - 1)]
    triangles = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    wind = Wind(velocity=(2.0, 0.0, 2.0), gust_amplitude=0.4, gust_frequency=1.5)
    t = 0.13
    job_wind = {"velocity": list(wind.velocity), "gust_amplitude": wind.gust_amplitude,
                "gust_frequency": wind.gust_frequency}
    air = newton_side.air_velocity(job_wind, t)
    assert air == pytest.approx(np.array(wind.at(t)), rel=1e-12)
    ours = newton_side.wind_forces(x, v, triangles, air, wind.air_density,
                                   wind.drag_coefficient)

    a, b, c = (torch.tensor(x[triangles[:, k]]) for k in range(3))
    count = len(triangles)
    r_jets = torch.zeros(count, jets.CHANNELS, 3, dtype=torch.float64)
    r_jets[:, jets.VALUE] = (a + b + c) / 3
    r_jets[:, jets.D1], r_jets[:, jets.D2] = b - a, c - a
    samples = SurfaceSamples(torch.zeros(count, 2, dtype=torch.float64), r_jets,
                             torch.full((count,), 0.5, dtype=torch.float64),
                             torch.zeros(count, 3, dtype=torch.float64))
    u_jets = torch.zeros_like(r_jets)
    velocity = torch.tensor(v[triangles].mean(axis=1))
    rate = 100.0  # k [1/s]; the origin y = −v₀/k makes the step's new velocity v' = v₀
    origin = torch.zeros_like(r_jets)
    origin[:, jets.VALUE] = -velocity / rate
    term = wind_term(wind, t, samples, u_jets, velocity, rate, origin)
    _, gradient = term.evaluate(samples, u_jets)
    per_triangle = -gradient[:, jets.VALUE].numpy()
    project = np.zeros_like(x)
    for k in range(3):
        np.add.at(project, triangles[:, k], per_triangle / 3)
    scale = np.abs(project).max()
    assert scale > 0.01  # N: the forces are not trivially small
    assert np.abs(ours - project).max() <= 1e-6 * scale
    normal = np.cross((b - a).numpy(), (c - a).numpy())
    s = ((air - v[triangles].mean(axis=1)) * normal).sum(axis=1)
    assert s.min() < 0 < s.max()  # some triangles overtake the air (the braking branch)


@pytest.mark.skipif(_newton_python() is None, reason="NVIDIA Newton (warp-lang, newton) not "
                    "importable; set NEWTON_PYTHON to an environment that has them")
def test_newton_flag_in_wind_is_pushed_by_the_drag_law(tmp_path):
    """One 10 ms step of the flag in wind in VBD from rest: the free corners, whose
    neighbours all move alike (no bending, no stretch), move along the normal by the wind's
    p/ρ_A h² (p = ½ ρ_air C_d s², s the normal air speed at t = h), i.e. the forces reach
    VBD's particles as computed; with the wind's speed doubled, four times as far."""
    peer = _module("dynamics_peer")
    lifts = []
    for scale in (1.0, 2.0):
        wind = {**peer.WIND, "velocity": [scale * c for c in peer.WIND["velocity"]]}
        job = peer.newton_job(peer.FLAG, (6, 4), (0.0, -9.81, 0.0), 1, 0.01, 1, 10, wind=wind)
        (tmp_path / "job.json").write_text(json.dumps(job))
        subprocess.run([_newton_python(), str(BENCH / "dynamics_peer_newton.py"),
                        str(tmp_path / "job.json"), str(tmp_path / "out.json")], check=True,
                       capture_output=True, timeout=1800)
        result = json.loads((tmp_path / "out.json").read_text())
        s = wind["velocity"][2] * (1 + 0.4 * np.sin(2 * np.pi * 1.5 * 0.01))
        p = 0.5 * peer.AIR_DENSITY * peer.FLAT_PLATE_DRAG * s * s
        for corner in ("fly_top", "fly_bottom"):
            lift = result["probes"][corner][-1][2]
            assert abs(lift) == pytest.approx(p / peer.DENSITY * 0.01 ** 2, rel=1e-3)
        lifts.append(abs(lift))
    assert lifts[1] == pytest.approx(4 * lifts[0], rel=1e-3)
