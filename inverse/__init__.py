"""Inverse problems with the thin-shell energy as a physics prior."""
