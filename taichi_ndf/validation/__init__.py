"""Validation against published shell benchmarks (`../shared/spec/benchmarks.md`): what a case
is (`catalogue`), case files and the built-in cases (`case_file`, `validation/cases/`), the
runner that trains a case's field and reads its quantities (`runner`) and the report writer
(`report`). The runner and the report (torch, Taichi) are imported on first use, so the
catalogue and the built-in cases (ndf-validate's --help) stay light."""

from taichi_ndf.validation.case_file import builtin_cases, load_case
from taichi_ndf.validation.catalogue import (
    CASES_DIR,
    LINEARISATION,
    SCENES_DIR,
    Case,
    Quantity,
    Readings,
    component_read,
    roll_up_moment,
    roll_up_references,
    rotation_read,
)

CASES = builtin_cases()

_LAZY = {"convergence_plot": "report", "markdown_table": "report", "write_report": "report",
         "CaseResult": "runner", "Row": "runner", "load_case_scene": "runner",
         "run_case": "runner"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f"taichi_ndf.validation.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'taichi_ndf.validation' has no attribute {name!r}")

__all__ = ["CASES", "CASES_DIR", "LINEARISATION", "SCENES_DIR", "Case", "CaseResult", "Quantity",
           "Readings", "Row", "builtin_cases", "component_read", "convergence_plot",
           "load_case", "load_case_scene", "markdown_table", "roll_up_moment",
           "roll_up_references", "rotation_read", "run_case", "write_report"]
