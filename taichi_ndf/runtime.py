"""The one place that imports and initialises the Taichi language.

Two implementations of the language are supported (*backends*): ``taichi`` (taichi 1.7.4, the
last release) and ``quadrants`` (Genesis' maintained fork, 1.3.3; the same language without
OpenGL, GGUI, AOT and the C API). Every module with kernels imports the language from here::

    from taichi_ndf.runtime import ti

The backend is bound when ``ti`` is first imported (or at ``init``, whichever comes first):
``init(backend=...)`` when called before any kernel module is imported, else the environment
variable ``TAICHI_NDF_BACKEND`` (``taichi`` or ``quadrants``), else the first installed of
taichi, quadrants (docs/backends.md says why taichi comes first). Kernels are compiled by the
backend that defined them, so the choice cannot change once a kernel module is imported.

Nothing Taichi happens at import time. ``init`` is called once per process (tests use a
session fixture); a second call with the same settings is a no-op, a second call with other
settings raises, because re-initialising Taichi invalidates every field and kernel that exists.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import linecache
import logging
import os
import platform
import random
import sys
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import torch

log = logging.getLogger(__name__)

BACKEND_VARIABLE = "TAICHI_NDF_BACKEND"
BACKENDS = ("taichi", "quadrants")  # in the order a default is looked for
# The arch names each backend offers ("cpu" is the x64 backend on both); quadrants has no OpenGL.
BACKEND_ARCHES = {
    "taichi": ("cpu", "x64", "cuda", "vulkan", "metal", "opengl", "gpu"),
    "quadrants": ("cpu", "x64", "cuda", "vulkan", "metal", "gpu"),
}
PRECISIONS = ("f32", "f64")

_language: ModuleType | None = None  # the bound backend's module, once `ti` or `init` asked


def _check_backend(backend: str) -> str:
    if backend not in BACKENDS:
        raise ValueError(f"unknown Taichi backend {backend!r}; choose one of {BACKENDS}")
    return backend


def installed_backends() -> tuple[str, ...]:
    """The backends whose package is installed (found, not imported)."""
    return tuple(name for name in BACKENDS if importlib.util.find_spec(name) is not None)


def selected_backend() -> str:
    """The backend `ti` is (or will be) bound to: the bound one, else ``TAICHI_NDF_BACKEND``,
    else the first installed of taichi, quadrants. Imports nothing; raises (one line) on an
    unknown name or a backend that is not installed."""
    if _language is not None:
        return _language.__name__
    wanted = os.environ.get(BACKEND_VARIABLE, "").strip()
    if wanted:
        try:
            return _installed(_check_backend(wanted))
        except (ValueError, RuntimeError) as error:
            raise type(error)(f"{BACKEND_VARIABLE}={wanted}: {error}") from None
    installed = installed_backends()
    if not installed:
        raise RuntimeError("neither taichi nor quadrants is installed: pip install taichi-ndf "
                           "(taichi) or taichi-ndf[quadrants]")
    return installed[0]


def _installed(backend: str) -> str:
    if importlib.util.find_spec(backend) is None:
        extra = "taichi-ndf[quadrants]" if backend == "quadrants" else "taichi-ndf"
        raise RuntimeError(f"the {backend} backend is not installed: pip install {extra}")
    return backend


def arches(backend: str | None = None) -> tuple[str, ...]:
    """The arch names a backend offers (the selected backend's by default)."""
    return BACKEND_ARCHES[_check_backend(backend or selected_backend())]


def language(backend: str | None = None) -> ModuleType:
    """The Taichi language module (``taichi`` or ``quadrants``), imported and bound on first use.

    backend: the one wanted (default `selected_backend()`); asking for another than the bound
    one raises, since the kernels already defined belong to the bound one.
    """
    global _language
    wanted = _check_backend(backend or selected_backend())
    if _language is None:
        finder = _PatchOnImport(f"{wanted}.lang.kernel_impl", _lighter_front_end)
        sys.meta_path.insert(0, finder)
        try:
            _language = importlib.import_module(_installed(wanted))
        finally:
            sys.meta_path.remove(finder)
        if f"{wanted}.lang.kernel_impl" in sys.modules:  # imported before: patched now
            _lighter_front_end(sys.modules[f"{wanted}.lang.kernel_impl"])
        log.info("Taichi language: %s %s", wanted, backend_version(_language))
    elif _language.__name__ != wanted:
        raise RuntimeError(
            f"the Taichi language is already {_language.__name__} (bound when the first kernel "
            f"module was imported or init ran); cannot switch to {wanted} in this process: set "
            f"{BACKEND_VARIABLE}={wanted} or call init(backend={wanted!r}) before importing "
            "taichi_ndf's kernel modules")
    return _language


# Taichi's Python front end spends much of a warm start (benchmarks/RESULTS.md, "Start-up")
# in: `inspect.getframeinfo` per @ti.kernel/@ti.func (is it in a class body? a scan of
# sys.modules each); an underlined, text-wrapped source excerpt per AST node compiled (~50 000
# before the first Newton iteration); a ti.func's source read again at each call site.
# Replaced by what they compute: the class test from `linecache`; file, line, function and
# source line of the node (Taichi's own under `init(debug=True)`); each source read once.
_FULL_POSITIONS: dict[str, object] = {}  # backend -> its own get_pos_info


class _PatchOnImport(importlib.abc.MetaPathFinder):
    """`patch(module)` as soon as the module `name` has run, before the rest of its package's
    import: Taichi's own ~90 decorations in `import taichi` then skip `_inside_class`'s scan
    of sys.modules (0.15-0.2 s CPU where torch was imported first)."""

    def __init__(self, name: str, patch):
        self.name, self.patch = name, patch

    def find_spec(self, fullname, path, target=None):
        spec = (importlib.machinery.PathFinder.find_spec(fullname, path)
                if fullname == self.name else None)
        if spec is not None and hasattr(spec.loader, "exec_module"):
            run = spec.loader.exec_module

            def exec_module(module):
                run(module)
                self.patch(module)

            spec.loader.exec_module = exec_module
        return spec


def _lighter_front_end(kernel_impl: ModuleType) -> None:
    """Taichi's `_inside_class` (is the decorated function in a class body?) from the source
    line by `linecache` instead of `inspect.getframeinfo`, the same answer; and on taichi,
    each function's source read once (`_remembered`). Then the compile context released."""
    if getattr(kernel_impl, "_taichi_ndf_lighter", False):
        return
    kernel_impl._taichi_ndf_lighter = True
    backend = kernel_impl.__name__.split(".")[0]
    _compile_arguments_released(kernel_impl)
    try:
        patterns = kernel_impl._KERNEL_CLASS_STACKFRAME_STMT_RES
    except AttributeError:
        log.debug("%s: no _inside_class to replace", backend)
        return

    def _inside_class(level_of_class_stackframe: int) -> bool:
        try:
            frame = sys._getframe(level_of_class_stackframe)
        except ValueError:
            return False
        line = linecache.getline(frame.f_code.co_filename, frame.f_lineno).strip()
        return any(pattern.match(line) for pattern in patterns)

    kernel_impl._inside_class = _inside_class
    if backend == "taichi":  # each ti.func's source, read again at each call site compiled
        for name in ("getsourcelines", "getsourcefile"):
            setattr(kernel_impl, name, _remembered(getattr(kernel_impl, name)))


def _compile_arguments_released(kernel_impl: ModuleType) -> None:
    """Taichi's compile context of a kernel (`ASTTransformerContext`) keeps the arguments of
    the call that compiled it (`argument_data`) and sits in a reference cycle with the AST
    transformer's closures, so those arrays (a first call's full-size inputs and outputs: 1.4
    GB at 322 k Gauss points, the spline basis jets and the shell's Hessian blocks) stay alive
    until Python's cyclic collector next runs a full pass. Dropped once the kernel is
    compiled (its AST built: the context is not read after that)."""
    try:
        build, materialize = kernel_impl._get_tree_and_ctx, kernel_impl.Kernel.materialize
    except AttributeError:
        log.debug("%s: no compile context to release", kernel_impl.__name__)
        return
    built: list = []  # contexts of the kernels (and their functions) being compiled

    def get_tree_and_ctx(*args, **kwargs):
        tree, ctx = build(*args, **kwargs)
        built.append(ctx)
        return tree, ctx

    def released(self, *args, **kwargs):
        try:
            return materialize(self, *args, **kwargs)
        finally:
            for ctx in [c for c in built if getattr(c, "ast_builder", None) is not None]:
                ctx.argument_data = None
                built.remove(ctx)

    kernel_impl._get_tree_and_ctx = get_tree_and_ctx
    kernel_impl.Kernel.materialize = released


def _remembered(read):
    """`read(function)` (a source file or its lines, which do not change within a process)
    once per function."""
    known: dict = {}

    def remembered(function):
        try:
            found = known[function]
        except KeyError:
            found = known[function] = read(function)
        except TypeError:  # not hashable
            return read(function)
        return (list(found[0]), found[1]) if isinstance(found, tuple) else found

    return remembered


def _source_positions(backend: str, *, full: bool) -> None:
    """Taichi's source position of an AST node (for its compile error messages): its own
    underlined excerpt with `full`, else file, line, function and the node's first source
    line."""
    if backend != "taichi":  # quadrants builds its positions its own (memoised) way
        return
    try:
        utils = importlib.import_module(f"{backend}.lang.ast.ast_transformer_utils")
        context = utils.ASTTransformerContext
    except (ImportError, AttributeError):
        log.debug("%s: no get_pos_info to replace", backend)
        return
    own = _FULL_POSITIONS.setdefault(backend, context.get_pos_info)
    if full:
        context.get_pos_info = own
        return

    def get_pos_info(self, node) -> str:
        try:
            return (f'File "{self.file}", line {node.lineno + self.lineno_offset}, in '
                    f"{self.func.func.__name__}:\n{self.src[node.lineno - 1]}\n")
        except (AttributeError, IndexError, TypeError):
            return own(self, node)

    context.get_pos_info = get_pos_info


def backend_version(module: ModuleType) -> str:
    version = module.__version__
    return ".".join(map(str, version)) if isinstance(version, tuple) else str(version)


def __getattr__(name: str):
    # `from taichi_ndf.runtime import ti` binds the backend on first use (PEP 562).
    if name == "ti":
        return language()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


@dataclass(frozen=True)
class Runtime:
    """Settings of the initialised Taichi runtime."""

    arch: str = "cpu"
    precision: str = "f64"
    seed: int = 0
    debug: bool = False
    backend: str = "taichi"
    fast_math: bool = False

    def __post_init__(self):
        _check_backend(self.backend)
        offered = BACKEND_ARCHES[self.backend]
        if self.arch not in offered:
            raise ValueError(f"unknown arch {self.arch!r} for the {self.backend} backend; choose "
                             f"one of {offered}")
        if self.precision not in PRECISIONS:
            raise ValueError(f"unknown precision {self.precision!r}; choose one of {PRECISIONS}")

    @property
    def dtype(self) -> torch.dtype:
        """Torch dtype of all real-valued tensors of this runtime."""
        import torch

        return torch.float64 if self.precision == "f64" else torch.float32

    @property
    def device(self) -> torch.device:
        """Torch device that holds tensors shared with Taichi kernels."""
        import torch

        if self.arch in ("cuda", "gpu") and torch.cuda.is_available():
            return torch.device("cuda")
        return torch.device("cpu")


_current: Runtime | None = None


def cache_dir() -> Path:
    """Directory of the offline kernel caches (``TAICHI_NDF_CACHE`` overrides it); each backend
    keeps its own in a subdirectory named after it."""
    default = Path.home() / ".cache" / "taichi_ndf" / "ti_cache"
    return Path(os.environ.get("TAICHI_NDF_CACHE", default))


def init(arch: str = "cpu", precision: str = "f64", seed: int = 0, *,
         debug: bool = False, backend: str | None = None, fast_math: bool = False) -> Runtime:
    """Initialise Taichi for this process and seed torch, numpy and Python's RNG.

    arch: one of `arches(backend)`: "cpu" (the x64 backend), "cuda", "vulkan", "metal", "gpu",
    and "opengl" on taichi only.
    precision: "f32" or "f64"; the default real type of kernels and of all tensors.
    debug: Taichi debug mode (bounds checks, autodiff validation); slow.
    backend: "taichi" or "quadrants" (default `selected_backend()`); must be the bound one if
    a kernel module was imported already.
    fast_math: let the compiler reassociate and contract floating-point operations (Taichi's
    own default). Off: IEEE arithmetic, so both backends give the same Π in f64 (with it on
    they differed by 1.1e-12 relative on the pinched hemisphere, and Π of the undeformed shell
    came out 1.7e-18 J instead of 0); the cost measured in benchmarks/RESULTS.md ("Fast math").
    """
    global _current
    wanted = Runtime(arch=arch, precision=precision, seed=seed, debug=debug,
                     backend=_check_backend(backend or selected_backend()), fast_math=fast_math)
    if _current is not None:
        if _current == wanted:
            return _current
        raise RuntimeError(
            f"taichi_ndf is already initialised with {_current}; cannot re-initialise with "
            f"{wanted} in the same process (call taichi_ndf.reset() first, which invalidates "
            "every existing field and network)"
        )
    ti = language(wanted.backend)
    ti_arch = getattr(ti, "x64" if arch == "cpu" else arch)
    fp = ti.f64 if precision == "f64" else ti.f32
    path = cache_dir() / wanted.backend
    path.mkdir(parents=True, exist_ok=True)
    _source_positions(wanted.backend, full=debug)
    ti.init(
        arch=ti_arch,
        default_fp=fp,
        random_seed=seed,
        debug=debug,
        offline_cache=True,
        offline_cache_file_path=str(path),
        ad_stack_size=512,
        log_level=ti.WARN,
        fast_math=fast_math,
    )
    import torch

    torch.manual_seed(seed)
    np.random.seed(seed)
    random.seed(seed)
    _current = wanted
    log.info("taichi_ndf initialised: %s (cache %s)", wanted, path)
    return wanted


def reset() -> None:
    """Tear Taichi down so ``init`` may be called again (tests only)."""
    global _current
    if _current is None:
        return
    language().reset()
    _current = None


def current() -> Runtime:
    """The active runtime; raises if ``init`` has not been called."""
    if _current is None:
        raise RuntimeError(
            "taichi_ndf is not initialised: call taichi_ndf.init(arch=..., precision=...) first")
    return _current


def is_initialised() -> bool:
    return _current is not None


def machine_description(runtime: Runtime) -> dict:
    """Python, platform, processor, CPU count and the runtime's backend (with its version),
    arch and precision (for the machine record of result files)."""
    return {"python": platform.python_version(), "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
            "backend": f"{runtime.backend} {backend_version(language(runtime.backend))}",
            "arch": runtime.arch, "precision": runtime.precision, "fast_math": runtime.fast_math}
