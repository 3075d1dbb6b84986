"""Options and set-up shared by the command-line tools."""

from __future__ import annotations

import argparse
import functools
import logging
import math
import re
import sys

from taichi_ndf.runtime import BACKEND_VARIABLE, arches, machine_description, selected_backend

__all__ = ["add_runtime_options", "description", "machine_description", "start"]


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def nonnegative_int(text: str) -> int:
    """An argparse type: an integer >= 0."""
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def description(doc: str) -> str:
    """A tool's --help description from its module docstring: the first paragraph as one line,
    without the `synopsis`: prefix (argparse's usage line shows it) and without backticks."""
    first = " ".join(doc.strip().split("\n\n")[0].split())
    first = re.sub(r"^`+[^`]*`+:?\s*", "", first).replace("`", "")
    return first[:1].upper() + first[1:]


class ArgumentParser(argparse.ArgumentParser):
    """argparse's parser whose errors are one line (``PROG: error: ...``, exit code 2) like
    every other user error of the tools; --help still shows the usage."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def finite_float(text: str) -> float:
    """An argparse type: a finite number (NaN and infinity are refused)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text}")
    return value


def _seed(text: str) -> int:
    value = int(text)
    if not 0 <= value < 2**32:
        raise argparse.ArgumentTypeError(f"must be in [0, 2^32), got {value}")
    return value


# Every tool's --precision default: f64, the precision the validation tables, the material fits
# and the SfT spline prior (which needs it) are computed in; f32 is the faster opt-in.
DEFAULT_PRECISION = "f64"


def add_runtime_options(parser: argparse.ArgumentParser, *, seed: int | None = 0,
                        seed_help: str = "random seed (default: 0)") -> None:
    """--arch, --precision (default DEFAULT_PRECISION), --seed, --threads and --verbose."""
    backend = selected_backend()
    parser.add_argument("--arch", default="cpu",
                        choices=tuple(a for a in arches(backend) if a != "x64"),
                        help=f"device of the {backend} backend (default: cpu; the backend: "
                        f"{BACKEND_VARIABLE}=taichi|quadrants)")
    parser.add_argument("--precision", default=DEFAULT_PRECISION, choices=("f32", "f64"),
                        help="floating-point precision of fields and kernels (default: "
                        f"{DEFAULT_PRECISION}, as in every tool; f32 is faster)")
    parser.add_argument("--seed", type=_seed, default=seed, help=seed_help)
    parser.add_argument("--threads", type=_positive_int, default=1,
                        help="CPU threads of torch and of numpy's and scipy's BLAS (default 1: "
                        "Taichi's kernels run on their own pool of all cores, and torch's and "
                        "BLAS's spinning threads competing with it were measured 5-20x and 1.7x "
                        "slower on a 2-core CPU)")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")


def start(args: argparse.Namespace):
    """Logging, the thread count of torch and of numpy's and scipy's BLAS, and the Taichi
    runtime (`taichi_ndf.runtime.Runtime`) from the runtime options."""
    import torch
    from threadpoolctl import threadpool_limits

    import taichi_ndf

    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    torch.set_num_threads(args.threads)
    # numpy and scipy each load an OpenBLAS that starts one thread per core: beside Taichi's
    # pool they spin for the cores (ndf-sft on φ-SfT R1, 2 cores: 2.59 -> 1.53 s CPU per frame,
    # 116 -> 84 s wall with one BLAS thread; the same meshes).
    threadpool_limits(args.threads)
    return taichi_ndf.init(arch=args.arch, precision=args.precision,
                           seed=0 if args.seed is None else args.seed)


def interruptible(prog: str):
    """Decorate a tool's `main`: Ctrl-C ends it with one line and exit code 130, running out of
    memory with one line and exit code 2 (instead of a traceback); its progress reports are
    shown (`taichi_ndf.cli.progress`). Files a tool writes are atomic (`atomic_path`), so an
    interruption leaves no half-written file."""

    def wrap(main):
        @functools.wraps(main)
        def run(argv=None) -> int:
            from taichi_ndf.cli.progress import shown

            try:
                with shown(prog):
                    return main(argv)
            except KeyboardInterrupt:
                print(f"{prog}: interrupted", file=sys.stderr)
                return 130
            except MemoryError:
                print(f"{prog}: error: out of memory; try a smaller problem (resolution, "
                      "samples, frames)", file=sys.stderr)
                return 2

        return run

    return wrap
