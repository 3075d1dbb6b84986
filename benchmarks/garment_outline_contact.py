"""Polygon panels against obstacles and cut flat (issue 30, "Garments: outline panels on a body,
a T-shirt"): what the contact rounds change for polygon panels (`outline`), whose check
points are inside the outline and on its border (`contact.check_points.outline_check_grid`).

1. far: two trapezoids sewn along their slanted edge, held at the top (6 × 4 spans), and the
   flat-cut skirt of scenes/skirt_body.toml with its two panels as polygons (wrapped at
   0.15 m, the waist gathered onto 0.12 m, 6 × 4 spans): each load step's Π without and with
   a sphere 5 m away (relative difference; Newton iterations; check points added).
2. rectangle: scenes/skirt_body.toml's flat-cut skirt sagging onto its capsule (4 × 2 spans)
   with its panels as rectangles and as polygons that are those rectangles: Π per load step,
   relative difference, check points, contact rounds.
3. draped: the trapezoids lying flat, sagging onto a 0.1 m sphere 5 mm below the slanted
   seam: the smallest gap beyond h/2 + margin over a 61² grid inside each outline and 200
   points along each edge, against the activation distance.

CPU = user + sys of this process per solve (`resource.getrusage`), float64, one thread.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/garment_outline_contact.py
"""

from __future__ import annotations

import os
import resource
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' scenarios and checks

from provenance import commit  # noqa: E402

import taichi_ndf  # noqa: E402
from tests.test_contact_outline_panels import (  # noqa: E402
    FAR,
    converged,
    skirt,
    smallest_outline_gap,
    trapezoids,
)

ROOT = Path(__file__).resolve().parents[1]
BALL = {"type": "sphere", "name": "ball", "centre": [0.15, 0.1, -0.105], "radius": 0.1}


def cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def solve(document: dict):
    """(scene, panels, solution, CPU s) of a garment document, every load step converged."""
    started = cpu()
    scene, panels, solution = converged(document)
    return scene, panels, solution, cpu() - started


def far_table() -> None:
    print("\n1. an obstacle 5 m away")
    print("| case | load factor | Π alone [J] | Π with the far sphere [J] | relative difference "
          "| Newton it. (alone / far) | check points | CPU alone / far [s] |")
    print("|---|---|---|---|---|---|---|---|")
    skirt_alone = skirt(True, (6, 4), {}, held_radius=0.12)
    skirt_alone["training"]["load_steps"] = [0.5, 1.0]
    skirt_far = skirt(True, (6, 4), FAR, held_radius=0.12)
    skirt_far["training"]["load_steps"] = [0.5, 1.0]
    for name, alone, far in (("trapezoids", trapezoids(None), trapezoids(FAR)),
                             ("flat-cut polygon skirt, gathered", skirt_alone, skirt_far)):
        *_, first, c1 = solve(alone)
        *_, second, c2 = solve(far)
        for a, b in zip(first.document["load_steps"], second.document["load_steps"],
                        strict=True):
            print(f"| {name} | {a['load_factor']:g} | {a['energy']:.12e} | {b['energy']:.12e} "
                  f"| {abs(b['energy'] / a['energy'] - 1):.1e} | {a['iterations']} / "
                  f"{b['iterations']} | {second.contact.count} | {c1:.1f} / {c2:.1f} |")


def rectangle_table() -> None:
    print("\n2. the flat-cut skirt on its body: rectangles and polygons that are them")
    print("| panels | load factor | Π [J] | relative to the rectangles | check points | rounds "
          "| CPU [s] |")
    print("|---|---|---|---|---|---|---|")
    rows = {}
    for outline in (False, True):
        *_, solution, seconds = solve(skirt(outline, (4, 2)))
        rows[outline] = solution
        for k, step in enumerate(solution.document["load_steps"]):
            reference = rows[False].document["load_steps"][k]["energy"]
            print(f"| {'polygons' if outline else 'rectangles'} | {step['load_factor']:g} | "
                  f"{step['energy']:.12e} | {abs(step['energy'] / reference - 1):.1e} | "
                  f"{solution.contact.count} | {solution.contact_counts['newton_rounds']} | "
                  f"{seconds:.1f} |")


def draped_table() -> None:
    print("\n3. the trapezoids draped over a sphere")
    scene, panels, solution, seconds = solve(trapezoids(BALL))
    config = scene.model.contact
    smallest = smallest_outline_gap(scene, panels)
    print("| Π [J] | Newton it. | rounds | check points | smallest gap [m] | ĝ [m] | seam gap [m] "
          "| CPU [s] |")
    print("|---|---|---|---|---|---|---|---|")
    print(f"| {solution.energy:.10e} | {solution.iterations} | "
          f"{solution.contact_counts['newton_rounds']} | {solution.contact.count} | "
          f"{smallest:.3e} | {config.activation:.3e} | "
          f"{max(solution.document['seam_gaps'].values()):.1e} | {seconds:.1f} |")


def main() -> None:
    taichi_ndf.init(arch="cpu", precision="f64", seed=0)
    print(f"commit {commit()}, load {os.getloadavg()[0]:.1f}")
    far_table()
    rectangle_table()
    draped_table()
    print(f"\nload {os.getloadavg()[0]:.1f}, CPU {cpu():.1f} s")


if __name__ == "__main__":
    main()
