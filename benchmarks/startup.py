"""Fixed cost of the tools (issue 28): CPU and wall from process start to the first Newton
iteration, to the result line and to the end, on a cold and on a warm Taichi offline cache.

    python benchmarks/startup.py [--commands help sim validate demo] [--full]
                                 [--out DIR] [--repeat 1]

Every run is a child process (`python benchmarks/startup.py --child MARKS.json -- TARGET ARGS`)
that runs a tool's module (``-m`` name) or a script in itself and records marks: CPU (user +
sys of the process, `resource.getrusage`) and wall (seconds since the parent started it) at the
first progress report of a Newton load stage (the first Newton iteration done: its Π and
decrement reported), and at every line the tool prints. Without `--full` the child ends at
that first Newton iteration; with it the run goes to the end and the table has the CPU to
the command's result line (pattern per command) and the whole process (the parent's
`os.wait4`, children such as an ffmpeg encoder included).

Cold: `TAICHI_NDF_CACHE` pointed at a fresh temporary folder (the runtime keeps Taichi's
offline cache under it); warm: the same folder on the next run. Prints Markdown tables with
the load average and the commit.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import runpy
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BYTECODE = False  # --pyc: the children write and read __pycache__ (see main)

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import commit  # noqa: E402  (the commit each benchmark states)

SCENES = ROOT / "scenes"
TOOLS = ("sim", "validate", "render", "export", "sweep", "view")


def commands(out: Path) -> dict[str, tuple[list[str], str]]:
    """Name -> (target and arguments, a text that starts the command's result line)."""
    return {
        "validate cantilever_shear": (
            ["-m", "taichi_ndf.cli.validate", "cantilever_shear", "--field", "spline",
             "--out", str(out / "v_shear")], "cantilever_shear "),
        "validate scordelis_lo_roof": (
            ["-m", "taichi_ndf.cli.validate", "scordelis_lo_roof", "--field", "spline",
             "--out", str(out / "v_roof")], "scordelis_lo_roof "),
        "sim napkin --field spline": (
            ["-m", "taichi_ndf.cli.sim", str(SCENES / "napkin.toml"), "--field", "spline",
             "--out", str(out / "s_napkin")], "napkin: Π"),
        "sim membrane_stretch, 4 load steps": (  # outputs with a trajectory video
            ["-m", "taichi_ndf.cli.sim", str(SCENES / "membrane_stretch.toml"), "--field",
             "spline", "--quick", "--set", "training.load_steps=[0.25, 0.5, 0.75, 1.0]",
             "--out", str(out / "s_stretch")], "membrane_stretch: Π"),
        "demos/napkin.py": (
            [str(ROOT / "demos" / "napkin.py"), "--out", str(out / "d_napkin")],
            "free corner"),
    }


# --- the child: run a target in this process and record marks ---------------------------

def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


class _Marks:
    def __init__(self, path: Path, started: float, stop_at_newton: bool):
        self.path, self.started, self.stop = path, started, stop_at_newton
        self.marks: list[dict] = []

    profiler = None  # a cProfile.Profile when the child profiles (STARTUP_PROFILE=FILE)

    def add(self, what: str, text: str = "") -> None:
        self.marks.append({"what": what, "text": text[:200], "cpu": cpu_seconds(),
                           "wall": time.time() - self.started})
        self.path.write_text(json.dumps(self.marks))

    def progress(self, report) -> None:
        if (report.stage.startswith("Newton") and "load" in report.stage and report.step >= 1
                and not any(m["what"] == "newton" for m in self.marks)):
            self.add("newton", report.stage)
            if os.environ.get("STARTUP_MODULES"):  # which modules a run needed to get here
                Path(os.environ["STARTUP_MODULES"]).write_text("\n".join(sorted(sys.modules)))
            if self.stop:
                sys.stdout.flush()
                _write_cache()  # what a finished run writes at exit; os._exit would skip it
                if self.profiler is not None:
                    self.profiler.disable()
                    self.profiler.dump_stats(os.environ["STARTUP_PROFILE"])
                os._exit(0)


def _write_cache() -> None:
    """Taichi writes the kernels it compiled to its offline cache when the program ends (at
    exit, or at a reset): do it before a child stops at its first Newton iteration."""
    from taichi_ndf import runtime

    if runtime.is_initialised():
        runtime.reset()


class _Lines:
    """stdout that marks every line printed."""

    def __init__(self, stream, marks: _Marks):
        self.stream, self.marks, self.buffer = stream, marks, ""

    def write(self, text: str) -> int:
        self.buffer += text
        while "\n" in self.buffer:
            line, self.buffer = self.buffer.split("\n", 1)
            self.marks.add("line", line)
        return self.stream.write(text)

    def __getattr__(self, name):
        return getattr(self.stream, name)


def _mark_init(marks: _Marks) -> None:
    """Marks "init" and "init done" around `taichi_ndf.init` (what the tools call through
    `cli.common.start`): the imports before it, the Taichi runtime's start in it."""
    from taichi_ndf import runtime

    init = runtime.init

    def marked(*args, **kwargs):
        marks.add("init")
        try:
            return init(*args, **kwargs)
        finally:
            marks.add("init done")

    runtime.init = marked


OUTPUT_WRITERS = ("write_field_outputs", "deformed_mesh", "write_mesh_files",
                  "write_reference_mesh", "write_probe_points", "write_render", "write_energy_plot",
                  "write_trajectory_mesh", "write_trajectory_video", "_finish")


def _time_outputs(marks: _Marks) -> None:
    """Mark the CPU each output writer of `simulate` takes ("output NAME", the CPU seconds of
    the call as its text), and the checkpoint writes."""
    from taichi_ndf.app import outputs, simulation
    from taichi_ndf.minimise import callbacks

    def timed(name, function):
        def run(*args, **kwargs):
            start = cpu_seconds()
            try:
                return function(*args, **kwargs)
            finally:
                marks.add(f"output {name}", f"{cpu_seconds() - start:.4f}")

        return run

    for name in OUTPUT_WRITERS:  # where each is looked up when called (writers have moved)
        for module in (simulation, outputs):
            if hasattr(module, name):
                setattr(module, name, timed(name, getattr(module, name)))
    writer = callbacks.CheckpointWriter
    for name in ("on_level", "on_end", "on_iteration"):
        if hasattr(writer, name):
            setattr(writer, name, timed(f"checkpoint.{name}", getattr(writer, name)))


def child(marks_path: Path, started: float, stop_at_newton: bool, target: list[str]) -> int:
    from taichi_ndf import progress

    marks = _Marks(marks_path, started, stop_at_newton)
    marks.add("python")
    if os.environ.get("STARTUP_PROFILE"):
        import cProfile

        marks.profiler = cProfile.Profile()
        marks.profiler.enable()
    sys.stdout = _Lines(sys.stdout, marks)
    _mark_init(marks)
    if os.environ.get("STARTUP_OUTPUTS"):
        _time_outputs(marks)
    with progress.listening(marks.progress):
        try:
            if target[0] == "-m":
                sys.argv = [target[1], *target[2:]]
                runpy.run_module(target[1], run_name="__main__", alter_sys=True)
            else:
                sys.argv = list(target)
                sys.path.insert(0, str(Path(target[0]).parent))
                runpy.run_path(target[0], run_name="__main__")
        except SystemExit as done:
            code = done.code if isinstance(done.code, int) else (0 if done.code is None else 1)
        else:
            code = 0
    marks.add("end")
    if marks.profiler is not None:
        marks.profiler.disable()
        marks.profiler.dump_stats(os.environ["STARTUP_PROFILE"])
    return code


# --- the parent ----------------------------------------------------------------------------

def run(target: list[str], cache: Path, workdir: Path, *, stop_at_newton: bool,
        outputs: bool = False) -> dict:
    """One child run; its marks, exit code and whole-process CPU (children included);
    `outputs`: with the CPU of each output writer marked."""
    marks_path = workdir / f"marks_{time.monotonic_ns()}.json"
    env = dict(os.environ, TAICHI_NDF_CACHE=str(cache), OMP_NUM_THREADS="1",
               PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    if BYTECODE:  # a user's Python: modules compiled once, then loaded from __pycache__
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        env.pop("PYTHONPYCACHEPREFIX", None)
    if outputs:
        env["STARTUP_OUTPUTS"] = "1"
    started = time.time()
    process = subprocess.Popen(
        [sys.executable, str(Path(__file__).resolve()), "--child", str(marks_path),
         "--started", repr(started), *(["--stop-at-newton"] if stop_at_newton else []),
         "--", *target], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(process.pid, 0)
    wall = time.time() - started
    output = process.stdout.read().decode(errors="replace")
    errors = process.stderr.read().decode(errors="replace")
    marks = json.loads(marks_path.read_text()) if marks_path.exists() else []
    code = os.waitstatus_to_exitcode(status)
    if code != 0:
        print(f"warning: {' '.join(target)} exited {code}: {errors.strip()[-400:]}",
              file=sys.stderr)
    return {"marks": marks, "code": code, "cpu": usage.ru_utime + usage.ru_stime, "wall": wall,
            "maxrss_mb": usage.ru_maxrss / 1024, "stdout": output}


def output_costs(marks: list[dict]) -> dict[str, tuple[int, float]]:
    """Output writer -> (calls, CPU seconds) from a run's "output NAME" marks."""
    costs: dict[str, tuple[int, float]] = {}
    for mark in marks:
        if mark["what"].startswith("output "):
            calls, cpu = costs.get(mark["what"][7:], (0, 0.0))
            costs[mark["what"][7:]] = (calls + 1, cpu + float(mark["text"]))
    return costs


def first(marks: list[dict], what: str, text: str = "") -> dict | None:
    return next((m for m in marks if m["what"] == what and m["text"].startswith(text)), None)


def _cell(mark: dict | None) -> str:
    return "–" if mark is None else f"{mark['cpu']:.2f} / {mark['wall']:.2f}"


def help_table(workdir: Path, repeat: int) -> list[str]:
    rows = ["| tool | CPU s (user+sys) | wall s | imports taichi / torch |", "|---|---|---|---|"]
    for tool in TOOLS:
        best = None
        for _ in range(repeat):
            result = run(["-m", f"taichi_ndf.cli.{tool}", "--help"], workdir / "cache_help",
                         workdir, stop_at_newton=False)
            if best is None or result["cpu"] < best["cpu"]:
                best = result
        loaded = subprocess.run(
            [sys.executable, "-c", "import sys, runpy; sys.argv = ['x', '--help']\n"
             f"try: runpy.run_module('taichi_ndf.cli.{tool}', run_name='__main__')\n"
             "except SystemExit: pass\n"
             "print('taichi' in sys.modules, 'torch' in sys.modules, file=sys.stderr)"],
            env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True, text=True)
        rows.append(f"| ndf-{tool} --help | {best['cpu']:.2f} | {best['wall']:.2f} | "
                    f"{' / '.join(loaded.stderr.split()[-2:])} |")
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--started", type=float, help=argparse.SUPPRESS)
    parser.add_argument("--stop-at-newton", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--commands", nargs="*", default=None,
                        help="which: help, and names starting like those of the table "
                        "(default: all)")
    parser.add_argument("--full", action="store_true",
                        help="run each command to its end (result line and outputs), not only "
                        "to the first Newton iteration")
    parser.add_argument("--repeat", type=int, default=1, help="warm runs per command")
    parser.add_argument("--outputs", action="store_true",
                        help="with --full: also the CPU of each output writer (last warm run)")
    parser.add_argument("--args", nargs="*", default=[], metavar="ARG",
                        help="further arguments for every command (e.g. --precision=f32)")
    parser.add_argument("--out", type=Path, help="folder of the runs (default: a temporary one)")
    parser.add_argument("--pyc", action="store_true",
                        help="let the children write and load Python bytecode (__pycache__) "
                        "even where PYTHONDONTWRITEBYTECODE is set, as a user's install does "
                        "(in this sandbox it is set: every module compiled from source, "
                        "0.2-0.5 s CPU of a start)")
    args, target = parser.parse_known_args(argv)
    if args.child:
        return child(args.child, args.started, args.stop_at_newton,
                     [t for t in target if t != "--"])
    if args.repeat < 1:
        parser.error("--repeat must be >= 1")
    global BYTECODE
    BYTECODE = args.pyc
    if BYTECODE:  # compile ROOT's modules once, so that no measured run pays for it
        subprocess.run([sys.executable, "-m", "compileall", "-q", str(ROOT / "taichi_ndf")],
                       env={k: v for k, v in os.environ.items()
                            if k != "PYTHONDONTWRITEBYTECODE"}, check=False)
    workdir = Path(args.out or tempfile.mkdtemp(prefix="ndf_startup_"))
    workdir.mkdir(parents=True, exist_ok=True)
    wanted = args.commands
    writes = BYTECODE or not os.environ.get("PYTHONDONTWRITEBYTECODE")
    print(f"commit {commit()}, load average {os.getloadavg()[0]:.2f} at start, "
          f"{os.cpu_count()} CPUs, {sys.executable}, Python bytecode "
          f"{'cached' if writes else 'not written (PYTHONDONTWRITEBYTECODE)'}")
    if wanted is None or "help" in wanted:
        print("\n".join(help_table(workdir, max(args.repeat, 3))))
    costs: dict[str, dict] = {}
    rows = ["| command | cache | CPU s to taichi_ndf.init / in it | CPU / wall s to 1st Newton "
            "iteration | CPU / wall s to result line | process CPU / wall s | peak MB |",
            "|---|---|---|---|---|---|---|"]
    for name, (target, result_text) in commands(workdir).items():
        if wanted is not None and not any(name.startswith(w) for w in wanted):
            continue
        cache = Path(tempfile.mkdtemp(prefix="cache_", dir=workdir))
        for label in ["cold", *["warm"] * args.repeat]:
            for path in workdir.glob("[vsd]_*"):  # each run writes a new output folder
                subprocess.run(["rm", "-rf", str(path)], check=False)
            result = run([*target, *args.args], cache, workdir, stop_at_newton=not args.full,
                         outputs=args.outputs)
            costs[name] = output_costs(result["marks"])
            line = first(result["marks"], "line", result_text) if args.full else None
            process = (f"{result['cpu']:.2f} / {result['wall']:.2f}" if args.full
                       else "(stopped)")
            init, done = (first(result["marks"], w) for w in ("init", "init done"))
            split = "–" if init is None or done is None else \
                f"{init['cpu']:.2f} / {done['cpu'] - init['cpu']:.2f}"
            rows.append(f"| {name} | {label} | {split} | "
                        f"{_cell(first(result['marks'], 'newton'))} | "
                        f"{_cell(line)} | {process} | {result['maxrss_mb']:.0f} |")
            print(rows[-1], file=sys.stderr, flush=True)
    print("\n" + "\n".join(rows))
    if args.outputs:
        print("\n| command | output | calls | CPU s |\n|---|---|---|---|")
        for name, cost in costs.items():
            for output, (calls, cpu) in cost.items():
                print(f"| {name} | {output} | {calls} | {cpu:.3f} |")
    print(f"load average {' '.join(f'{v:.2f}' for v in os.getloadavg())} at the end")
    return 0


if __name__ == "__main__":
    sys.exit(main())
