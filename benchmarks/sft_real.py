"""Shape-from-template on a real capture (φ-SfT's R1): ``ndf-sft --capture`` as a user runs it.

    python benchmarks/sft_real.py --data PATH [--frames N] [--pinned 0,992] [--label TEXT]
        [--out DIR] [--results benchmarks/RESULTS.md | --no-write] [-- extra ndf-sft options]

Runs the whole command ``ndf-sft --capture PATH`` (default settings, plus whatever follows
``--``) as a child process, with the CPU time of the child from
``resource.getrusage(RUSAGE_CHILDREN)`` (all its threads, start-up included), and reads its
``result.json``: the field's chamfer ×1e4 per frame (``inverse.sft.chamfer``), its mean, the
worst frame, the largest vertex-to-cloud distance, CPU s per frame, wall, and the estimated
material when the result has one. Prints the table beside the published values and puts it
into RESULTS.md's section "Shape-from-template on a real capture (φ-SfT R1)" (newest run
first). With ``--frames N`` the first N frames, masks and clouds are linked into a temporary
capture. The data stays outside the repository.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import commit as provenance_commit  # noqa: E402  (the commit each benchmark states)

SECTION = "## Shape-from-template on a real capture (φ-SfT R1)"
# Chamfer x1e4 on R1 as published (NSfT's table for PGSfT; docs in the capture's README).
PUBLISHED = (("NSfT (ICCV 2025)", 0.66, "~2 s/frame on a V100"),
             ("φ-SfT (CVPR 2022)", 0.79, "16–24 h per sequence on a GPU"),
             ("Thin-Shell-SfT (CVPR 2025)", 1.17, "30–60 min on an A100"),
             ("PGSfT (CVPR 2024)", 6.05, "as reported in NSfT's table"))
TARGET = "mean ≤ 0.6, no frame above 2.0, no vertex farther than 20 mm, ≤ 1.5 s CPU per frame"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", type=Path, required=True, help="the capture folder (R1)")
    p.add_argument("--frames", type=int, help="use the first N frames only")
    p.add_argument("--pinned", help="held vertices passed to ndf-sft (e.g. 0,992)")
    p.add_argument("--label", default="default settings", help="the run's name in the table")
    p.add_argument("--out", type=Path, help="ndf-sft's output folder (default: a temporary one)")
    p.add_argument("--results", type=Path, default=Path(__file__).with_name("RESULTS.md"))
    p.add_argument("--no-write", action="store_true", help="print only")
    return p


def subset(data: Path, frames: int, into: Path) -> Path:
    """A capture of the first `frames` frames of `data`, as symbolic links in `into`."""
    for name in ("frames", "masks", "ground_truth", "point_clouds"):
        if (data / name).is_dir():
            (into / name).mkdir()
            for path in sorted((data / name).iterdir())[:frames]:
                (into / name / path.name).symlink_to(path.resolve())
    for path in data.iterdir():
        if not (into / path.name).exists():
            (into / path.name).symlink_to(path.resolve())
    return into


def run_ndf_sft(capture: Path, out: Path, extra: list[str]) -> tuple[dict, float, float]:
    """result.json of ``ndf-sft --capture``, the child's CPU seconds and the wall seconds."""
    command = [sys.executable, "-m", "inverse.cli.sft", "--capture", str(capture),
               "--out", str(out), *extra]
    print("$ " + " ".join(command), flush=True)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(command, check=False)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"ndf-sft exited with {done.returncode}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return json.loads((out / "result.json").read_text()), cpu, wall


def machine_text(machine) -> str:
    """ndf-sft's machine description (a dict) in a few words."""
    if not isinstance(machine, dict):
        return f"{platform.platform()}, {os.cpu_count()} cores"
    return (f"{machine.get('cpus', os.cpu_count())} cores {machine.get('processor', '')}, "
            f"{machine.get('platform', '')}, Python {machine.get('python', '')}, "
            f"{machine.get('arch', '')} {machine.get('precision', '')}")


def material_text(result: dict) -> str | None:
    """The estimated material of a result, as written by ndf-sft, or None."""
    for key in ("material", "material_estimate"):
        if result.get(key):
            return json.dumps(result[key])
    return None


