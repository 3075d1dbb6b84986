"""Validation against published shell benchmarks (`../shared/spec/benchmarks.md`): what a case
is (`catalogue`), case files and the built-in cases (`case_file`, `validation/cases/`), the
runner that trains a case's field and reads its quantities (`runner`) and the report writer
(`report`)."""

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
from taichi_ndf.validation.report import convergence_plot, markdown_table, write_report
from taichi_ndf.validation.runner import CaseResult, Row, load_case_scene, run_case

CASES = builtin_cases()

__all__ = ["CASES", "CASES_DIR", "LINEARISATION", "SCENES_DIR", "Case", "CaseResult", "Quantity",
           "Readings", "Row", "builtin_cases", "component_read", "convergence_plot",
           "load_case", "load_case_scene", "markdown_table", "roll_up_moment",
           "roll_up_references", "rotation_read", "run_case", "write_report"]
