"""Every shipped scene solved by both fields: SIREN + Adam (the scene as written) and spline +
projected Newton (`ndf-sim --field spline`: the grid rule's grid, one level, the scene's load
steps). Each run is `ndf-sim` in its own process (one ti.init per process, one thread).

Per scene and field: Π reached [J], the relative gap (Π_spline − Π_SIREN) / |Π_SIREN|
(negative: the spline found the lower energy), wall time [s] of the whole process (start,
compilation, solve, outputs), the solve time result.json reports, the peak resident memory
[MiB] of the child process (ru_maxrss of its own rusage from `os.wait4`, Linux: KiB; the
high-water mark of that process alone; its CPU time, user + system, is stored too),
iterations (Adam: the fixed count; Newton: all iterations and whether every load step
converged; the JSON store also keeps the last Newton steps and how many iterations used the
projected Hessian). A scene whose spline run is refused
(exit 2, e.g. obstacles: contact is not on the Newton path yet) is listed as refused.

Results are kept per (scene, field) in benchmarks/spline_vs_siren.json, so a subset can be
rerun (`--scenes`, `--fields`) and the table is rebuilt from all stored results: the section
between the markers in benchmarks/RESULTS.md, and small renders of both results,
docs/images/compare/SCENE_FIELD.png, shown side by side in docs/spline_vs_siren.md.

    python benchmarks/spline_vs_siren.py                      # every scene, both fields
    python benchmarks/spline_vs_siren.py --fields spline      # rerun the spline column
    python benchmarks/spline_vs_siren.py --scenes napkin,flag --fields siren
    python benchmarks/spline_vs_siren.py --table-only         # rebuild the table
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import commit  # noqa: E402  (the commit each benchmark states)

SCENES = ROOT / "scenes"
STORE = ROOT / "benchmarks" / "spline_vs_siren.json"
RESULTS = ROOT / "benchmarks" / "RESULTS.md"
GALLERY = ROOT / "docs" / "spline_vs_siren.md"
RENDERS = ROOT / "docs" / "images" / "compare"
FIELDS = {"siren": [], "spline": ["--field", "spline"]}
LABELS = {"siren": "SIREN + Adam", "spline": "spline + Newton"}
BEGIN = "<!-- spline_vs_siren.py: begin (generated, do not edit) -->"
END = "<!-- spline_vs_siren.py: end -->"
RENDER_SIZE = "360x270"


def shipped_scenes() -> list[str]:
    return [p.stem for p in sorted(SCENES.glob("*.toml"))]



def scene_material(scene: str) -> str:
    """The scene's [material] table as compact JSON: a stored run whose material differs is
    shown in the table and on the renders page as not rerun, without its numbers."""
    import tomllib

    table = tomllib.loads((SCENES / f"{scene}.toml").read_text()).get("material", {})
    return json.dumps(table, sort_keys=True, separators=(",", ":"))


def run_one(scene: str, field: str, out: Path, precision: str, quick: bool,
            extra: tuple[str, ...] = ()) -> dict:
    """One ndf-sim process: Π, times, peak memory, iterations (or why it did not run).
    extra: further ndf-sim arguments (e.g. --resume)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    command = [sys.executable, "-m", "taichi_ndf.cli.sim", str(SCENES / f"{scene}.toml"),
               "--out", str(out), "--precision", precision, "--arch", "cpu", *FIELDS[field],
               *(["--quick"] if quick else []), *extra]
    load_before = os.getloadavg()[0]
    started = time.perf_counter()
    process = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE)
    stderr = process.stderr.read().decode(errors="replace")
    _, status, usage = os.wait4(process.pid, 0)
    record = {"wall": time.perf_counter() - started, "peak_mib": usage.ru_maxrss / 1024,
              "cpu": usage.ru_utime + usage.ru_stime,
              "load": [round(load_before, 2), round(os.getloadavg()[0], 2)],
              "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
              "commit": commit(), "precision": precision, "quick": quick,
              "material": scene_material(scene)}
    code = os.waitstatus_to_exitcode(status)
    if code != 0:
        lines = [line for line in stderr.strip().splitlines() if line.strip()]
        return {**record, "status": "refused" if code == 2 else "failed", "exit_code": code,
                "message": lines[-1] if lines else f"exit code {code}"}
    result = json.loads((out / "result.json").read_text())
    record.update(status="ok", energy=result["energy"], solve=result["wall_time"],
                  iterations=result["iterations"])
    if "backoffs" in result:  # the SIREN path: Adam's learning-rate backoffs, its output scale
        record.update(backoffs=result["backoffs"],
                      output_scale=result["resolved"]["field"]["output_scale"])
    if "levels" in result:
        history = result["history"]
        record.update(converged=all(lv["converged"] for lv in result["levels"]),
                      spans=result["resolved"]["field"]["finest_spans"],
                      # how the Newton run ended: Π, λ², α, projected blocks of its last steps
                      newton_tail=[[h["energy"], h["decrement"], h["step_length"],
                                    h["projected_blocks"]] for h in history[-5:]],
                      projected_iterations=sum(h["projected_blocks"] > 0 for h in history))
    return record


