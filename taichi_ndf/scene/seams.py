"""The `[[seams]]` tables of a scene file: seams joining edge segments (docs/scenes.md, "Seams").

Each table is read into a plain `SeamSpec` (`taichi_ndf.problem.seams`); the specs are
checked together (an edge in two seams) and against the surface where the model's terms are
built (`SeamTerm`: a periodic coordinate, a range outside its edge, lengths that differ).
Errors are one line naming the table, the seam and the edge.
"""

from __future__ import annotations

from taichi_ndf.objective.seam import SeamTerm
from taichi_ndf.problem.seams import (
    BENDING,
    DEFAULT_PENALTY,
    EDGES,
    ORIENTATIONS,
    EdgeSegment,
    SeamSpec,
    check_seams,
)
from taichi_ndf.scene.schema import Table, checked


def _segment(t: Table, side: str) -> EdgeSegment:
    edge = t.string(side, choices=EDGES)
    span = t.vector(f"{side}_range", 2) if t.has(f"{side}_range") else None
    return EdgeSegment(edge, span)


def _spec(t: Table, index: int) -> SeamSpec:
    name = t.string("name", f"seams[{index}]")
    return SeamSpec(name, _segment(t, "a"), _segment(t, "b"),
                    orientation=t.string("orientation", "same", choices=ORIENTATIONS),
                    bending=t.string("bending", "transmitted", choices=BENDING),
                    penalty=t.number("stiffness", DEFAULT_PENALTY, positive=True),
                    segments=t.integer("segments", 64, minimum=1),
                    nodes=t.integer("nodes", 4, minimum=1))


def parse_seams(top: Table, surface, material) -> tuple[SeamTerm, ...]:
    """The seam terms of the `[[seams]]` tables, in their order (none: ())."""
    tables = top.tables("seams")
    specs = []
    for index, t in enumerate(tables):
        specs.append(checked(lambda t=t, index=index: _spec(t, index), t.path))
        t.close()
    checked(lambda: check_seams(specs), "seams")
    return tuple(checked(lambda spec=spec, t=t: SeamTerm(spec, surface, material), t.path)
                 for spec, t in zip(specs, tables, strict=True))
