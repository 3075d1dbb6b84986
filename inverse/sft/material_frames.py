"""The frames of a video that the material estimate uses, and how far each is from rest.

Each used frame is fitted as an equilibrium (`material_from_video`): the sheet at rest under
gravity with its corners held. A frame whose sheet accelerates is not one. The reconstruction
says how much it accelerates: the second difference of every vertex over a stencil of
`STENCIL` frames at the frame rate,

    a_f = rms over vertices of |x_{f+k} − 2 x_f + x_{f−k}| · (fps / k)²,   k = STENCIL,

(a frame within k of either end takes its nearest interior frame's value; a sequence shorter
than 2k + 1 frames has no value). A wider stencil divides the reconstruction's frame-to-frame
noise by k² (measured on φ-SfT's R1 at an assumed 30 fps: k = 1 gave 0.05–0.47 g per frame,
k = 3 0.02–0.13 g, benchmarks/RESULTS.md, Material from video, 2026-12-06 15:30). A sheet
swinging about its corner line like a pendulum by an angle θ accelerates by about g θ, so
a_f / g is roughly the angle [rad] by which the frame is off its rest shape.

`quasi_static_limit` (a fraction of g; None: every frame is taken as an equilibrium, the
default, as for the synthetic sequences of rendered equilibria whose "frame rate" is nominal)
keeps only the frames with a_f ≤ limit · g; frame 0, the template's frame whose shape gives the
flat sheet's size (`material_from_video.unstretched_grid`), is always kept. `frames` of them
are then used, evenly spread (`chosen_frames`).

The held corners' own accelerations (`corner_accelerations`) are reported beside
(`QUASI_STATIC_LIMIT`).
"""

from __future__ import annotations

import numpy as np

QUASI_STATIC_LIMIT = 0.05  # corner acceleration / g above which a frame is not quasi-static
STENCIL = 3  # frames between the three samples of a sheet's second difference


def chosen_frames(count: int, used: int) -> list[int]:
    """`used` frame indices evenly spread over `count` frames (all when used is 0 or more)."""
    if used == 0 or used >= count:
        return list(range(count))
    return sorted({int(round(i)) for i in np.linspace(0, count - 1, used)})


def corner_accelerations(vertices: list[np.ndarray], held: tuple[int, int],
                         fps: float) -> np.ndarray:
    """Largest acceleration [m/s²] of the two held corners per interior frame (second
    differences at the frame rate); (F − 2,)."""
    corners = np.stack([np.asarray(v)[list(held)] for v in vertices])  # (F, 2, 3)
    if len(corners) < 3:
        return np.zeros(0)
    second = corners[2:] - 2 * corners[1:-1] + corners[:-2]
    return np.linalg.norm(second, axis=2).max(axis=1) * fps ** 2


def sheet_accelerations(vertices: list[np.ndarray], fps: float,
                        stencil: int = STENCIL) -> np.ndarray | None:
    """a_f [m/s²] per frame (F,) (module docstring), or None when the sequence has fewer
    than 2 · stencil + 1 frames."""
    x = np.stack([np.asarray(v, dtype=np.float64) for v in vertices])  # (F, V, 3)
    k = int(stencil)
    if len(x) < 2 * k + 1:
        return None
    second = x[2 * k:] - 2 * x[k:-k] + x[:-2 * k]
    interior = np.sqrt(np.mean(np.sum(second ** 2, axis=2), axis=1)) * (fps / k) ** 2
    return np.concatenate([np.full(k, interior[0]), interior, np.full(k, interior[-1])])


def used_frames(vertices: list[np.ndarray], used: int, fps: float, gravity: float,
                limit: float | None) -> tuple[list[int], dict]:
    """The used frames (module docstring) and the record of the choice: the per-frame
    a_f / g, the limit and the frames that met it."""
    accelerations = sheet_accelerations(vertices, fps)
    over_g = None if accelerations is None else accelerations / gravity
    record = {"limit_over_g": limit, "stencil": STENCIL, "fps": fps,
              "sheet_acceleration_over_g": None if over_g is None else over_g.tolist()}
    if limit is None or over_g is None:
        record["eligible"] = list(range(len(vertices)))
        record["note"] = ("every frame taken as an equilibrium" if limit is None else
                          f"fewer than {2 * STENCIL + 1} frames: no acceleration measured, "
                          "every frame taken as an equilibrium")
        return chosen_frames(len(vertices), used), record
    eligible = [0] + [f for f in range(1, len(vertices)) if over_g[f] <= limit]
    record["eligible"] = eligible
    record["note"] = (f"{len(eligible)} of {len(vertices)} frames with the sheet's rms "
                      f"acceleration at most {limit:g} g (frame 0 always)")
    return [eligible[i] for i in chosen_frames(len(eligible), used)], record