def render(out: Path, target: Path) -> None:
    """A small render of a finished run (ndf-render, iso view) at `target`."""
    subprocess.run([sys.executable, "-m", "taichi_ndf.cli.render", str(out), "--size",
                    RENDER_SIZE, "--out", str(target), "--overwrite"], check=True,
                   stdout=subprocess.DEVNULL, env={**os.environ, "OMP_NUM_THREADS": "1"})


def _stale(scene: str, r: dict) -> bool:
    """Run with another material than the scene has now."""
    return (SCENES / f"{scene}.toml").is_file() and r.get("material") != scene_material(scene)


def _gap(scene: str, rows: dict) -> str:
    siren, spline = rows.get("siren", {}), rows.get("spline", {})
    if siren.get("status") != "ok" or spline.get("status") != "ok":
        return ""
    if _stale(scene, siren) or _stale(scene, spline):
        return "(materials differ)"
    return f"{100 * (spline['energy'] - siren['energy']) / abs(siren['energy']):+.2f} %"


def _row(scene: str, field: str, r: dict | None, gap: str) -> str:
    label = LABELS[field]
    if r is None:
        return f"| {scene} | {label} | not run | | | | | |"
    if r["status"] != "ok":
        reason = r["message"]
        if r["status"] == "refused" and "contact" in reason:
            reason = "refused (contact on Newton path: pending)"
        else:
            reason = f"{r['status']}: {reason}"
        return f"| {scene} | {label} | {reason} | | {r['wall']:.0f} | | " \
               f"{r['peak_mib']:.0f} | |"
    if field == "spline":
        spans = " × ".join(str(s) for s in r.get("spans", []))
        its = f"{r['iterations']} ({'converged' if r['converged'] else 'NOT converged'}, " \
              f"{spans} spans)"
    elif "output_scale" in r:  # recorded since "auto" became the equilibrium estimate
        n = r["backoffs"]
        backoffs = f", {n} backoff{'s' if n > 1 else ''}" if n else ""
        its = f"{r['iterations']} (fixed; output scale {r['output_scale']:.3g} m{backoffs})"
    else:
        its = f"{r['iterations']} (fixed; dimensional output scale)"
    quick = " (quick)" if r.get("quick") else ""
    if r.get("precision") == "f64":  # e.g. the gallery's runs (docs/make_gallery.py)
        quick += " (f64)"
    if r.get("start"):  # a gallery run re-solved from a perturbed state
        quick += f" (from {r['start']})"
    if _stale(scene, r):  # its numbers belong to another material: not shown
        return (f"| {scene} | {label} | not rerun since the scene's material became "
                f"`{scene_material(scene)}` (the stored run of {r['date']} used "
                f"`{r.get('material')}`) | | | | | |")
    return (f"| {scene} | {label}{quick} | {r['energy']:.6g} | {gap} | {r['wall']:.0f} | "
            f"{r['solve']:.0f} | {r['peak_mib']:.0f} | {its} |")


