"""A repository script (a benchmark, a demo, docs/make_gallery.py) loaded as a module, so that a
test can call its functions without running it as a process."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[1]


def load_script(relative: str, name: str | None = None) -> ModuleType:
    """The script at ROOT / `relative` (e.g. "benchmarks/fe_peer.py") executed as module `name`
    (default: the file's stem). It is registered in sys.modules under that name (a dataclass
    looks its module up there), and its folder is on sys.path while it loads (a script that
    imports a sibling script)."""
    path = ROOT / relative
    name = name or path.stem
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    sys.path.insert(0, str(path.parent))
    try:
        spec.loader.exec_module(module)
    except BaseException:
        sys.modules.pop(name, None)
        raise
    finally:
        sys.path.remove(str(path.parent))
    return module
