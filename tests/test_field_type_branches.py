"""No branch on the field type outside the discretisation classes and the readers (issue 26).

Walks every module of `taichi_ndf` and `inverse` with `ast` (nothing is imported) and fails
on a test of the field type written anywhere but the places allowed to tell field types apart
(`ALLOWED`): the discretisations (`taichi_ndf/discretise/`), the field-type registries they and
the inverse package read (`problem/field_types.py`, `inverse/material/field_types.py`) and the
scene reader (`taichi_ndf/scene/`). Elsewhere a difference between field types is a value or
a capability of the registry's entry (`FieldType`, `InverseFieldType`) or a method of the
discretisation. What counts as a test of the field type:

- `isinstance` / `issubclass` against a class of one field type (`FIELD_CLASSES`: the fields,
  their configurations and specifications, the discretisations, the inverse equilibria, SfT
  settings and frame fits), and a comparison with one (`type(x) is C`, `kind is C`);
- a comparison (`==`, `!=`, `is`, `in`, ...) with a field type's name ("siren", "spline",
  "panels") or with a registry entry by name (`SIREN`, `SPLINE`, `PANELS`);
- `getattr` / `hasattr` probing for an attribute that only some field types' configurations
  have (`even_ends`, `pseudo_time`, ...: the fields of `FieldConfig` and `SplineConfig` not
  common to both), a capability found by duck typing.

The command-line readers name the field types only as argparse `choices` (not a comparison).
"""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

from taichi_ndf.field import FieldConfig, SplineConfig

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("taichi_ndf", "inverse")

# The places that may tell field types apart (paths relative to the repository; a folder
# stands for everything in it).
ALLOWED = (
    "taichi_ndf/discretise/",             # the discretisation classes and their factory
    "taichi_ndf/problem/field_types.py",  # the forward registry (FIELD_TYPES, of_spec, of_field)
    "inverse/material/field_types.py",    # the inverse registry (INVERSE_FIELD_TYPES)
    "taichi_ndf/scene/",                  # the scene reader: [field] type into a specification
)

# Branches left today, each with why: the list may only shrink (an entry whose branch is
# gone fails `test_known_branches_still_occur`). Keyed on (path, what), not on the line.
KNOWN: dict[tuple[str, str], str] = {
}

# Classes of one field type each.
FIELD_CLASSES = frozenset({
    "NeuralField", "SplineField", "PanelFields",                 # fields
    "FieldConfig", "SplineConfig", "PanelsConfig",               # their architectures
    "SplinePlan", "MultiPatchPlan",                              # specifications
    "SirenDiscretisation", "SplineDiscretisation", "MultiPatchDiscretisation",
    "ImplicitEquilibrium", "SplineEquilibrium",                  # inverse forward models
    "ImplicitConfig", "SplineModelConfig",
    "ReconstructionConfig", "SplinePriorConfig",                 # SfT settings naming a field
    "SirenFrameField", "SplineFrameField",                       # SfT frame fields
})
FIELD_NAMES = frozenset({"siren", "spline", "panels"})
ENTRY_NAMES = frozenset({"SIREN", "SPLINE", "PANELS"})


def _config_only_attributes() -> frozenset[str]:
    """Attributes of one field configuration that the other lacks."""
    siren = {f.name for f in dataclasses.fields(FieldConfig)}
    spline = {f.name for f in dataclasses.fields(SplineConfig)}
    return frozenset(siren ^ spline)


PROBED = _config_only_attributes()


def _name(node: ast.AST) -> str | None:
    """The class or entry a node names: `C` or `module.C`."""
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return node.attr
    return None


def _names_in(node: ast.AST) -> list[str]:
    """The names of a class argument: one, or a tuple of them."""
    items = node.elts if isinstance(node, (ast.Tuple, ast.List, ast.Set)) else [node]
    return [n for n in map(_name, items) if n is not None]


def _strings_in(node: ast.AST) -> set[str]:
    items = node.elts if isinstance(node, (ast.Tuple, ast.List, ast.Set)) else [node]
    return {i.value for i in items if isinstance(i, ast.Constant) and isinstance(i.value, str)}


