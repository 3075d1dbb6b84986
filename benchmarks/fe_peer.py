"""FE peer (issue 28): taichi-ndf against Kratos Multiphysics on three shell benchmarks, back to
back in one run, every solve a child process on one thread.

    python benchmarks/fe_peer.py [--cases roof cylinder cantilever] [--levels 1 2 3]
                                 [--codes ours kratos] [--json PATH] [--keep DIR]

Cases (validation/cases/*.toml with their scenes under validation/scenes/): roof =
scordelis_lo_roof (−u_z at the middle of a free edge), cylinder = pinched_cylinder (the inward
radial displacement under the loads), cantilever = cantilever_shear (tip deflection W and
shortening −U at the load factors its case file reads; geometrically nonlinear).

Ours: level k is the command a user runs, `python -m taichi_ndf.cli.validate CASE.toml --field
spline --quick --out DIR`, on a copy of the case whose scene's [field] is a cubic spline on
the grid rule's spans × 2^(k−1) (level 1: the grid `--field spline` picks by itself, given
explicitly so every level is one grid solved from scratch; `--quick` = that one grid). The
linear cases are solved linearised as ndf-validate does. Kratos: `benchmarks/fe_peer_kratos.py`
(structured quads, ShellThinElementCorotational3D4N, SparseLU; the mesh of level k is the base
mesh × 2^(k−1)); skipped with one line where KratosMultiphysics is not importable (pip install
KratosMultiphysics==10.4.4 KratosStructuralMechanicsApplication==10.4.4
KratosLinearSolversApplication==10.4.4).

Per run: unknowns, the values, their error against the published reference (the case file)
and against the converged value (CASES below), CPU seconds of the whole child command (user +
sys from os.wait4), wall, peak RSS, and the solve's own wall seconds (ours: results.json's
wall_time; Kratos: assembly + solve). Then per case: CPU to ≤ 1 % of the reference (every
quantity) and to ≤ 0.1 % of the converged value for each code, and the ratio.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import commit as provenance_commit  # noqa: E402  (the commit each benchmark states)

KRATOS_SCRIPT = Path(__file__).resolve().parent / "fe_peer_kratos.py"
ONE_THREAD = {"TI_CPU_MAX_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
              "OPENBLAS_NUM_THREADS": "1"}
REFERENCE_TOLERANCE = 0.01  # the summary's "≤ 1 % of the reference"
CONVERGED_TOLERANCE = 0.001  # and "≤ 0.1 % of the converged value"


@dataclass(frozen=True)
class PeerCase:
    """A benchmark in both codes: the case file's name, the grid rule's spline spans at
    level 1 (at 6a1ae29; checked against what the run reports), Kratos's base mesh
    (quads along the scene's first, second surface coordinate), the default levels of each
    code, and the converged value of each quantity (label "name @ load factor")."""

    case_file: str
    spans: tuple[int, int]
    mesh: tuple[int, int]
    our_levels: tuple[int, ...]
    kratos_levels: tuple[int, ...]
    converged: dict[str, float]


# Converged values: the spline path's three-grid Richardson values (benchmarks/RESULTS.md,
# "spline_newton": roof 0.30053 ± 8e-9, cylinder 1.8268e-5 ± 6e-9; the cantilever's grids
# agree to all five digits). Each code's own finest levels are printed beside them as a check.
CASES = {
    "roof": PeerCase("scordelis_lo_roof", (14, 20), (8, 8), (1, 2, 3), (1, 2, 3, 4, 5),
                     {"-u_z @ 1": 0.30053}),
    "cylinder": PeerCase("pinched_cylinder", (63, 20), (32, 16), (1, 2, 3), (1, 2, 3, 4),
                         {"u_r @ 1": 1.8268e-5}),
    "cantilever": PeerCase("cantilever_shear", (8, 1), (10, 2), (1, 2, 3), (1, 2, 3, 4),
                           {"W @ 0.1": 1.3098, "-U @ 0.1": 0.10354, "W @ 0.5": 4.9347,
                            "-U @ 0.5": 1.6065, "W @ 1": 6.6999, "-U @ 1": 3.2895}),
}


def references(case: PeerCase) -> dict[str, float]:
    """The published reference of each quantity, from the case file."""
    with open(ROOT / "validation" / "cases" / f"{case.case_file}.toml", "rb") as f:
        doc = tomllib.load(f)
    return {f"{q['name']} @ {q.get('level', 1.0):g}": q["reference"] for q in doc["quantity"]}


def run_child(cmd: list[str], log: Path, timeout: float) -> dict:
    """Run `cmd` on one thread, stdout and stderr to `log`; its exit code, CPU seconds
    (user + sys of the child and what it waited for), wall seconds and peak RSS [MB]."""
    env = {**os.environ, **ONE_THREAD, "PYTHONPATH": str(ROOT)}
    start = time.perf_counter()
    with open(log, "w") as out:
        proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, env=env, cwd=ROOT)
        deadline = start + timeout
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.perf_counter() > deadline:
                proc.kill()
                pid, status, usage = os.wait4(proc.pid, 0)
                break
            time.sleep(0.05)
    proc.returncode = os.waitstatus_to_exitcode(status)
    return {"rc": proc.returncode, "cpu_s": usage.ru_utime + usage.ru_stime,
            "user_s": usage.ru_utime, "sys_s": usage.ru_stime,
            "wall_s": time.perf_counter() - start, "rss_mb": usage.ru_maxrss / 1024}


def spline_scene(scene: Path, spans: tuple[int, int], dest: Path) -> Path:
    """A copy of `scene` whose [field] is a spline on `spans` and whose [training] keeps only
    load_steps and seed (what `--field spline` keeps) with method = "newton"."""
    with open(scene, "rb") as f:
        training = tomllib.load(f).get("training", {})
    kept, dropping = [], False
    for line in scene.read_text().splitlines():
        header = line.strip()
        if header.startswith("[") and not header.startswith("[["):
            dropping = header.split("#")[0].strip() in ("[field]", "[training]",
                                                        "[training.quick]")
        elif header.startswith("[["):
            dropping = False
        if not dropping:
            kept.append(line)
    extra = [f"[field]\ntype = \"spline\"\nspans = [{spans[0]}, {spans[1]}]\n", "[training]",
             "method = \"newton\""]
    if "load_steps" in training:
        extra.append(f"load_steps = {json.dumps(training['load_steps'])}")
    if "seed" in training:
        extra.append(f"seed = {training['seed']}")
    dest.write_text("\n".join(kept) + "\n\n" + "\n".join(extra) + "\n")
    return dest


def ours(case: PeerCase, level: int, work: Path, timeout: float) -> dict:
    """Level `level` of taichi-ndf: ndf-validate on one explicit spline grid."""
    spans = (case.spans[0] * 2 ** (level - 1), case.spans[1] * 2 ** (level - 1))
    tag = f"{case.case_file}_ours_{level}"
    src = ROOT / "validation" / "cases" / f"{case.case_file}.toml"
    with open(src, "rb") as f:
        scene_rel = tomllib.load(f)["scene"]
    scene = spline_scene((src.parent / scene_rel).resolve(), spans, work / f"{tag}_scene.toml")
    text = src.read_text().replace(f'"{scene_rel}"', json.dumps(str(scene)))
    case_path = work / f"{tag}.toml"
    case_path.write_text(text)
    out = work / tag
    cmd = [sys.executable, "-m", "taichi_ndf.cli.validate", str(case_path), "--field", "spline",
           "--quick", "--precision", "f64", "--out", str(out)]
    run = run_child(cmd, work / f"{tag}.log", timeout)
    row = {"code": "taichi-ndf", "level": level, "mesh": f"{spans[0]} × {spans[1]} spans",
           **run, "values": {}, "unknowns": None, "solve_s": None}
    try:
        result = json.loads((out / "results.json").read_text())
    except (OSError, ValueError):
        return row
    for r in result["rows"]:
        if r["computed"] is not None:
            row["values"][f"{r['quantity']} @ {r['level']:g}"] = r["computed"]
    row["solve_s"] = max(r["wall_time"] for r in result["rows"])
    field = result["cases"][case.case_file]["solver"]["field"]
    if tuple(field["spans"]) != spans:
        row["warning"] = f"solved on {field['spans']}, asked {list(spans)}"
    coefficients = 1
    for n, periodic in zip(field["spans"], field["periodic"], strict=True):
        coefficients *= n if periodic else n + field["degree"]
    row["unknowns"] = coefficients * field["out_dim"]
    return row


def kratos(name: str, case: PeerCase, level: int, work: Path, timeout: float) -> dict:
    """Level `level` of Kratos: fe_peer_kratos.py on the base mesh × 2^(level − 1)."""
    nx, ny = (m * 2 ** (level - 1) for m in case.mesh)
    log = work / f"{case.case_file}_kratos_{level}.log"
    run = run_child([sys.executable, str(KRATOS_SCRIPT), name, str(nx), str(ny)], log, timeout)
    row = {"code": "Kratos", "level": level, "mesh": f"{nx} × {ny} quads", **run,
           "values": {}, "unknowns": None, "solve_s": None}
    for line in log.read_text().splitlines():
        if line.startswith("{"):
            result = json.loads(line)
            row["values"] = result.get("values", {})
            row["unknowns"] = result.get("dofs")
            row["solve_s"] = result.get("seconds", {}).get("solve")
            if "error" in result:
                row["warning"] = result["error"]
    return row


def kratos_missing() -> str | None:
    """Why Kratos cannot run here (one line), or None."""
    probe = subprocess.run(
        [sys.executable, "-c", "import KratosMultiphysics, "
         "KratosMultiphysics.StructuralMechanicsApplication, "
         "KratosMultiphysics.LinearSolversApplication"],
        capture_output=True, text=True, env={**os.environ, **ONE_THREAD}, cwd=ROOT)
    if probe.returncode == 0:
        return None
    lines = probe.stderr.strip().splitlines()
    return lines[-1] if lines else f"exit code {probe.returncode}"


def errors(row: dict, refs: dict[str, float], converged: dict[str, float]) -> None:
    """Add each quantity's relative error against the reference and the converged value, and
    the largest of each (None where a quantity is missing)."""
    row["error_ref"] = {k: abs(v / refs[k] - 1) for k, v in row["values"].items() if k in refs}
    row["error_conv"] = {k: abs(v / converged[k] - 1) for k, v in row["values"].items()
                         if k in converged}
    complete = row["rc"] == 0 and set(row["values"]) >= set(refs)
    row["max_error_ref"] = max(row["error_ref"].values()) if complete else None
    row["max_error_conv"] = max(row["error_conv"].values()) if complete else None


def table(rows: list[dict], labels: list[str]) -> str:
    """The Markdown table of one case's runs."""
    head = ["code", "level", "mesh", "unknowns", *labels, "max err ref %", "max err conv %",
            "CPU s", "wall s", "peak RSS MB", "solve wall s"]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        def pct(x):
            return "–" if x is None else f"{100 * x:.3f}"
        vals = [f"{r['values'][k]:.6g}" if k in r["values"] else "–" for k in labels]
        cells = [r["code"], str(r["level"]), r["mesh"], str(r["unknowns"] or "–"), *vals,
                 pct(r["max_error_ref"]), pct(r["max_error_conv"]), f"{r['cpu_s']:.2f}",
                 f"{r['wall_s']:.2f}", f"{r['rss_mb']:.0f}",
                 "–" if r["solve_s"] is None else f"{r['solve_s']:.2f}"]
        if r["rc"] != 0 or "warning" in r:
            cells[0] += f" (rc {r['rc']}{'; ' + r['warning'] if 'warning' in r else ''})"
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out)


