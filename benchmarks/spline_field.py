"""Time of the spline field's jets and backward at N points, against the SIREN field.

For each precision, a fresh process initialises taichi_ndf in that precision and times:
    spline jets       SplineField.jets (Taichi basis kernel + Taichi contraction)
    spline backward   SplineField.backward (Taichi per-point contraction + torch index_add_)
    spline basis      SplineField.local_basis alone (the basis kernel, for Newton assembly)
    torch contraction the jets from the same basis by torch.bmm (the alternative not taken)
    siren jets+bwd    NeuralField.jets + backward at the default width 128 x 3 hidden layers
and its first call (jets + backward, compilation included) with an empty Taichi cache ("cold")
and, in a second fresh process, with the cache the first one filled ("warm"). Times are medians
over interleaved rounds; the load average is printed before and after.

    python benchmarks/spline_field.py                 # 16384 points, 32 x 32 cubic spans
    python benchmarks/spline_field.py --degree 4 --points 4096
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import torch


def _timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def worker(args) -> dict:
    import taichi_ndf
    from taichi_ndf.field import FieldConfig, NeuralField, SplineConfig, SplineField

    torch.set_num_threads(args.threads)
    start = time.perf_counter()
    taichi_ndf.init(arch="cpu", precision=args.precision, seed=0)
    init_s = time.perf_counter() - start
    dtype = taichi_ndf.current().dtype
    generator = torch.Generator().manual_seed(0)
    xi = torch.rand(args.points, 2, generator=generator, dtype=torch.float64).to(dtype)
    field = SplineField(SplineConfig(spans=(args.spans, args.spans), degree=args.degree))
    field.coefficients.normal_(generator=generator)
    grad = torch.randn(args.points, 6, 3, generator=generator, dtype=torch.float64).to(dtype)

    first_call_s = _timed(lambda: field.backward(field.jets(xi)))
    if args.first_call_only:
        return {"init_s": init_s, "first_call_s": first_call_s}

    siren = NeuralField(FieldConfig())
    index, basis = field.local_basis(xi)

    def torch_contraction():
        torch.bmm(basis, field.coefficients[index])

    jets = field.jets(xi)
    difference = (torch.bmm(basis, field.coefficients[index]) - jets).abs().max() / jets.abs().max()
    assert difference < (1e-5 if dtype == torch.float32 else 1e-13), difference
    contenders = {
        "spline jets": lambda: field.jets(xi),
        "spline backward": lambda: field.backward(grad),
        "spline basis": lambda: field.local_basis(xi),
        "torch contraction": torch_contraction,
        "siren jets+bwd": lambda: siren.backward(siren.jets(xi)),
    }
    for fn in contenders.values():
        fn()
    field.jets(xi)
    times = {name: [] for name in contenders}
    for _ in range(args.rounds):
        for name, fn in contenders.items():
            if name == "spline backward":
                field.jets(xi)  # the tape of this field's points
            times[name].append(_timed(fn))
    return {"init_s": init_s, "first_call_s": first_call_s,
            "ms": {name: 1e3 * statistics.median(t) for name, t in times.items()}}


def run(args, precision: str, cache: str, first_call_only: bool) -> dict:
    env = {**os.environ, "TAICHI_NDF_CACHE": cache, "OMP_NUM_THREADS": str(args.threads)}
    command = [sys.executable, __file__, "--worker", "--precision", precision,
               "--points", str(args.points), "--spans", str(args.spans),
               "--degree", str(args.degree), "--rounds", str(args.rounds),
               "--threads", str(args.threads)]
    if first_call_only:
        command.append("--first-call-only")
    out = subprocess.run(command, env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=16384)
    parser.add_argument("--spans", type=int, default=32)
    parser.add_argument("--degree", type=int, default=3)
    parser.add_argument("--rounds", type=int, default=20)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--precision", default="f64")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--first-call-only", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(worker(args)))
        return
    print(f"load average at start: {os.getloadavg()}")
    print(f"{args.points} points, {args.spans} x {args.spans} spans, degree {args.degree}, "
          f"{args.threads} thread(s), medians of {args.rounds} rounds")
    for precision in ("f32", "f64"):
        with tempfile.TemporaryDirectory() as cache:
            cold = run(args, precision, cache, first_call_only=True)
            warm = run(args, precision, cache, first_call_only=False)
        print(f"\n{precision}: first jets+backward {cold['first_call_s']:.2f} s cold cache, "
              f"{warm['first_call_s']:.3f} s warm (taichi_ndf.init {warm['init_s']:.2f} s)")
        print("| step | ms (median) |\n|---|---|")
        for name, ms in warm["ms"].items():
            print(f"| {name} | {ms:.2f} |")
    print(f"\nload average at end: {os.getloadavg()}")


if __name__ == "__main__":
    main()
