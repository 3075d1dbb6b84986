"""Write the obstacle meshes of this directory (see README.md); deterministic.

Run from the repository root:  python data/make_obstacles.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
TORUS_MAJOR, TORUS_MINOR = 0.25, 0.08  # [m]
TORUS_SECTIONS = (32, 16)  # around the axis, around the tube


def torus(major: float, minor: float, n_major: int, n_minor: int
          ) -> tuple[np.ndarray, np.ndarray]:
    """Closed torus about the z axis, centre at the origin: vertices (n_major·n_minor, 3) [m]
    and outward-oriented triangles."""
    phi, theta = np.meshgrid(np.arange(n_major) * 2 * np.pi / n_major,
                             np.arange(n_minor) * 2 * np.pi / n_minor, indexing="ij")
    rho = major + minor * np.cos(theta)
    vertices = np.stack((rho * np.cos(phi), rho * np.sin(phi), minor * np.sin(theta)), axis=-1)
    faces = []
    for i in range(n_major):
        for j in range(n_minor):
            i1, j1 = (i + 1) % n_major, (j + 1) % n_minor
            a, b, c, d = i * n_minor + j, i1 * n_minor + j, i1 * n_minor + j1, i * n_minor + j1
            faces += [(a, b, c), (a, c, d)]
    return vertices.reshape(-1, 3), np.array(faces)


def write(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    write(HERE / "torus.obj", *torus(TORUS_MAJOR, TORUS_MINOR, *TORUS_SECTIONS))