def first_within(rows: list[dict], code: str, key: str, tol: float) -> dict | None:
    """The cheapest run of `code` (least CPU) whose largest error `key` is ≤ tol."""
    hits = [r for r in rows if r["code"] == code and r[key] is not None and r[key] <= tol]
    return min(hits, key=lambda r: r["cpu_s"]) if hits else None


def summary(name: str, rows: list[dict]) -> list[dict]:
    """Per criterion: CPU of the cheapest run of each code meeting it, and the ratio."""
    out = []
    for key, tol, what in (("max_error_ref", REFERENCE_TOLERANCE, "≤ 1 % of the reference"),
                           ("max_error_conv", CONVERGED_TOLERANCE, "≤ 0.1 % of converged")):
        a, b = (first_within(rows, c, key, tol) for c in ("taichi-ndf", "Kratos"))
        out.append({"case": name, "criterion": what,
                    "ours": None if a is None else {"level": a["level"], "cpu_s": a["cpu_s"]},
                    "kratos": None if b is None else {"level": b["level"], "cpu_s": b["cpu_s"]},
                    "ratio": a["cpu_s"] / b["cpu_s"] if a and b else None})
    return out


def summary_table(items: list[dict]) -> str:
    out = ["| case | criterion | taichi-ndf CPU s (level) | Kratos CPU s (level) | "
           "ratio ours / Kratos |", "|---|---|---|---|---|"]
    for s in items:
        def cell(x):
            return "not reached" if x is None else f"{x['cpu_s']:.2f} ({x['level']})"
        ratio = "–" if s["ratio"] is None else f"{s['ratio']:.2f}"
        out.append(f"| {s['case']} | {s['criterion']} | {cell(s['ours'])} | "
                   f"{cell(s['kratos'])} | {ratio} |")
    return "\n".join(out)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES),
                   help="cases to run (default: all three)")
    p.add_argument("--levels", nargs="+", type=int, metavar="K",
                   help="levels to run in both codes (default: each code's list per case: "
                   + "; ".join(f"{n} ours {list(c.our_levels)}, Kratos {list(c.kratos_levels)}"
                               for n, c in CASES.items()) + ")")
    p.add_argument("--codes", nargs="+", choices=["ours", "kratos"], default=["ours", "kratos"],
                   help="codes to run (default: both)")
    p.add_argument("--json", type=Path, metavar="PATH", help="also write the tables as JSON")
    p.add_argument("--keep", type=Path, metavar="DIR",
                   help="keep the runs' logs and outputs in DIR (default: a temporary folder)")
    p.add_argument("--timeout", type=float, default=1800.0, help="seconds per child (1800)")
    args = p.parse_args(argv)
    if args.levels is not None and any(k < 1 or k > 6 for k in args.levels):
        p.error(f"--levels: each level must be 1 to 6, got {args.levels}")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    missing = kratos_missing() if "kratos" in args.codes else None
    codes = [c for c in args.codes if not (c == "kratos" and missing)]
    if missing:
        print(f"fe_peer: Kratos skipped (not importable: {missing})", flush=True)
    load = os.getloadavg()
    commit = provenance_commit()
    print(f"commit {commit}, load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} at start, "
          f"{os.cpu_count()} CPUs", flush=True)
    report = {"commit": commit, "load_start": load, "kratos_skipped": missing, "cases": {}}
    with tempfile.TemporaryDirectory(prefix="fe_peer_") as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        summaries = []
        for name in args.cases:
            case = CASES[name]
            refs = references(case)
            rows = []
            for code in codes:
                levels = args.levels or (case.our_levels if code == "ours"
                                         else case.kratos_levels)
                for level in levels:
                    row = (ours(case, level, work, args.timeout) if code == "ours"
                           else kratos(name, case, level, work, args.timeout))
                    errors(row, refs, case.converged)
                    rows.append(row)
                    print(f"  {name} {row['code']} level {level} ({row['mesh']}): "
                          f"CPU {row['cpu_s']:.2f} s, wall {row['wall_s']:.2f} s, "
                          f"rc {row['rc']}", flush=True)
            labels = list(refs)
            print(f"\n### {name} ({case.case_file})\n\n{table(rows, labels)}\n", flush=True)
            summaries += summary(name, rows)
            report["cases"][name] = {"references": refs, "converged": case.converged,
                                     "rows": rows}
        report["summary"] = summaries
        report["load_end"] = os.getloadavg()
        print(summary_table(summaries))
        end = report["load_end"]
        print(f"\nload average {end[0]:.2f} {end[1]:.2f} {end[2]:.2f} at the end")
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
