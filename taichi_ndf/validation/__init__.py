"""Validation against published shell benchmarks (`../shared/spec/benchmarks.md`): the case
catalogue (`catalogue`), the runner that trains a case's field and reads its quantities
(`runner`) and the report writer (`report`)."""

from taichi_ndf.validation.catalogue import (
    CASES,
    LINEARISATION,
    SCENES_DIR,
    Case,
    Quantity,
    Readings,
    _component,
    _roll_up_references,
    roll_up_moment,
)
from taichi_ndf.validation.report import convergence_plot, markdown_table, write_report
from taichi_ndf.validation.runner import CaseResult, Row, load_case_scene, run_case

__all__ = ["CASES", "LINEARISATION", "SCENES_DIR", "Case", "CaseResult", "Quantity", "Readings",
           "Row", "_component", "_roll_up_references", "convergence_plot", "load_case_scene",
           "markdown_table", "roll_up_moment", "run_case", "write_report"]