def table(store: dict) -> str:
    """The generated RESULTS.md section body: how it was measured and one row per run."""
    dates = sorted(r["date"] for rows in store.values() for r in rows.values())
    loads = [x for rows in store.values() for r in rows.values() for x in r["load"]]
    commits = sorted({r["commit"] for rows in store.values() for r in rows.values()})
    lines = [
        "`python benchmarks/spline_vs_siren.py` (each run `ndf-sim` in its own process, "
        "`--arch cpu`, one thread; SIREN + Adam: the scene as written; spline + Newton: "
        "`ndf-sim --field spline`, cubic, the grid rule's grid, one level, the scene's load "
        "steps). Gap: (Π_spline − Π_SIREN) / |Π_SIREN|, negative where the spline found the "
        "lower energy. Wall: the whole process (start, kernel compilation, solve, outputs); "
        "solve: result.json's wall_time. Peak: ru_maxrss of the child process (`os.wait4`), "
        "the peak resident memory of that process. Π is each run's own quadrature of the same "
        "integral (SIREN: monitor samples; spline: Gauss points).",
        "",
        f"Runs {dates[0]} – {dates[-1]} (commits {', '.join(commits)}), 2 CPU cores shared "
        f"with other sessions: 1-minute load average {min(loads):.1f}–{max(loads):.1f} at the "
        "starts and ends of the runs, so times are noisy upper bounds.",
        "",
        "| scene | field | Π [J] | gap | wall [s] | solve [s] | peak [MiB] | iterations |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for scene in sorted(set(shipped_scenes()) | set(store)):
        rows = store.get(scene, {})
        gap = _gap(scene, rows)
        for field in FIELDS:
            lines.append(_row(scene, field, rows.get(field), gap if field == "spline" else ""))
    return "\n".join(lines)


def renders(store: dict) -> str:
    """The generated part of docs/spline_vs_siren.md: both renders of each scene side by side
    (or why a run has none)."""
    lines = [f"| scene | {LABELS['siren']} | {LABELS['spline']} |", "|---|---|---|"]
    for scene in sorted(set(shipped_scenes()) | set(store)):
        cells = []
        for field in FIELDS:
            r = store.get(scene, {}).get(field)
            image = RENDERS / f"{scene}_{field}.png"
            if r is not None and _stale(scene, r):
                cells.append("not rerun on the scene's material")
            elif r is not None and r["status"] == "ok" and image.is_file():
                cells.append(f"![{scene}, {LABELS[field]}]"
                             f"({image.relative_to(GALLERY.parent).as_posix()})")
            else:
                cells.append("not run" if r is None else
                             "no render" if r["status"] == "ok" else r["status"])
        lines.append(f"| {scene} | {' | '.join(cells)} |")
    return "\n".join(lines)


def replace_section(path: Path, body: str, heading: str) -> None:
    """Replace the text between BEGIN and END in `path` by `body` (appended under `heading`
    if the markers are missing)."""
    text = path.read_text()
    block = f"{BEGIN}\n{body}\n{END}"
    if BEGIN in text and END in text:
        head, rest = text.split(BEGIN, 1)
        text = head + block + rest.split(END, 1)[1]
    else:
        text = text.rstrip("\n") + f"\n\n{heading}\n\n{block}\n"
    path.write_text(text)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default=",".join(shipped_scenes()),
                        help="comma-separated scene names (default: every scenes/*.toml)")
    parser.add_argument("--fields", default=",".join(FIELDS),
                        help="comma-separated fields to run: siren, spline (default: both)")
    parser.add_argument("--precision", choices=("f32", "f64"), default="f32")
    parser.add_argument("--quick", action="store_true",
                        help="the scenes' [training.quick] settings (a smoke test of this "
                        "script; its rows are marked quick)")
    parser.add_argument("--table-only", action="store_true",
                        help="run nothing; rebuild the table from the stored results")
    args = parser.parse_args()
    scenes = [s for s in args.scenes.split(",") if s]
    fields = [f for f in args.fields.split(",") if f]
    for name in scenes:
        if not (SCENES / f"{name}.toml").is_file():
            parser.error(f"--scenes: no scene {name!r} in {SCENES}")
    for field in fields:
        if field not in FIELDS:
            parser.error(f"--fields: {field!r} is not one of {', '.join(FIELDS)}")
    store = json.loads(STORE.read_text()) if STORE.is_file() else {}
    RENDERS.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        for name in scenes if not args.table_only else []:
            for field in fields:
                out = Path(tmp) / f"{name}_{field}"
                record = run_one(name, field, out, args.precision, args.quick)
                if record["status"] == "ok":
                    render(out, RENDERS / f"{name}_{field}.png")
                # reread: another invocation (e.g. the other field) may have stored meanwhile
                store = json.loads(STORE.read_text()) if STORE.is_file() else {}
                store.setdefault(name, {})[field] = record
                STORE.write_text(json.dumps(store, indent=1, sort_keys=True) + "\n")
                print(json.dumps({name: {field: record}}), flush=True)
    if store:
        replace_section(RESULTS, table(store), "## Spline + Newton against SIREN + Adam "
                        "(benchmarks/spline_vs_siren.py, issue 19)")
        replace_section(GALLERY, renders(store), "## Renders")
        print(table(store))


if __name__ == "__main__":
    main()