def report(result: dict, cpu: float, wall: float, *, label: str, data: Path, extra: list[str],
           load: tuple[str, str]) -> str:
    """The run as markdown: the summary against the published values, per-frame values."""
    m = result["metrics"]
    n = result["frames"]
    per_frame = result["metrics_per_frame"]
    commit = provenance_commit()
    branch = subprocess.run(["git", "rev-parse", "--abbrev-ref", "HEAD"], capture_output=True,
                            text=True, check=False).stdout.strip() or "unknown"
    stamp = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        f"### {stamp} ({branch}, {commit}): {label}, {n} frames",
        "",
        f"`python benchmarks/sft_real.py --data {data}"
        + (f" {' '.join(extra)}" if extra else "") + "` — `ndf-sft --capture` as one child "
        "process, CPU from `getrusage(RUSAGE_CHILDREN)` (all threads, start-up included). "
        f"Machine: {machine_text(result.get('machine'))}; "
        f"load average {load[0]} before, {load[1]} after.",
        "",
        "| method | chamfer ×1e4 mean | worst frame | largest vertex-to-cloud distance | CPU s / "
        "frame | wall |",
        "|---|---|---|---|---|---|",
        f"| **ndf-sft, {label}** | **{m['chamfer_x1e4']:.2f}** | {m['chamfer_x1e4_worst']:.2f} "
        f"(frame {m['worst_frame']}) | {1000 * m['max_vertex_distance_m']:.0f} mm (frame "
        f"{m['max_vertex_distance_frame']}) | {cpu / n:.2f} | {wall:.0f} s |",
    ]
    lines += [f"| {name} (published) | {value} | | | | {cost} |" for name, value, cost
              in PUBLISHED]
    material = material_text(result)
    lines += ["", f"Target (issue 27): {TARGET}. Estimated material: "
              + (material if material else "none in result.json (not estimated by this run)")
              + ".", "", "Per frame (chamfer ×1e4 / largest vertex distance [mm]):", ""]
    rows = [f"{i}: {c:.2f} / {1000 * d:.0f}" for i, (c, d) in
            enumerate(zip(per_frame["chamfer_x1e4"], per_frame["max_vertex_distance_m"],
                          strict=True))]
    lines += ["    " + ", ".join(rows[i:i + 8]) for i in range(0, len(rows), 8)]
    confidence = result.get("confidence")
    if confidence:
        flagged = confidence["frames_with_unobserved_parts"]
        lines += ["", "Per-frame confidence (result.json `confidence`): frames with vertices "
                  f"farther than {confidence['reach_mean_edges']:g} mean edge lengths from every "
                  "tracked point (frame: vertices): "
                  + (", ".join(f"{i}: {confidence['unobserved_vertices'][i]}" for i in flagged)
                     if flagged else "none") + "."]
    return "\n".join(lines) + "\n"


def write_results(path: Path, text: str) -> None:
    """Put a run at the top of SECTION in RESULTS.md (the section appended if absent)."""
    content = path.read_text() if path.exists() else "# Benchmark results\n"
    if SECTION not in content:
        content = content.rstrip("\n") + f"\n\n{SECTION}\n\n" + (
            "`benchmarks/sft_real.py` (issue 27): the field's chamfer protocol (docs/sft.md §4) "
            "on φ-SfT's real sequence R1 (50 frames 1920 × 1080, Kinect clouds), read with "
            "`ndf-sft --capture` (docs/sft.md §7). Newest run first.\n")
    head, tail = content.split(SECTION, 1)
    intro, rest = (tail.split("\n### ", 1) + [""])[:2]
    rest = ("### " + rest) if rest else ""
    content = head + SECTION + intro.rstrip("\n") + "\n\n" + text + ("\n" + rest if rest else "")
    path.write_text(content)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    args = build_parser().parse_args(argv[:argv.index("--")] if "--" in argv else argv)
    if args.pinned:
        extra = ["--pinned", args.pinned, *extra]
    with tempfile.TemporaryDirectory() as temporary:
        capture = args.data
        if args.frames:
            (Path(temporary) / "capture").mkdir()
            capture = subset(args.data, args.frames, Path(temporary) / "capture")
        out = args.out or Path(temporary) / "out"
        load_before = f"{os.getloadavg()[0]:.1f}"
        result, cpu, wall = run_ndf_sft(capture, out, extra)
        load_after = f"{os.getloadavg()[0]:.1f}"
    shown = extra + ([f"--frames {args.frames}"] if args.frames else [])
    text = report(result, cpu, wall, label=args.label, data=args.data, extra=shown,
                  load=(load_before, load_after))
    print(text)
    if not args.no_write:
        write_results(args.results, text)
        print(f"written to {args.results}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
