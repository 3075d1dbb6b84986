"""The spline grids of the material estimate, chosen from the bending length.

A sheet hanging under gravity bends in boundary layers of width ~ the bending length
c = (B / (ρ_A g))^(1/3) along its held edge, around the held corners and along its free
edges; between them its shape is the sag of the whole sheet. A grid resolves both when each
span of the coarse grid is at most `SPAN_PER_BENDING_LENGTH` · c long (the fine grid halves
it) and there are at least `MIN_SPANS` spans per side. Measured on the synthetic hanging
sheet (0.3 m, benchmarks/RESULTS.md, Material from video, 2026-12-06 04:10): coarse spans of
0.86 c (c = 5 cm on 7 × 7) and 1.43 c (c = 3 cm on 7 × 7) recovered B within 1.3 % on the
fine grid; 2.1 c (c = 2 cm on 7 × 7) left the coarse grid's B 88 % low and B undetermined.

c is not known before the estimate, so the grid is chosen in steps
(`material_from_video.estimate_material`): from a guess (the start's bending length, by
default the median of measured fabrics), then from the coarse grid's estimate, and once more
from the final estimate if that asks for a finer grid. An under-resolved grid is stiffer
than the sheet, so its estimate of c comes out low and asks for a finer grid, not a coarser
one. `MAX_SPANS` caps the coarse grid (time and memory of the fine grid's Newton solves grow
with its (n + p)² coefficients); a capped grid is said in the report's notes.
"""

from __future__ import annotations

import math

from taichi_ndf.shell.fabrics import bending_length

SPAN_PER_BENDING_LENGTH = 1.5  # longest coarse span / bending length
MIN_SPANS = 7  # fewest coarse spans per side (the sheet's sag between the boundary layers)
MAX_SPANS = 16  # most coarse spans per side (fine grid 32 × 32)


def spans_for_bending_length(size: tuple[float, float], bending_length: float
                             ) -> tuple[tuple[int, int], bool]:
    """Coarse spans (n1, n2) for a flat sheet of `size` (W, H) [m] and a bending length [m]
    (module docstring), and whether `MAX_SPANS` capped them."""
    if not (math.isfinite(bending_length) and bending_length > 0):
        raise ValueError(f"bending_length must be a positive length [m], got "
                         f"{bending_length!r}")
    span = SPAN_PER_BENDING_LENGTH * bending_length
    wanted = [max(MIN_SPANS, math.ceil(float(s) / span - 1e-9)) for s in size]
    spans = tuple(min(n, MAX_SPANS) for n in wanted)
    return spans, spans != tuple(wanted)


def finer(spans: tuple[int, int], other: tuple[int, int]) -> bool:
    """Whether `other` has more spans than `spans` along either side."""
    return any(b > a for a, b in zip(spans, other, strict=True))


class GridChoice:
    """The coarse grid of each step of one estimate (module docstring): the stated
    `config.spans`, or chosen from the bending length — first from the guess
    `config.start_bending_length`, then from each estimate of B given to `next`. `steps`
    records each choice for the report, `notes` the capped ones."""

    def __init__(self, config, gravity: float):
        self.config, self.gravity = config, float(gravity)
        self.chosen = config.spans is None
        self.steps: list[dict] = []
        self.notes: list[str] = []

    def first(self, size: tuple[float, float]) -> tuple[int, int]:
        if not self.chosen:
            spans = tuple(int(s) for s in self.config.spans)
            self.steps.append({"from": "stated", "spans": list(spans)})
            return spans
        return self._from(size, self.config.start_bending_length, "guess")

    def next(self, size: tuple[float, float], bending_stiffness: float, label: str, *,
             only_finer: tuple[int, int] | None = None) -> tuple[int, int] | None:
        """The spans for the estimate B (None when stated, or when `only_finer` is given and
        they are not finer than it)."""
        if not self.chosen:
            return None
        c = bending_length(float(bending_stiffness), float(self.config.areal_density),
                           float(self.gravity))
        spans = self._from(size, c, label)
        if only_finer is not None and not finer(only_finer, spans):
            return None
        return spans

    def _from(self, size, c: float, label: str) -> tuple[int, int]:
        spans, capped = spans_for_bending_length(size, c)
        self.steps.append({"from": label, "bending_length_m": c, "spans": list(spans),
                           "capped": capped})
        if capped:
            self.notes.append(
                f"the grid for the {label}'s bending length {100 * c:.3g} cm "
                f"(spans of at most {SPAN_PER_BENDING_LENGTH:g} c on a "
                f"{size[0]:.3g} x {size[1]:.3g} m sheet) was capped at {MAX_SPANS} spans per "
                f"side (time and memory); a softer sheet than this resolves needs "
                f"--material-spans or a smaller sheet")
        return spans
