"""The `[[terms]]` tables of a scene file: further energy terms of the model (docs/scenes.md).

Each table names its term by `type`; `TERMS` maps the type to the reader of its keys, which
returns the term (`taichi_ndf.objective.Term`). The model carries the terms
(`ShellModel.terms`) and `Objective.of_model` adds them to the shell's potential energy, so a
new scene-reachable term is its class (`objective/terms.py`) and one reader here.
"""

from __future__ import annotations

from taichi_ndf.objective.terms import FoundationTerm
from taichi_ndf.scene.schema import Table, checked


def _foundation(t: Table) -> FoundationTerm:
    """An elastic (Winkler) foundation: `stiffness` k [N/m³] > 0."""
    return FoundationTerm(t.number("stiffness", positive=True))


TERMS = {"foundation": _foundation}


def parse_terms(top: Table) -> tuple:
    """The terms of the `[[terms]]` tables, in their order (none: ())."""
    terms = []
    for t in top.tables("terms"):
        kind = t.string("type", choices=TERMS)
        terms.append(checked(lambda t=t, kind=kind: TERMS[kind](t), t.path))
        t.close()
    return tuple(terms)
