"""One run of NVIDIA Newton's cloth (VBD) for benchmarks/dynamics_peer.py, in Newton's own
Python environment (warp-lang, newton; not the project's): reads a JSON job, writes a JSON result.

    /path/to/newton-venv/bin/python benchmarks/dynamics_peer_newton.py JOB.json RESULT.json

The job: a rectangle [x0, x0 + Lx] × [y0, y0 + Ly] in the plane z = 0 as
`ModelBuilder.add_cloth_grid` cells (nx × ny, each cell two triangles), lumped masses ρ_A × ⅓ of
the rest area of the triangles at each vertex [kg], the first `fixed_columns` columns of
vertices (x = x0, x0 + Δx, …) held (1: a hinge, the sheet turns freely about the held line; 2: a
clamp), gravity g [m/s²], the membrane's Lamé constants per area μ = tri_ke, λ = tri_ka [N/m]
(Newton's stable Neo-Hookean triangle, whose linearisation at rest is the plane-stress law with
these Lamé constants), the dihedral-angle bending stiffness edge_ke [N] (energy ½ edge_ke |e| θ²
per interior edge of rest length |e|), no damping (tri_kd = edge_kd = 0), `steps` steps of dt
[s] with `iterations` VBD iterations each (VBD's implicit Euler; no contact).

With `wind` (velocity U [m/s], gust_amplitude a, gust_frequency f [Hz], air_density ρ_air
[kg/m³], drag_coefficient C_d) the project's wind law (taichi_ndf/problem/wind.py) acts on the
cloth as external per-particle forces, recomputed before every step from the step's start
(`wind_forces`: per triangle its current normal and area, the mean of its vertices' velocities,
the air at the step's end w(t + dt) = U (1 + a sin(2π f (t + dt))), the pressure ½ ρ_air C_d s|s|
on s = (w − v)·n, a third of the triangle's force to each vertex). VBD reads them in its
inertial prediction (`state.particle_f`, forward_step: v + (g + f/m) dt), so the drag is
explicit in the velocity (ours is implicit in it: objective/wind.py).

The result: per step the time [s], the probes' displacements [m] (the vertex nearest each
probe's reference point), the kinetic energy T = ½ Σ m |v|², the potential Π = elastic energy
(the Neo-Hookean membrane minus its value at rest, plus the dihedral springs, evaluated here
in numpy with VBD's own formulas) − Σ m g·u [J]; CPU seconds (user + sys of this process) and
wall seconds of the steps alone (the first step, which loads Warp's compiled kernels, timed
apart; the wind's forces included, and their CPU also alone); the final vertex positions.
"""

from __future__ import annotations

import json
import resource
import sys
import time

import numpy as np


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def lumped_masses(rest: np.ndarray, triangles: np.ndarray, density: float) -> np.ndarray:
    """ρ_A × ⅓ of the rest area of each vertex's triangles [kg] (V,)."""
    a = rest[triangles[:, 1]] - rest[triangles[:, 0]]
    b = rest[triangles[:, 2]] - rest[triangles[:, 0]]
    area = 0.5 * np.linalg.norm(np.cross(a, b), axis=1)
    mass = np.zeros(len(rest))
    for k in range(3):
        np.add.at(mass, triangles[:, k], density * area / 3)
    return mass


def wind_forces(x: np.ndarray, v: np.ndarray, triangles: np.ndarray, air: np.ndarray,
                air_density: float, drag_coefficient: float) -> np.ndarray:
    """Nodal wind forces [N] (V, 3) on a triangle mesh at positions x (V, 3) [m] moving at v
    (V, 3) [m/s] in air moving at `air` (3,) [m/s]: per triangle (vertices a, b, c) the unit
    normal n = (b − a) × (c − a)/|…|, its area A = ½ |(b − a) × (c − a)| [m²], the relative
    normal speed s = (w − v̄)·n with v̄ the mean of its vertices' velocities [m/s], the force
    ½ ρ_air C_d s|s| A n (the project's law, taichi_ndf/problem/wind.py, on one point per
    triangle), a third to each of its vertices. The sign of n does not matter (s and the
    force's direction flip together)."""
    a, b, c = (x[triangles[:, k]] for k in range(3))
    cross = np.cross(b - a, c - a)
    twice_area = np.linalg.norm(cross, axis=1)
    normal = cross / twice_area[:, None]
    mean_velocity = v[triangles].mean(axis=1)
    s = ((air[None, :] - mean_velocity) * normal).sum(axis=1)
    force = (0.5 * air_density * drag_coefficient * s * np.abs(s) * 0.5 * twice_area)[:, None] \
        * normal
    out = np.zeros_like(x, dtype=np.float64)
    for k in range(3):
        np.add.at(out, triangles[:, k], force / 3)
    return out