def branches(source: str) -> list[tuple[int, str]]:
    """(line, what) for each test of the field type in a module's source."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
            if node.func.id in ("isinstance", "issubclass") and len(node.args) == 2:
                hit = [n for n in _names_in(node.args[1]) if n in FIELD_CLASSES]
                if hit:
                    found.append((node.lineno, f"{node.func.id}(..., {', '.join(hit)})"))
            if (node.func.id in ("getattr", "hasattr") and len(node.args) >= 2
                    and isinstance(node.args[1], ast.Constant) and node.args[1].value in PROBED):
                found.append((node.lineno, f"{node.func.id}(..., {node.args[1].value!r})"))
        if isinstance(node, ast.Compare):
            sides = [node.left, *node.comparators]
            for side in sides:
                names = FIELD_NAMES & _strings_in(side)
                if names:
                    found.append((node.lineno, f"comparison with {sorted(names)}"))
                entries = [n for n in _names_in(side) if n in ENTRY_NAMES]
                if entries:
                    found.append((node.lineno, f"comparison with {entries}"))
            classes = [n for s in sides for n in _names_in(s) if n in FIELD_CLASSES]
            if classes:
                found.append((node.lineno, f"comparison with the class {classes}"))
    return sorted(set(found))


def _modules() -> list[Path]:
    return [path for package in PACKAGES for path in sorted((ROOT / package).rglob("*.py"))]


def _allowed(relative: str) -> bool:
    return any(relative == a or (a.endswith("/") and relative.startswith(a)) for a in ALLOWED)


def _outside() -> list[tuple[str, int, str]]:
    """(path, line, what) of each branch outside the allowed places."""
    return [(path.relative_to(ROOT).as_posix(), line, what) for path in _modules()
            if not _allowed(path.relative_to(ROOT).as_posix())
            for line, what in branches(path.read_text())]


def test_no_field_type_branch_outside_the_discretisations_and_readers():
    outside = [f"{path}:{line}: {what}" for path, line, what in _outside()
               if (path, what) not in KNOWN]
    assert not outside, "branches on the field type:\n" + "\n".join(outside)


def test_known_branches_still_occur():
    found = {(path, what) for path, _, what in _outside()}
    gone = [key for key in KNOWN if key not in found]
    assert not gone, f"no longer branches, remove from KNOWN: {gone}"


def test_allowed_places_exist():
    """Each allowed place is still there (a moved module would widen nothing silently)."""
    for place in ALLOWED:
        assert (ROOT / place).exists(), place


def test_the_walk_finds_each_kind_of_branch():
    """The detector itself, on the forms it must catch and the ones it must let pass."""
    caught = """
tag = PANELS if isinstance(field, PanelFields) else name
if isinstance(spec, (FieldConfig, int)): pass
if type(spec) is SplinePlan: pass
if args.field == "spline": pass
if "siren" != kind: pass
if field in ("spline", "other"): pass
if kind is SPLINE: pass
even = getattr(field.config, "even_ends", ())
if hasattr(config, "pseudo_time"): pass
if kind is not SplinePriorConfig: pass
"""
    assert sorted({line for line, _ in branches(caught)}) == list(range(2, 12))
    passed = """
p.add_argument("--field", choices=("siren", "spline"))
if isinstance(value, (list, tuple)): pass
if state.method == "newton": pass
value = getattr(self, name)
kind = FIELD_TYPES[args.field]
"""
    assert branches(passed) == []


def test_the_entries_carry_what_the_branches_asked(tmp_path):
    """What the removed branches tested is now a value of the entry: a garment's panels are
    a checkpoint type of their own (tag "panels", saved and loaded through `of_field` /
    `CHECKPOINT_TYPES`) that no scene names; the operator's and the bilevel fit's
    capabilities; the SfT tool's per-field settings."""
    import torch

    from inverse.material.field_types import INVERSE_FIELD_TYPES
    from inverse.sft.settings import ReconstructionConfig, SplinePriorConfig
    from taichi_ndf.field.panels import PanelFields, PanelsConfig
    from taichi_ndf.minimise.checkpoint import load_checkpoint, read_checkpoint, save_checkpoint
    from taichi_ndf.problem.field_types import (
        CHECKPOINT_TYPES,
        FIELD_TYPES,
        PANELS,
        SIREN,
        SPLINE,
        of_field,
    )

    grid = SplineConfig(spans=(2, 1), domain=((0.0, 1.0), (0.0, 0.5)))
    panels = PanelFields(PanelsConfig(("front", "back"), (grid, grid)))
    panels.fields[1].parameters[0].fill_(0.25)
    assert of_field(panels) is PANELS and "panels" not in FIELD_TYPES
    assert set(CHECKPOINT_TYPES) == {*FIELD_TYPES, "panels"}
    path = save_checkpoint(tmp_path / "panels.pt", panels)
    assert read_checkpoint(path)["field_type"] == "panels"
    loaded = load_checkpoint(path).field
    assert isinstance(loaded, PanelFields) and loaded.config == panels.config
    assert torch.equal(loaded.get_flat(), panels.get_flat())
    assert (SIREN.pseudo_time, SIREN.conditioned, SIREN.even_ends) == (True, True, False)
    assert (SPLINE.pseudo_time, SPLINE.conditioned, SPLINE.even_ends) == (False, False, True)
    sft = {name: (k.frame_settings, k.initial_guesses, k.photometric, k.float64_only)
           for name, k in INVERSE_FIELD_TYPES.items()}
    assert sft == {"siren": (ReconstructionConfig, True, False, False),
                   "spline": (SplinePriorConfig, False, True, True)}
