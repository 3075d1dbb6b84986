"""One Taichi backend on this interpreter: taichi and quadrants imported side by side, then the
named one compiles and runs a kernel in f64 with reverse-mode autodiff (ti.ad.Tape), checked
against the closed form. Usage: python .ci/backend_smoke.py taichi|quadrants"""

import importlib
import os
import sys

import numpy as np

os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "False")
os.environ.setdefault("ENABLE_QUADRANTS_HEADER_PRINT", "False")
languages = {name: importlib.import_module(name) for name in ("taichi", "quadrants")}
ti = languages[sys.argv[1]]
ti.init(arch=ti.x64, default_fp=ti.f64, offline_cache=False, log_level=ti.WARN)

x = ti.field(ti.f64, shape=16, needs_grad=True)
loss = ti.field(ti.f64, shape=(), needs_grad=True)


@ti.kernel
def energy():
    for i in x:
        loss[None] += ti.sin(x[i]) ** 2


values = np.linspace(-2.0, 2.0, 16)
x.from_numpy(values)
with ti.ad.Tape(loss=loss):
    energy()
value_error = abs(loss[None] - np.sum(np.sin(values) ** 2))
gradient_error = np.max(np.abs(x.grad.to_numpy() - np.sin(2 * values)))
if value_error > 1e-12 or gradient_error > 1e-12:
    sys.exit(f"{sys.argv[1]}: kernel off by {value_error:.1e}, gradient by {gradient_error:.1e}")
version = ".".join(map(str, ti.__version__))
print(f"{sys.argv[1]} {version} on Python {sys.version.split()[0]}: value and gradient agree "
      f"to {max(value_error, gradient_error):.1e}")
