"""Independent reference: the planar heavy elastica of a strip clamped at s = 0 (scipy BVP).

Per unit width, reference arclength s ∈ [0, L], tangent angle θ(s), stretch λ(s):
x' = λ (cos θ, sin θ); section force n(s) = P + (L − s) f (f: load per unit reference area,
P: tip force per unit width); moment m = B λ² θ' with m' = −λ n × t; axial balance
D ε λ + B λ θ'² = n · t with ε = (λ² − 1)/2. This is the Koiter shell with ν = 0 in cylindrical
bending (κ₁₁ = λ θ'), solved without any of the project's code (numpy and scipy only); D → ∞
gives the classical inextensible heavy elastica of the cantilever bending test (Peirce; ASTM
D1388). A clamp tilted by α is the same problem with the load rotated by −α in the strip's
frame.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_bvp


def cantilever(length, bending, membrane, load, tip_force=(0.0, 0.0)):
    """Solve; returns a function s -> (x, z) positions, shape (len(s), 2), and the BVP solution.

    load: (f_x, f_z) [N/m²]; tip_force: (P_x, P_z) per unit width [N/m]."""
    f = np.asarray(load, dtype=float)
    p = np.asarray(tip_force, dtype=float)

    def section_force(s):
        return p[:, None] + (length - s)[None, :] * f[:, None]

    def stretch(theta, m, s):
        n = section_force(s)
        axial = n[0] * np.cos(theta) + n[1] * np.sin(theta)
        lam = np.ones_like(s)
        for _ in range(40):
            res = membrane * 0.5 * (lam**2 - 1) * lam + m**2 / (bending * lam**3) - axial
            slope = membrane * (1.5 * lam**2 - 0.5) - 3 * m**2 / (bending * lam**4)
            lam = lam - res / slope
        return lam

    def rhs(s, y):
        theta, m = y[0], y[1]
        lam = stretch(theta, m, s)
        n = section_force(s)
        cross = n[0] * np.sin(theta) - n[1] * np.cos(theta)  # −n × t
        return np.vstack([m / (bending * lam**2), lam * cross,
                          lam * np.cos(theta), lam * np.sin(theta)])

    def bc(ya, yb):
        return np.array([ya[0], yb[1], ya[2], ya[3]])

    mesh = np.linspace(0.0, length, 401)
    guess = np.zeros((4, mesh.size))
    guess[2] = mesh
    sol = solve_bvp(rhs, bc, mesh, guess, tol=1e-10, max_nodes=200000)
    if not sol.success:
        raise RuntimeError(f"elastica BVP failed: {sol.message}")

    def positions(s):
        y = sol.sol(np.asarray(s, dtype=float))
        return np.stack([y[2], y[3]], axis=1)

    return positions, sol
