"""`ndf-sweep STUDY.toml --out DIR`: run every point of a study, one run directory each.

    ndf-sweep STUDY.toml --out DIR [--workers N | --ray auto|ADDRESS] [--retry-failed]
              [--parquet] [-v]

Writes DIR/runs/NAME/ (the tool's usual outputs, NAME made of the point's parameters),
DIR/logs/NAME.out|.err, DIR/rows/NAME.json, DIR/results.csv (updated as runs finish),
DIR/summary.png (one- and two-axis studies), DIR/study.json and, for a job that shares
set-up between its runs, DIR/cache/. Running it again with the
same study and DIR resumes: finished runs (failed ones too, unless --retry-failed) are skipped,
unfinished ones redone. docs/sweeps.md.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections import Counter
from pathlib import Path

from taichi_ndf.cli.common import ArgumentParser, interruptible
from taichi_ndf.sweep.plot import summary_plot
from taichi_ndf.sweep.ray_engine import EngineError
from taichi_ndf.sweep.run import RunSpec
from taichi_ndf.sweep.study import Study, StudyError, load_study
from taichi_ndf.sweep.table import LEADING, STATUS, TRAILING, ResultsTable


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(prog="ndf-sweep", description=__doc__.split("\n")[0].strip("`"))
    p.add_argument("study", type=Path, help="study file (TOML); see docs/sweeps.md")
    p.add_argument("--out", type=Path, required=True,
                   help="study folder (new, or one of the same study to resume)")
    engine = p.add_mutually_exclusive_group()
    engine.add_argument("--workers", type=int, default=1,
                        help="local engine: runs at once, each one process of one thread "
                        "(default 1)")
    engine.add_argument("--ray", metavar="auto|ADDRESS",
                        help="run on Ray (the optional extra `ray`): auto = the cluster this "
                        "machine joined with `ray start`, or a cluster address HOST:PORT; "
                        "DIR must be on a file system every node mounts at the same path")
    p.add_argument("--retry-failed", action="store_true",
                   help="redo the runs that failed or diverged before (default: keep their "
                   "rows)")
    p.add_argument("--parquet", action="store_true",
                   help="also write DIR/results.parquet (needs pyarrow: the `parquet` extra)")
    p.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    return p


def check_out(out: Path, study: Study) -> None:
    """Refuse a DIR that holds something else than this study (ValueError, one line)."""
    record = out / "study.json"
    if record.is_file():
        stored = json.loads(record.read_text())
        now = json.loads(json.dumps(study.describe()))
        changed = [k for k in now if stored.get(k) != now[k]]
        if changed:
            raise ValueError(f"{out} holds another study ({changed[0]} differs from "
                             f"{study.path}); use a new --out")
    elif out.exists() and any(out.iterdir()):
        raise ValueError(f"{out} is not empty and holds no study.json; use a new --out")


def specs(study: Study, out: Path, todo: list[int]) -> list[RunSpec]:
    """What the engines run: the points `todo` as commands with their run directories."""
    out_specs = []
    for i in todo:
        point = study.points[i]
        keys = {**study.options, **point.parameters}
        run_dir = out / "runs" / point.name
        command = study.job.command(study.base, keys, run_dir, cache=out / "cache")
        out_specs.append(RunSpec(
            index=i, name=point.name, parameters=point.parameters, seed=keys.get("seed"),
            job=study.job.kind, command=tuple(command),
            run_dir=str(run_dir), log=str(out / "logs" / point.name)))
    return out_specs


_SHOWN = ("value_", "estimate_", "best_fit_")  # the outputs a progress line shows


def _line(row: dict) -> str:
    if row["status"] != "ok":
        return f"{row['status']}: {row['reason']}"
    shown = [f"{k} = {v:.6g}" for k, v in row.items()
             if isinstance(v, int | float) and not isinstance(v, bool)
             and (k in ("energy_J", "mean_e3d") or k.startswith(_SHOWN))]
    times = f"{row.get('wall_s', 0):.1f} s, CPU {row.get('cpu_s', 0):.1f} s"
    return ", ".join(shown[:3]) + f" ({times})"


@interruptible("ndf-sweep")
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    out = args.out.resolve()
    try:
        if args.workers < 1:
            raise ValueError(f"--workers must be >= 1, got {args.workers}")
        study = load_study(args.study)
        if args.parquet:
            try:
                import pyarrow  # noqa: F401
            except ImportError:
                raise ValueError("--parquet needs pyarrow: pip install 'taichi-ndf[parquet]'") \
                    from None
        if args.ray is not None:
            from taichi_ndf.sweep.ray_engine import require_ray

            require_ray()
        check_out(out, study)
    except (StudyError, ValueError, EngineError) as err:
        print(f"ndf-sweep: error: {err}", file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    (out / "study.json").write_text(json.dumps(study.describe(), indent=1))
    table = ResultsTable(out, study.axes, [p.name for p in study.points], parquet=args.parquet)
    table.load()
    if args.retry_failed:
        for i, row in list(table.rows.items()):
            if row.get("status") != "ok":
                table.forget(i)
    todo = [p.index for p in study.points if not table.done(p.index)]
    total = len(study.points)
    engine = f"Ray ({args.ray})" if args.ray else f"{args.workers} worker(s)"
    print(f"{study.name}: {total} runs, {total - len(todo)} finished before (skipped), "
          f"{len(todo)} to run on {engine}", flush=True)

    def on_row(spec: RunSpec, row: dict) -> None:
        table.add(spec.index, row)
        print(f"[{len(table.rows)}/{total}] {spec.name}: {_line(row)}", flush=True)

    resume = f"ndf-sweep {args.study} --out {args.out}"
    try:
        if args.ray is not None:
            from taichi_ndf.sweep.ray_engine import run_ray

            run_ray(specs(study, out, todo), args.ray, on_row)
        else:
            from taichi_ndf.sweep.pool import run_local

            run_local(specs(study, out, todo), args.workers, on_row)
    except KeyboardInterrupt:
        # The rows' records on disk are the truth: Ctrl-C may land after a run's record was
        # written and before the table kept it in memory.
        table.load()
        table.write()
        print(f"ndf-sweep: interrupted; {len(table.rows)} of {total} runs finished (in "
              f"{out / 'results.csv'}); resume with: {resume}", file=sys.stderr)
        return 130
    except EngineError as err:
        print(f"ndf-sweep: error: {err}", file=sys.stderr)
        return 2
    path = table.write()
    named = set(LEADING) | set(study.axes) | set(STATUS) | set(TRAILING)
    plot = summary_plot(out / "summary.png", study.axes, study.points, table.rows, named)
    counts = Counter(row["status"] for row in table.rows.values())
    print(f"{study.name}: " + ", ".join(f"{n} {s}" for s, n in sorted(counts.items()))
          + f"; results in {path}" + (f", plot {plot}" if plot else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
