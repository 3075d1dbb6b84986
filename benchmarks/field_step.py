"""Time per optimisation step of the neural field: taichi-ndf against two PyTorch baselines.

One step = the field's jets at N samples (value, 2 first and 3 second derivatives of each of
the 3 output components), a per-sample loss of all 18 channels (½ Σ κ_c y², κ weighting the
channels), the gradient of the summed loss w.r.t. every weight and bias, and one Adam update.
All contenders start from the same SIREN weights, compute the same function in float32, and are
checked to agree before they are timed.

    taichi-ndf    NeuralField.jets/backward (torch BLAS GEMMs, Taichi jet kernels), taichi_ndf Adam
    torch-jets    jets propagated through the layers with batched matmuls, autograd backward,
                  torch.optim.Adam
    torch-nested  derivatives by nested autograd (create_graph=True), the way the original
                  NeuralClothSim computes them, torch.optim.Adam

Step times are medians over rounds that interleave the contenders, so a busy neighbour on a
shared machine slows all of them alike. First-call time and peak resident memory are measured
in a fresh process per contender (taichi-ndf twice: empty kernel cache, then warm cache).

    python benchmarks/field_step.py            # the three cases of the issue, ~3 minutes
    python benchmarks/field_step.py --quick    # tiny case, smoke test
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass

import torch

CHANNEL_WEIGHTS = (1.0, 1.0, 1.0, 0.1, 0.1, 0.1)  # κ_c: second derivatives are larger
CONTENDERS = ("taichi-ndf", "torch-jets", "torch-nested")
BASELINE = "torch-jets"


@dataclass(frozen=True)
class Case:
    samples: int
    width: int
    hidden_layers: int
    repeats: int
    nested_repeats: int

    @property
    def name(self) -> str:
        return f"N={self.samples}, {self.width}x{self.hidden_layers}"


CASES = (
    Case(4096, 128, 3, repeats=20, nested_repeats=10),
    Case(4096, 256, 5, repeats=8, nested_repeats=4),
    Case(4000, 512, 5, repeats=4, nested_repeats=2),
)
QUICK_CASES = (Case(256, 16, 2, repeats=2, nested_repeats=2),)


def rss_mb(key: str = "VmRSS") -> float:
    """Resident memory of this process [MB] (VmHWM: peak since the last reset)."""
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith(key + ":"):
                return int(line.split()[1]) / 1024
    raise RuntimeError(f"{key} not found in /proc/self/status")


def reset_peak_rss() -> None:
    with open("/proc/self/clear_refs", "w") as clear:
        clear.write("5")


class TaichiNDF:
    def __init__(self, case: Case, xi: torch.Tensor, seed: int):
        from taichi_ndf.field import FieldConfig, NeuralField
        from taichi_ndf.problem.optim import Adam

        config = FieldConfig(width=case.width, hidden_layers=case.hidden_layers)
        self.field = NeuralField(config, seed=seed)
        self.adam = Adam(self.field.parameters, self.field.gradients)
        self.xi = xi
        self.kappa = torch.tensor(CHANNEL_WEIGHTS).view(1, 6, 1)

    def jets(self) -> torch.Tensor:
        return self.field.jets(self.xi)

    def step(self) -> None:
        y = self.field.jets(self.xi)
        self.field.backward(self.kappa * y)
        self.adam.step()


class TorchContender:
    """Shared set-up of the PyTorch baselines: SIREN weights as autograd leaves."""

    def __init__(self, case: Case, xi: torch.Tensor, seed: int):
        from taichi_ndf.field import FieldConfig
        from taichi_ndf.field.network import siren_parameters

        config = FieldConfig(width=case.width, hidden_layers=case.hidden_layers)
        self.omega = config.omega0
        self.params = [p.float().requires_grad_(True) for p in siren_parameters(config, seed)]
        self.adam = torch.optim.Adam(self.params, lr=1e-3)
        self.xi = xi
        self.kappa = torch.tensor(CHANNEL_WEIGHTS).view(1, 6, 1)

    def step(self) -> None:
        y = self.jets()
        loss = 0.5 * (self.kappa * y * y).sum()
        self.adam.zero_grad(set_to_none=True)
        loss.backward()
        self.adam.step()


class TorchJets(TorchContender):
    def jets(self) -> torch.Tensor:
        n = self.xi.shape[0]
        h = torch.zeros(6, n, 2)
        h[0] = 2 * self.xi - 1
        h[1, :, 0] = 2
        h[2, :, 1] = 2
        weights, biases = self.params[0::2], self.params[1::2]
        for w, b in zip(weights[:-1], biases[:-1], strict=True):
            a = torch.matmul(h, self.omega * w.t())
            s, c = torch.sin(a[0] + self.omega * b), torch.cos(a[0] + self.omega * b)
            a1, a2, a11, a12, a22 = a[1:]
            h = torch.stack(
                (
                    s,
                    c * a1,
                    c * a2,
                    c * a11 - s * a1 * a1,
                    c * a12 - s * a1 * a2,
                    c * a22 - s * a2 * a2,
                )
            )
        y = torch.matmul(h, weights[-1].t())
        y = torch.cat((y[:1] + biases[-1], y[1:]))
        return y.transpose(0, 1)


class TorchNested(TorchContender):
    def jets(self) -> torch.Tensor:
        x = self.xi.clone().requires_grad_(True)
        h = 2 * x - 1
        weights, biases = self.params[0::2], self.params[1::2]
        for w, b in zip(weights[:-1], biases[:-1], strict=True):
            h = torch.sin(self.omega * (h @ w.t() + b))
        u = h @ weights[-1].t() + biases[-1]
        components = []
        for j in range(u.shape[1]):
            (du,) = torch.autograd.grad(u[:, j].sum(), x, create_graph=True)
            (d1u,) = torch.autograd.grad(du[:, 0].sum(), x, create_graph=True)
            (d2u,) = torch.autograd.grad(du[:, 1].sum(), x, create_graph=True)
            channels = (u[:, j], du[:, 0], du[:, 1], d1u[:, 0], d1u[:, 1], d2u[:, 1])
            components.append(torch.stack(channels, 1))
        return torch.stack(components, 2)


CLASSES = {"taichi-ndf": TaichiNDF, "torch-jets": TorchJets, "torch-nested": TorchNested}


def samples(case: Case, seed: int) -> torch.Tensor:
    return torch.rand(case.samples, 2, generator=torch.Generator().manual_seed(seed))


def init_runtime(threads: int | None) -> None:
    """float32 Taichi runtime; ``threads`` limits torch's and Taichi's CPU threads."""
    import taichi_ndf

    if threads is not None:
        torch.set_num_threads(threads)
        os.environ["TI_CPU_MAX_NUM_THREADS"] = str(threads)  # read by ti.init
    taichi_ndf.init(arch="cpu", precision="f32", seed=0)


def probe(name: str, case: Case, threads: int | None) -> dict:
    """In a fresh process: time of the first step (compilation included) and peak memory."""
    init_runtime(threads)
    baseline = rss_mb()
    reset_peak_rss()
    start = time.perf_counter()
    contender = CLASSES[name](case, samples(case, 1), seed=0)
    contender.step()
    first = time.perf_counter() - start
    contender.step()
    return {"first_call_s": first, "peak_rss_mb": rss_mb("VmHWM"), "baseline_rss_mb": baseline}


def run_probe(
    args: argparse.Namespace, name: str, case_index: int, cache: str | None = None
) -> dict:
    command = [sys.executable, __file__, "--probe", name, "--case", str(case_index)]
    if args.quick:
        command.append("--quick")
    if args.threads is not None:
        command += ["--threads", str(args.threads)]
    env = dict(os.environ)
    if cache is not None:
        env["TAICHI_NDF_CACHE"] = cache
    done = subprocess.run(command, capture_output=True, text=True, env=env, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def max_relative_difference(a: torch.Tensor, b: torch.Tensor) -> float:
    """Largest per-channel max|a - b| / max|b|."""
    return max(((a[:, c] - b[:, c]).abs().max() / b[:, c].abs().max()).item() for c in range(6))


def time_case(case: Case) -> dict:
    xi = samples(case, 1)
    contenders = {name: CLASSES[name](case, xi, seed=0) for name in CONTENDERS}
    reference = contenders["taichi-ndf"].jets().clone()
    agreement = {
        name: max_relative_difference(c.jets().detach(), reference)
        for name, c in contenders.items()
    }
    for contender in contenders.values():
        contender.step()  # warm-up: compilation, allocation
    times = {name: [] for name in CONTENDERS}
    for round_ in range(case.repeats):
        for name, contender in contenders.items():
            if name == "torch-nested" and round_ >= case.nested_repeats:
                continue
            start = time.perf_counter()
            contender.step()
            times[name].append(time.perf_counter() - start)
    return {"times": times, "agreement": agreement}


def time_evaluation(points: int) -> dict:
    """Seconds to evaluate a 128x3 field at ``points`` samples (best of 3), without and with
    first derivatives (what exporting a mesh with normals needs)."""
    from taichi_ndf.field import FieldConfig, NeuralField

    field = NeuralField(FieldConfig(width=128, hidden_layers=3), seed=0)
    xi = torch.rand(points, 2, generator=torch.Generator().manual_seed(2))
    result = {}
    for derivatives in (False, True):
        times = []
        for _ in range(3):
            start = time.perf_counter()
            field.evaluate(xi, derivatives=derivatives)
            times.append(time.perf_counter() - start)
        result[derivatives] = min(times)
    return result


def machine() -> str:
    import taichi

    model = platform.processor() or "unknown CPU"
    with open("/proc/cpuinfo") as info:
        for line in info:
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    return (
        f"{model}, {os.cpu_count()} cores, torch {torch.__version__} "
        f"({torch.get_num_threads()} threads), Taichi CPU threads "
        f"{os.environ.get('TI_CPU_MAX_NUM_THREADS', 'default')}, "
        f"taichi {'.'.join(map(str, taichi.__version__))}, "
        f"Python {platform.python_version()}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="tiny case only (smoke test)")
    parser.add_argument("--threads", type=int, help="CPU threads for torch and Taichi")
    parser.add_argument("--probe", choices=CONTENDERS, help=argparse.SUPPRESS)
    parser.add_argument("--case", type=int, default=0, help=argparse.SUPPRESS)
    args = parser.parse_args()
    cases = QUICK_CASES if args.quick else CASES
    if args.probe:
        print(json.dumps(probe(args.probe, cases[args.case], args.threads)))
        return

    init_runtime(args.threads)
    print(f"machine: {machine()}")
    print(f"load average at start: {os.getloadavg()}")
    rows = []
    for index, case in enumerate(cases):
        result = time_case(case)
        with tempfile.TemporaryDirectory() as cache:
            probes = {"taichi-ndf": run_probe(args, "taichi-ndf", index, cache)}
            # The quick smoke test skips the warm-cache probe: one Python start-up less.
            warm = None if args.quick else run_probe(args, "taichi-ndf", index, cache)
        for name in CONTENDERS[1:]:
            probes[name] = run_probe(args, name, index)
        baseline = statistics.median(result["times"][BASELINE])
        nested = statistics.median(result["times"]["torch-nested"])
        for name in CONTENDERS:
            median = statistics.median(result["times"][name])
            memory = probes[name]["peak_rss_mb"]
            growth = memory - probes[name]["baseline_rss_mb"]
            first = f"{probes[name]['first_call_s']:.2f}"
            if name == "taichi-ndf":
                first += " cold" if warm is None else f" cold / {warm['first_call_s']:.2f} warm"
            fastest = min(result["times"][name])
            rows.append(
                f"| {case.name} | {name} | {median * 1e3:.1f} | {fastest * 1e3:.1f} "
                f"| {median / baseline:.2f} | {nested / median:.1f} | {first} "
                f"| {memory:.0f} (+{growth:.0f}) | {result['agreement'][name]:.1e} |"
            )
    points = 10_000 if args.quick else 1_000_000
    evaluation = time_evaluation(points)
    print(f"load average at end: {os.getloadavg()}")
    print()
    print(
        "| case | contender | step ms (median) | step ms (min) | time / torch-jets "
        "| speed-up vs torch-nested | first call s | peak RSS MB (+ over start-up) "
        "| jets rel. diff |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    print("\n".join(rows))
    print()
    print(
        f"evaluate {points} points, 128x3: values {evaluation[False]:.2f} s, "
        f"values + first derivatives {evaluation[True]:.2f} s"
    )


if __name__ == "__main__":
    main()