def air_velocity(wind: dict, t: float) -> np.ndarray:
    """w(t) = U (1 + a sin(2π f t)) [m/s] (3,) of the job's `wind`."""
    factor = 1.0 + wind["gust_amplitude"] * np.sin(2 * np.pi * wind["gust_frequency"] * t)
    return factor * np.asarray(wind["velocity"], dtype=np.float64)


def membrane_energy(x: np.ndarray, rest: np.ndarray, triangles: np.ndarray, mu: float,
                    lmbd: float) -> float:
    """Σ A (ψ(F) − ψ(I)) [J]: VBD's stable Neo-Hookean triangle (particle_vbd_kernels:
    ψ = μ/2 (|F|² − 2) + λ'/2 (J − α)², λ' = λ + μ, α = 1 + μ/λ', F the 3 × 2 deformation
    gradient, J = |f₀ × f₁|), less its value at rest so that the rest state has 0."""
    d1 = rest[triangles[:, 1]] - rest[triangles[:, 0]]
    d2 = rest[triangles[:, 2]] - rest[triangles[:, 0]]
    dm = np.stack([d1[:, :2], d2[:, :2]], axis=2)  # (T, 2, 2) in the rest plane z = 0
    area = 0.5 * np.abs(np.linalg.det(dm))
    dm_inv = np.linalg.inv(dm)
    ds = np.stack([x[triangles[:, 1]] - x[triangles[:, 0]],
                   x[triangles[:, 2]] - x[triangles[:, 0]]], axis=2)  # (T, 3, 2)
    f = ds @ dm_inv
    j = np.linalg.norm(np.cross(f[:, :, 0], f[:, :, 1]), axis=1)
    lam = lmbd + mu
    alpha = 1 + mu / lam
    psi = 0.5 * mu * ((f * f).sum(axis=(1, 2)) - 2) + 0.5 * lam * (j - alpha) ** 2
    psi_rest = 0.5 * lam * (1 - alpha) ** 2
    return float((area * (psi - psi_rest)).sum())


def bending_energy(x: np.ndarray, edges: np.ndarray, rest_length: np.ndarray,
                   stiffness: float) -> float:
    """Σ ½ edge_ke |e| θ² [J] over the interior edges, θ the dihedral angle as VBD computes
    it (atan2 of the unit normals' sine along the edge and cosine), rest angle 0 (flat)."""
    inner = (edges[:, 0] >= 0) & (edges[:, 1] >= 0)
    e, length = edges[inner], rest_length[inner]
    x0, x1, x2, x3 = (x[e[:, k]] for k in range(4))
    n1 = np.cross(x2 - x0, x3 - x0)
    n2 = np.cross(x3 - x1, x2 - x1)
    n1 /= np.linalg.norm(n1, axis=1, keepdims=True)
    n2 /= np.linalg.norm(n2, axis=1, keepdims=True)
    edge = x3 - x2
    edge /= np.linalg.norm(edge, axis=1, keepdims=True)
    theta = np.arctan2((np.cross(n1, n2) * edge).sum(axis=1), (n1 * n2).sum(axis=1))
    return float((0.5 * stiffness * length * theta ** 2).sum())


def bending_modes(rest: np.ndarray, edges: np.ndarray, rest_length: np.ndarray,
                  stiffness: float, bending: float, kappa: float = 1e-3) -> dict:
    """The dihedral springs' energy on the rest mesh bent by the small curvatures κ [1/m]
    of z = ½ κ x², ½ κ y² and κ x y, over the plate's ½ B (κ₁₁² + κ₂₂² + 2 κ₁₂²) × area
    (ν = 0; B = `bending` [N·m]): 1 where the mapping edge_ke = B/Δ is exact."""
    x, y = rest[:, 0] - rest[:, 0].min(), rest[:, 1] - rest[:, 1].min()
    area = x.max() * y.max()
    out = {}
    for name, z, plate in (("x", 0.5 * kappa * x * x, 0.5 * bending * kappa ** 2),
                           ("y", 0.5 * kappa * y * y, 0.5 * bending * kappa ** 2),
                           ("twist", kappa * x * y, bending * kappa ** 2)):
        bent = rest.copy()
        bent[:, 2] = z
        out[name] = bending_energy(bent, edges, rest_length, stiffness) / (plate * area)
    return out


