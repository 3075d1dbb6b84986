"""The results table of a study: one row per finished run, rewritten as each run finishes.

Each finished run's row is kept as OUT/rows/NAME.json (written atomically: the record that the
run is done, read back on resume); OUT/results.csv (and with ``parquet`` OUT/results.parquet,
the optional ``parquet`` extra) holds every row in study order. Columns: point, the axes,
status, reason, the job's outputs (first seen order), then seed, wall_s, cpu_s,
peak_memory_MiB, commit, machine. A list value is written as TOML text (``[0, 0, -9.81]``).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

from taichi_ndf.io import atomic_path
from taichi_ndf.sweep.jobs import toml_value

LEADING = ("point",)
STATUS = ("status", "reason")
TRAILING = ("seed", "wall_s", "cpu_s", "peak_memory_MiB", "commit", "machine")
TIMES = ("wall_s", "cpu_s", "peak_memory_MiB", "fit_s")  # differ between identical runs


def cell(value) -> str | int | float | bool:
    """A value as a table cell: lists and tables as TOML text, None as ''."""
    if value is None:
        return ""
    if isinstance(value, list | dict):
        return toml_value(value)
    return value


class ResultsTable:
    """Rows of a study's finished runs (by point index) and the files that hold them."""

    def __init__(self, out: Path, axes: tuple[str, ...], names: list[str], *,
                 parquet: bool = False):
        self.out, self.axes, self.names, self.parquet = out, axes, names, parquet
        self.rows: dict[int, dict] = {}
        self.rows_dir = out / "rows"

    def load(self) -> None:
        """Read back the rows of runs finished earlier (resume)."""
        for index, name in enumerate(self.names):
            path = self.rows_dir / f"{name}.json"
            if path.is_file():
                self.rows[index] = json.loads(path.read_text())

    def done(self, index: int) -> bool:
        return index in self.rows

    def add(self, index: int, row: dict) -> None:
        """Keep a finished run's row (its record first, then the table files)."""
        with atomic_path(self.rows_dir / f"{self.names[index]}.json") as path:
            path.write_text(json.dumps(row, indent=1))
        self.rows[index] = row
        self.write()

    def forget(self, index: int) -> None:
        """Drop a run's row (it is redone: --retry-failed)."""
        (self.rows_dir / f"{self.names[index]}.json").unlink(missing_ok=True)
        self.rows.pop(index, None)

    def columns(self) -> list[str]:
        named = set(LEADING) | set(self.axes) | set(STATUS) | set(TRAILING)
        outputs = [k for i in sorted(self.rows) for k in self.rows[i] if k not in named]
        return [*LEADING, *self.axes, *STATUS, *dict.fromkeys(outputs),
                *(k for k in TRAILING if k not in self.axes)]

    def records(self) -> list[dict]:
        """The rows in study order as cells, every column present ('' where a row lacks it)."""
        columns = self.columns()
        return [{c: cell(self.rows[i].get(c)) for c in columns} for i in sorted(self.rows)]

    def write(self) -> Path:
        """Rewrite OUT/results.csv (and .parquet) from every row; returns the CSV's path."""
        columns, records = self.columns(), self.records()
        target = self.out / "results.csv"
        with atomic_path(target) as path, open(path, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=columns)
            writer.writeheader()
            writer.writerows(records)
        if self.parquet:
            import pyarrow as pa
            import pyarrow.parquet as pq

            try:
                table = pa.Table.from_pylist(
                    [{c: None if r[c] == "" else r[c] for c in columns} for r in records])
            except (pa.ArrowInvalid, pa.ArrowTypeError):  # a column of mixed types
                table = pa.Table.from_pylist([{c: str(r[c]) for c in columns} for r in records])
            with atomic_path(self.out / "results.parquet") as path:
                pq.write_table(table, path)
        return target


def read_csv(path: str | Path) -> list[dict]:
    """The rows of a results.csv as dicts of strings."""
    with open(path, newline="") as f:
        return list(csv.DictReader(f))
