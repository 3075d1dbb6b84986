"""Command-line entry points (`ndf-sim`, `ndf-export`, `ndf-validate`).

Importing the tools imports the kernel modules, which bind the Taichi backend
(`taichi_ndf.runtime`); an unknown or missing backend in ``TAICHI_NDF_BACKEND`` is a user error:
one line and exit code 2, before that import.
"""

import sys
from pathlib import Path

from taichi_ndf.runtime import selected_backend

try:
    selected_backend()
except (ValueError, RuntimeError) as _error:
    print(f"{Path(sys.argv[0]).name}: error: {_error}", file=sys.stderr)
    raise SystemExit(2) from None