def run(job: dict) -> dict:
    import newton
    import warp as wp

    wp.config.quiet = True
    nx, ny = job["cells"]
    lx, ly = job["size"]
    builder = newton.ModelBuilder(gravity=tuple(job["gravity"]))
    builder.add_cloth_grid(pos=wp.vec3(job["x0"], job["y0"], 0.0), rot=wp.quat_identity(),
                           vel=wp.vec3(0.0, 0.0, 0.0), dim_x=nx, dim_y=ny, cell_x=lx / nx,
                           cell_y=ly / ny, mass=1.0, fix_left=True, tri_ke=job["tri_ke"],
                           tri_ka=job["tri_ka"], tri_kd=0.0, edge_ke=job["edge_ke"],
                           edge_kd=0.0)
    rest = np.array(builder.particle_q, dtype=np.float64)
    triangles = np.array(builder.tri_indices, dtype=np.int64)
    mass = lumped_masses(rest, triangles, job["areal_density"])
    held = rest[:, 0] < job["x0"] + (job["fixed_columns"] - 0.5) * lx / nx
    for i in range(len(rest)):
        builder.particle_mass[i] = 0.0 if held[i] else float(mass[i])
        if held[i]:
            builder.particle_flags[i] &= ~int(newton.ParticleFlags.ACTIVE)
    builder.color(include_bending=True)
    model = builder.finalize(device="cpu")
    solver = newton.solvers.SolverVBD(model, iterations=job["iterations"])
    state, scratch, control = model.state(), model.state(), model.control()
    edges = model.edge_indices.numpy().astype(np.int64)
    rest_length = model.edge_rest_length.numpy().astype(np.float64)
    probes = {name: int(np.argmin(np.linalg.norm(rest - np.array(point), axis=1)))
              for name, point in job["probes"].items()}
    g = np.array(job["gravity"], dtype=np.float64)
    free_mass = np.where(held, 0.0, mass)
    dt = job["dt"]
    wind = job.get("wind")
    positions, velocities = [rest.copy()], [np.zeros_like(rest)]
    first_cpu = first_wall = 0.0
    cpu = wall = wind_cpu = 0.0
    for k in range(job["steps"]):
        c0, w0 = cpu_seconds(), time.perf_counter()
        state.clear_forces()
        if wind is not None:
            force = wind_forces(positions[-1], velocities[-1], triangles,
                                air_velocity(wind, (k + 1) * dt), wind["air_density"],
                                wind["drag_coefficient"])
            state.particle_f.assign(force.astype(np.float32))
            wind_cpu += cpu_seconds() - c0
        solver.step(state, scratch, control, None, dt)
        state, scratch = scratch, state
        q = state.particle_q.numpy()  # the step is done once its result is read back
        c1, w1 = cpu_seconds(), time.perf_counter()
        if k == 0:
            first_cpu, first_wall = c1 - c0, w1 - w0
        else:
            cpu, wall = cpu + c1 - c0, wall + w1 - w0
        positions.append(q.astype(np.float64))
        velocities.append(state.particle_qd.numpy().astype(np.float64))
    kinetic, potential = [], []
    for x, v in zip(positions, velocities, strict=True):
        kinetic.append(float(0.5 * (free_mass * (v * v).sum(axis=1)).sum()))
        potential.append(membrane_energy(x, rest, triangles, job["tri_ke"], job["tri_ka"])
                         + bending_energy(x, edges, rest_length, job["edge_ke"])
                         - float((free_mass * ((x - rest) @ g)).sum()))
    steps = max(1, job["steps"] - 1)
    return {"times": [dt * k for k in range(job["steps"] + 1)],
            "probes": {name: [(x[i] - rest[i]).tolist() for x in positions]
                       for name, i in probes.items()},
            "probe_points": {name: rest[i].tolist() for name, i in probes.items()},
            "kinetic": kinetic, "potential": potential,
            "total": [a + b for a, b in zip(kinetic, potential, strict=True)],
            "first_step_cpu_seconds": first_cpu, "first_step_wall_seconds": first_wall,
            "cpu_per_step": cpu / steps, "wall_per_step": wall / steps,
            "wind_cpu_per_step": wind_cpu / job["steps"],
            "particles": int(model.particle_count), "triangles": int(model.tri_count),
            "edges": int(model.edge_count), "held": int(held.sum()), "mass": float(mass.sum()),
            "bending_modes": bending_modes(rest, edges, rest_length, job["edge_ke"],
                                           job["bending_stiffness"]),
            "final": positions[-1].tolist(), "rest": rest.tolist(),
            "newton_version": newton.__version__, "warp_version": wp.config.version}


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: dynamics_peer_newton.py JOB.json RESULT.json")
    with open(sys.argv[1]) as f:
        job = json.load(f)
    with open(sys.argv[2], "w") as f:
        json.dump(run(job), f)
