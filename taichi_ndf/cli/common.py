"""Options and set-up shared by the command-line tools."""

from __future__ import annotations

import argparse
import logging
import platform

import taichi_ndf


def add_runtime_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--arch", default="cpu", choices=("cpu", "cuda", "vulkan", "metal", "gpu"),
                        help="Taichi backend (default: cpu)")
    parser.add_argument("--precision", default="f32", choices=("f32", "f64"),
                        help="floating-point precision of fields and kernels (default: f32)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")


def start(args: argparse.Namespace) -> taichi_ndf.runtime.Runtime:
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    return taichi_ndf.init(arch=args.arch, precision=args.precision, seed=args.seed)


def machine_description(runtime) -> dict:
    import os

    return {"python": platform.python_version(), "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
            "arch": runtime.arch, "precision": runtime.precision}
