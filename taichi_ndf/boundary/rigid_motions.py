"""Rigid motions the supports leave free, and what acts on them: a check before a solve.

A shell held by its boundary conditions may still move rigidly. Such a model has no unique
equilibrium when something acts on the free motion, or nothing resists it:

- the loads do work on it (first order: a resultant force along a free translation, a
  resultant moment about a free axis): a free translation has no equilibrium at all, a free
  rotation turns the shell rigidly until the loads' moment vanishes;
- the loads' work on a free rotation is zero at first order but their potential falls at second
  order (self-equilibrated dead loads on a shell held at one point: the pinched hemisphere
  swings about the held point until its loads are no longer radial);
- nothing resists it at all, in any shape of the shell: no support or contact resists it and
  the loads' potential is the same along it whatever the shape (a translation they do no
  work on, a rotation about an axis along every force, e.g. about the vertical under gravity):
  a Newton solve has a singular Hessian along it, and whatever acts on it nonlinearly decides
  where the shell ends (tablecloth_box held at its centre on a frictionless table turned 45°
  about z). A tilt that is neutral only at the flat reference is not reported: a hanging
  shape makes it stable.

The free motions are the twists q = (t, ω) (velocity v(x) = t + ω × (x − c), c the centroid of
the reference surface) that every constraint admits: held components vanish on the
constraint's set, and where the factor vanishes quadratically along a curve (clamped edges,
rim rotations, interior lines that are not hinged) their derivative across the curve vanishes
too; a symmetry plane holds its odd components on the edge and the derivative across the
edge of its even ones. A point (pinned point, handle) holds its components only: the slope it
holds is a point constraint on a derivative, whose stiffness vanishes as the grid is refined
(the hemisphere held at one rim point swings more on finer grids), so it does not count as
holding a rotation. With a free pin (rotation = "free") the rotations about the pin are free by
the scene's own statement (a hanging sheet finds its orientation): only translations are
checked.

Contact resists a motion when, over the reference points closest to an obstacle (gap within
the activation distance ĝ of the smallest gap), the obstacle's normal component of the motion
averages at least CONTACT_RESISTS of its size (squared), into the obstacle for a one-sided
test. The check is linear at the reference configuration: it cannot see a motion that becomes
stiff or loaded only once the shell has deformed.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import torch

from taichi_ndf import jets
from taichi_ndf.boundary.constraints import COMPONENTS, SymmetryPlane
from taichi_ndf.boundary.resolution import _from_eta, resolve
from taichi_ndf.boundary.segments import points_along
from taichi_ndf.geometry.surface import IDENTITY_FRAME

log = logging.getLogger(__name__)

# Singular values of the (unit) constraint rows below this times the largest: a free motion.
MOTION_TOL = 1e-7
# Works and second-order works below this times the loads' scale count as none.
WORK_TOL = 1e-7
# Mean (n·v)² / |v|² over the contact points from which contact holds a motion.
CONTACT_RESISTS = 0.05
# Midpoint grid of the reference surface for the distributed loads and the contact points.
GRID = 64


@dataclass(frozen=True)
class Finding:
    """A free rigid motion and what acts on it: kind "work" (the loads do work on it),
    "second_order" (their potential falls at second order along it) or "no_stiffness";
    loads: the loads that act (work or second-order work), value: the work [J/m or J/rad] or
    the second derivative of the loads' potential [J/rad²]."""

    motion: str
    kind: str
    loads: tuple[str, ...] = ()
    value: float = 0.0

    def line(self) -> str:
        loads = " and ".join(self.loads) or "the loads"
        if self.kind == "work" and self.motion.startswith("the translation"):
            return (f"the supports leave {self.motion} free and the work of {loads} on it is "
                    f"{self.value:.3g} J/m: no equilibrium with the loads as stated")
        if self.kind == "work":
            return (f"only a point's held slope holds {self.motion} and the work of {loads} on "
                    f"it is {self.value:.3g} J/rad: the shell turns rigidly about the point as "
                    f"the grid is refined")
        if self.kind == "second_order":
            return (f"only a point's held slope holds {self.motion} and the potential of "
                    f"{loads} falls along it at second order ({self.value:.3g} J/rad²): the "
                    f"shell swings rigidly about the point as the grid is refined")
        return (f"the supports leave {self.motion} free and no support (a point's held slope "
                f"does not count), load or contact resists it: a Newton solve has no "
                f"stiffness along it")


