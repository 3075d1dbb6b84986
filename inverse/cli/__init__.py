"""Command-line tools of the inverse package."""

import taichi_ndf.cli  # noqa: F401  (first: a bad TAICHI_NDF_BACKEND is one line and exit 2)
