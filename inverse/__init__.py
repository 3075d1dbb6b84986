"""Inverse problems with the thin-shell energy as a physics prior."""

import taichi_ndf  # noqa: F401,E402  (first: it keeps Taichi's import banner quiet)