def free_motions(boundary, surface, *, point_slopes: bool = False, leave_out=()
                 ) -> tuple[np.ndarray, np.ndarray, float]:
    """The twists left free by the boundary conditions: an orthonormal basis (6, k) of
    q = (t, L ω) (t [m], ω [rad] about the centre c; L the surface's size [m]), c (3,) and L.
    point_slopes: count the slope a pinned point or handle holds (rotation "held") as holding
    (the constraints as stated; by default it does not: module docstring). leave_out:
    constraints of `boundary.constraints` not counted."""
    (lo1, hi1), (lo2, hi2) = surface.domain.bounds
    r = surface.jets(_grid_xi(surface.domain))
    area = torch.linalg.cross(r[:, jets.D1], r[:, jets.D2], dim=-1).norm(dim=-1)
    centre = ((r[:, 0] * area[:, None]).sum(0) / area.sum()).numpy()
    size = float(np.sqrt(float(area.mean()) * (hi1 - lo1) * (hi2 - lo2)))
    rows = [row for con in boundary.constraints if not any(con is c for c in leave_out)
            for row in constraint_rows(con, boundary, surface, centre, size, point_slopes)]
    if not rows:
        return np.eye(6), centre, size
    a = np.asarray(rows)
    a = a / np.maximum(np.linalg.norm(a, axis=1, keepdims=True), 1e-300)
    _, s, vt = np.linalg.svd(a, full_matrices=True)
    s = np.concatenate((s, np.zeros(6 - len(s))))
    return vt[s <= MOTION_TOL * s.max()].T, centre, size


def constraint_rows(con, boundary, surface, centre: np.ndarray, size: float,
                    point_slopes: bool = False) -> list[np.ndarray]:
    """The rows (6,) of one constraint on the twists q = (t, L ω) about `centre`: a held
    component at the points of its set, and across a curve where its factor vanishes
    quadratically; a point's slope with `point_slopes` (`free_motions`)."""
    frame = np.asarray(boundary.frame or IDENTITY_FRAME, dtype=np.float64)
    term = resolve(con, boundary.domain, surface, boundary.length, boundary.frame or IDENTITY_FRAME)
    held = sorted(term.components)
    across_held = [] if term.linear else held
    if isinstance(con, SymmetryPlane):
        across_held = [c for c in range(3) if c not in held]
    rows = []
    for start, end in term.where:
        xi = torch.tensor(points_along(_from_eta(boundary.domain, start),
                                       _from_eta(boundary.domain, end)), dtype=torch.float64)
        xi = xi[boundary.domain.contains(xi)]
        if len(xi) == 0:
            continue
        rj = surface.jets(xi).numpy()
        y = rj[:, 0] - centre
        rows += [np.concatenate((frame[c], np.cross(yk, frame[c]) / size))
                 for c in held for yk in y]
        if start == end:    # a point: its slope along both coordinates, if counted
            point = point_slopes and getattr(con, "rotation", "held") == "held"
            tangents = [rj[:, jets.D1], rj[:, jets.D2]] if point else []
        else:
            d = np.subtract(end, start) * np.asarray(boundary.domain.lengths)
            normal = np.array([-d[1], d[0]]) / np.linalg.norm(d)
            tangents = [normal[0] * rj[:, jets.D1] + normal[1] * rj[:, jets.D2]]
        rows += [np.concatenate((np.zeros(3), np.cross(a, frame[c])))  # e·(ω × a) = ω·(a × e)
                 for across in tangents for c in across_held for a in across]
    return rows


