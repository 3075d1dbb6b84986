"""`--threads` limits torch and numpy's and scipy's BLAS (taichi_ndf.cli.common.start)."""

import json
import subprocess
import sys

from tests.scripts import ROOT

PROBE = """
import json, sys
import numpy, scipy.linalg
from threadpoolctl import threadpool_info
from taichi_ndf.cli.common import ArgumentParser, add_runtime_options, start
p = ArgumentParser(prog="probe")
add_runtime_options(p)
args = p.parse_args(sys.argv[1:])
start(args)
import torch
print(json.dumps({"torch": torch.get_num_threads(),
                  "blas": [i["num_threads"] for i in threadpool_info()
                           if i["user_api"] == "blas"]}))
"""


def _threads(*argv: str) -> dict:
    out = subprocess.run([sys.executable, "-c", PROBE, *argv], cwd=ROOT, check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def test_start_limits_torch_and_blas_threads():
    threads = _threads()  # default 1
    assert threads["torch"] == 1
    assert threads["blas"] and all(n == 1 for n in threads["blas"])
    threads = _threads("--threads", "2")
    assert threads["torch"] == 2
    assert all(n == 2 for n in threads["blas"])