def describe(q: np.ndarray, centre: np.ndarray, size: float) -> str:
    """A twist q = (t, L ω) in words: a translation along a direction, or a rotation about an
    axis through a point (with its translation along the axis, when it has one)."""
    t, omega = q[:3], q[3:] / size
    if np.linalg.norm(omega) * size <= 1e-6 * np.linalg.norm(q):
        return f"the translation along {_direction(t)}"
    k = omega / np.linalg.norm(omega)
    point = centre + np.cross(omega, t) / float(omega @ omega)
    pitch = float(t @ omega) / float(omega @ omega)
    text = f"the rotation about {_direction(k)} through {_vector(point)} m"
    if abs(pitch) > 1e-6 * size:
        text += f" with {pitch:.3g} m per rad along it"
    return text


def _direction(v: np.ndarray) -> str:
    v = v / np.linalg.norm(v)
    k = int(np.argmax(np.abs(v)))
    if abs(abs(v[k]) - 1.0) < 1e-6:
        return COMPONENTS[k]
    return _vector(v)


def _vector(v: np.ndarray) -> str:
    v = np.where(np.abs(v) < 1e-9 * max(1.0, float(np.abs(v).max())), 0.0, v)
    return "(" + ", ".join(f"{x:.4g}" for x in v) + ")"


def _grid_xi(domain) -> torch.Tensor:
    (lo1, hi1), (lo2, hi2) = domain.bounds
    s = (torch.arange(GRID, dtype=torch.float64) + 0.5) / GRID
    g1, g2 = torch.meshgrid(lo1 + (hi1 - lo1) * s, lo2 + (hi2 - lo2) * s, indexing="ij")
    xi = torch.stack((g1.reshape(-1), g2.reshape(-1)), dim=1)
    return xi[domain.contains(xi)]


def load_points(model) -> tuple[np.ndarray, dict]:
    """The loads of `model` as forces at reference points: the points x (N, 3) [m] and the
    forces (N, 3) [N] of each kind of load (name -> forces)."""
    from taichi_ndf.problem.line_loads import quadrature

    surface, loads = model.surface, model.loads
    domain = surface.domain
    xi = _grid_xi(domain)
    r = surface.jets(xi)
    cell = domain.area / len(xi)
    normal_area = torch.linalg.cross(r[:, jets.D1], r[:, jets.D2], dim=-1) * cell  # a₃ √a dξ
    weight = normal_area.norm(dim=1)[:, None]
    parts = [(r[:, 0], {})]
    forces = parts[0][1]
    density = float(model.material.areal_density)
    if any(loads.gravity) and density:
        forces["gravity"] = density * torch.tensor(loads.gravity, dtype=torch.float64) * weight
    if any(loads.body_force):
        forces["the body force"] = torch.tensor(loads.body_force, dtype=torch.float64) * weight
    if loads.pressure:
        forces["the pressure"] = loads.pressure * normal_area
    if loads.point_loads:
        pxi = torch.tensor([p.xi for p in loads.point_loads], dtype=torch.float64)
        force = torch.tensor([p.force for p in loads.point_loads], dtype=torch.float64)
        parts.append((surface.jets(pxi)[:, 0], {"the point loads": force}))
    if loads.line_loads:
        lxi, force = quadrature(surface, loads.line_loads, dtype=torch.float64)
        parts.append((surface.jets(lxi)[:, 0], {"the line loads": force}))
    x = torch.cat([p[0] for p in parts]).numpy()
    out, offset = {}, 0
    for points, named in parts:
        for name, force in named.items():
            full = np.zeros_like(x)
            full[offset:offset + len(points)] = force.numpy()
            out[name] = full
        offset += len(points)
    return x, out


def twist_velocities(q: np.ndarray, y: np.ndarray, size: float) -> np.ndarray:
    """v (N, 3) [m] of twist q at points y = x − c (N, 3)."""
    return q[:3] + np.cross(q[3:] / size, y)


def rigid_work(forces: np.ndarray, q: np.ndarray, y: np.ndarray, size: float) -> float:
    return float((forces * twist_velocities(q, y, size)).sum())


def _second_order(forces: np.ndarray, q: np.ndarray, y: np.ndarray, size: float) -> float:
    """d²Π_loads/ds² along the finite rigid motion exp(s q): the points' second derivative is
    ω × v, so the dead loads' potential −Σ F·u has −Σ F·(ω × v)."""
    omega = q[3:] / size
    return -float((forces * np.cross(omega, twist_velocities(q, y, size))).sum())


def contact_points(model, centre: np.ndarray):
    """Points y = x − c (M, 3) of the reference closest to an obstacle and the obstacles'
    outward normals there (M, 3); None without obstacles."""
    config = getattr(model, "contact", None)
    if config is None:
        return None
    x = model.surface.jets(_grid_xi(model.surface.domain))[:, 0]
    gaps, normals = [], []
    for obstacle in config.obstacles:
        d, n = obstacle.signed_distance(x.to(torch.float64), 1.0)
        gaps.append(d.double() - config.offset)
        normals.append(n.double())
    gaps, normals = torch.stack(gaps, 1), torch.stack(normals, 1)
    gap, which = gaps.min(dim=1)
    near = gap <= gap.min() + config.activation
    normal = normals[torch.arange(len(x)), which][near]
    return (x[near] - torch.as_tensor(centre)).numpy(), normal.numpy()


def _resisted(contact, q: np.ndarray, size: float, one_sided: bool) -> float:
    """Mean (n·v)² / mean |v|² of twist q over the contact points (one-sided: only motion into
    the obstacles, n·v < 0, counts)."""
    if contact is None:
        return 0.0
    y, n = contact
    v = twist_velocities(q, y, size)
    into = (n * v).sum(1)
    if one_sided:
        into = np.minimum(into, 0.0)
    return float((into**2).mean() / max((v**2).sum(1).mean(), 1e-300))


def unresisted(contact, basis: np.ndarray, size: float) -> np.ndarray:
    """The subspace (6, m) of `basis` that contact does not resist (generalised eigenvectors of
    the contact's (n·v)² against |v|² below CONTACT_RESISTS)."""
    if contact is None or basis.shape[1] == 0:
        return basis
    y, n = contact
    columns = [twist_velocities(q, y, size) for q in basis.T]
    normal = np.stack([(n * v).sum(1) for v in columns], 1)           # (M, k)
    stiff = normal.T @ normal
    mass = np.array([[(a * b).sum() for b in columns] for a in columns])
    mu, vectors = scipy.linalg.eigh(stiff, mass)
    free = basis @ vectors[:, mu < CONTACT_RESISTS]
    return free / np.maximum(np.linalg.norm(free, axis=0, keepdims=True), 1e-300)


def rigid_motion_findings(model, *, newton: bool = True) -> list[Finding]:
    """What acts on the rigid motions the supports leave free (module docstring): work on a
    free translation; work or second-order work on a rotation that only a point's held slope
    holds (a rotation the constraints leave free as stated, about a hinge or a free pin, is
    the scene's statement: the loads choose the orientation); newton: also motions with no
    stiffness at all in any shape (a Newton solve's singular direction)."""
    basis, centre, size = free_motions(model.boundary, model.surface)
    if basis.shape[1] == 0:
        return []
    stated, _, _ = free_motions(model.boundary, model.surface, point_slopes=True)
    x, forces = load_points(model)
    y = x - centre
    total = sum(forces.values()) if forces else np.zeros_like(y)
    scale = float(np.linalg.norm(total, axis=1).sum())
    contact = contact_points(model, centre)
    findings = []

    def worked(sub, kinds):
        """The motion of span(sub) the loads do most work on, reported when contact does not
        hold it; the rest of span(sub)."""
        work = np.array([rigid_work(total, q, y, size) for q in sub.T])
        if sub.shape[1] == 0 or scale == 0 or np.linalg.norm(work) <= WORK_TOL * scale:
            return sub
        q = sub @ work / np.linalg.norm(work)
        if _resisted(contact, q, size, one_sided=True) < CONTACT_RESISTS:
            acting = tuple(name for name, f in forces.items()
                           if abs(rigid_work(f, q, y, size)) > WORK_TOL * scale)
            per = np.linalg.norm(q[3:]) / size or np.linalg.norm(q[:3])   # per rad or per m
            findings.append(Finding(describe(q, centre, size), kinds, acting,
                                    float(np.linalg.norm(work) / per)))
        return complement(sub, q)

    _, sv, vt = np.linalg.svd(basis[3:], full_matrices=True)   # span(basis) with ω = 0
    sv = np.concatenate((sv, np.zeros(basis.shape[1] - len(sv))))
    translations = basis @ vt[sv <= 1e-6].T
    worked(translations, "work")
    held_by_points = complement(basis, stated)       # what only a point's slope holds
    rest = unresisted(contact, worked(held_by_points, "work"), size)
    for value, q in load_curvatures(total, rest, y, size):
        if scale > 0 and value < -WORK_TOL * scale * size:
            acting = tuple(name for name, f in forces.items()
                           if _second_order(f, q, y, size) < -WORK_TOL * scale * size)
            findings.append(Finding(describe(q, centre, size), "second_order", acting,
                                    float(value)))
    if not newton:
        return findings
    free_pin = getattr(model.boundary, "free_pin", None) is not None
    work = np.array([rigid_work(total, q, y, size) for q in basis.T])
    if scale > 0 and np.linalg.norm(work) > WORK_TOL * scale:
        basis = complement(basis, (basis @ work)[:, None])
    for value, q in load_curvatures(total, unresisted(contact, basis, size), y, size):
        rotation = np.linalg.norm(q[3:]) > 1e-6
        if (abs(value) <= WORK_TOL * max(scale, 1e-300) * size and not (free_pin and rotation)
                and neutral_in_every_shape(total, q, size, scale)):
            findings.append(Finding(describe(q, centre, size), "no_stiffness"))
    return findings


def load_curvatures(forces, sub: np.ndarray, y, size):
    """(value, motion) pairs: the eigenvalues and eigenvectors of the loads' second-order
    potential over span(sub)."""
    k = sub.shape[1]
    if k == 0:
        return []
    h = np.zeros((k, k))
    for i in range(k):
        for j in range(k):
            plus = _second_order(forces, sub[:, i] + sub[:, j], y, size)
            h[i, j] = 0.25 * (plus - _second_order(forces, sub[:, i] - sub[:, j], y, size))
    # In the metric of the rotation ω [rad] where span(sub) has no translation (a value per
    # rad², the eigenvectors the world's axes where the loads' moments are), else of q.
    metric = sub[3:].T @ sub[3:] / size**2
    if np.linalg.eigvalsh(sub[3:].T @ sub[3:]).min() <= 1e-9:
        metric = np.eye(k)
    values, vectors = scipy.linalg.eigh(0.5 * (h + h.T), metric)
    return [(float(v), sub @ w) for v, w in zip(values, vectors.T, strict=True)]


def neutral_in_every_shape(forces: np.ndarray, q: np.ndarray, size: float, scale: float) -> bool:
    """Whether the loads' potential stays the same along the motion in every shape of the
    shell: a translation they do no work on, or a rotation about an axis along every force
    (gravity and a rotation about the vertical); zero at the reference is not enough, since
    a hanging shape turns a neutral tilt into a stable one."""
    omega = q[3:] / size
    if np.linalg.norm(omega) * size <= 1e-6:
        return True
    k = omega / np.linalg.norm(omega)
    return float(np.linalg.norm(np.cross(forces, k), axis=1).sum()) <= WORK_TOL * max(scale, 1e-300)


def complement(basis: np.ndarray, other: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the part of span(basis) orthogonal to span(other) (a vector
    or columns inside span(basis))."""
    other = np.asarray(other, dtype=np.float64).reshape(6, -1)
    if other.shape[1]:
        u, s, _ = np.linalg.svd(other, full_matrices=False)
        other = u[:, s > 1e-9]
        basis = basis - other @ (other.T @ basis)
    if basis.shape[1] == 0:
        return basis
    u, s, _ = np.linalg.svd(basis, full_matrices=False)
    return u[:, s > 1e-6]


def warn_rigid_motions(model, *, newton: bool = True) -> list[str]:
    """Log one warning line per finding of `rigid_motion_findings`; returns the lines."""
    lines = [f.line() for f in rigid_motion_findings(model, newton=newton)]
    for line in lines:
        log.warning("%s", line)
    return lines
