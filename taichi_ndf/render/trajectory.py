"""Frames of a trajectory video: each state of a run (load steps or pseudo-time frames) coloured
by its displacement on one colour range, with the obstacles and the ground shadow, from one
camera that frames every state and sees the surface over the trajectory (`visible_azimuth`),
and a label with the load factor (or pseudo-time)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from taichi_ndf.render.camera import PREFERRED_AZIMUTH_DEG, widest_azimuth_over
from taichi_ndf.render.colour import ROBUST_PERCENTILES, colour_scale
from taichi_ndf.render.figure import VIEWS, Obstacle, render_figure
from taichi_ndf.render.shaded import BACKGROUND_BGR

__all__ = ["trajectory_frames", "frame_repeats", "real_time_fps", "put_label", "MIN_SECONDS",
           "FPS", "LABEL_ROWS", "visible_azimuth"]

FPS = 4.0  # frames per second of a trajectory video
MIN_SECONDS = 3.0  # a short trajectory's states are repeated so that the video lasts this long
MAX_FPS = 60.0  # a dynamic run's video plays in real time up to this frame rate
HOLD_SECONDS = 1.0  # the last state is held this long at the end
# Sub-pixels per pixel along each axis of a video frame: 2 (4 samples) instead of the still
# pictures' 3 (9), the frames' main cost (docs/dynamics.md, "Outputs"; benchmarks/RESULTS.md).
SUPERSAMPLE = 2
_INK = (40, 40, 40)
# Rows from the top that `put_label`'s text and box take (the box ends at row 41 for the
# font's 0.7 scale), plus a gap: `render_figure(label_rows=...)` keeps them free of the surface.
LABEL_ROWS = 46
VISIBILITY_STATES = 8  # states (evenly spaced, first and last included) `visible_azimuth` sees


def frame_repeats(states: int, fps: float = FPS) -> int:
    """How many video frames show each state so that `states` of them last MIN_SECONDS."""
    return max(1, math.ceil(MIN_SECONDS * fps / max(states, 1)))


def real_time_fps(times: Sequence[float]) -> float:
    """The frame rate [1/s] at which states at `times` [s] (a dynamic run's output frames,
    evenly spaced but for a shorter last one) play in real time: their number over the time
    they span, within [1, MAX_FPS]."""
    span = float(times[-1]) - float(times[0]) if len(times) > 1 else 0.0
    if not span > 0:
        return 1.0
    return min(MAX_FPS, max(1.0, (len(times) - 1) / span))


def put_label(image: np.ndarray, text: str, *, boxed: bool = False) -> None:
    """Write `text` into the top left corner of a BGR image (in place); `boxed`: on a box of
    the background's colour, so that it stays legible over the surface."""
    if boxed:
        (width, height), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.7, 2)
        cv2.rectangle(image, (8, 30 - height - 6), (20 + width, 30 + base + 4),
                      tuple(int(c) for c in BACKGROUND_BGR), -1)
    cv2.putText(image, text, (14, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.7, _INK, 2, cv2.LINE_AA)


def visible_azimuth(
    states: Sequence[np.ndarray],
    faces: np.ndarray,
    obstacles: Sequence[Sequence[Obstacle]] | None = None,
    *,
    up=(0.0, 0.0, 1.0),
    elevation_deg: float = 30.0,
    preferred_deg: float = PREFERRED_AZIMUTH_DEG,
) -> float:
    """The azimuth [deg] of a video's camera: `widest_azimuth_over` up to VISIBILITY_STATES of
    `states` (evenly spaced, the first and the last included) with their obstacles. The
    surface's visible area over the trajectory, not the final state's silhouette alone: a
    sheet sliding on a tilted table top is seen from above the top, not from beside it where
    the table hides it until it slides off (sheet_slide_box)."""
    obstacles = [()] * len(states) if obstacles is None else list(obstacles)
    picks = np.unique(np.linspace(0, len(states) - 1, min(len(states), VISIBILITY_STATES))
                      .round().astype(int))
    return widest_azimuth_over([states[k] for k in picks], faces,
                               [obstacles[k] for k in picks], up=up,
                               elevation_deg=elevation_deg, preferred_deg=preferred_deg)


def trajectory_frames(
    states: Sequence[np.ndarray],
    faces: np.ndarray,
    load_factors: Sequence[float],
    *,
    reference: np.ndarray,
    obstacles: Sequence[Sequence[Obstacle]] | None = None,
    up=(0.0, 0.0, 1.0),
    pseudo_time: bool = False,
    physical_time: bool = False,
    size: tuple[int, int] = (800, 600),
    fps: float = FPS,
) -> list[np.ndarray]:
    """The video frames (uint8 BGR, `size` = (width, height)) of `states` (positions (V, 3)
    [m] on `faces`) at `load_factors`: coloured by |u| = |x − reference| [m] on the 1st–99th
    percentile of every state's values together (one colour bar, the same in every frame,
    states what it clips over all of them), rendered with SUPERSAMPLE from the three-quarter
    view's elevation at `visible_azimuth` (the surface seen largest over the trajectory,
    obstacles in front of it counted as hiding it),
    `obstacles` per state (their meshes at that state), each state repeated `frame_repeats`
    times and the last held HOLD_SECONDS longer. Labels: "load factor λ (step k of n)",
    "t λ" with `pseudo_time`, "t = λ s (frame k of n)" with `physical_time` (a dynamic
    run's times [s])."""
    if len(states) != len(load_factors) or not len(states):
        raise ValueError(f"need one load factor per state, got {len(load_factors)} for "
                         f"{len(states)} states")
    obstacles = [()] * len(states) if obstacles is None else list(obstacles)
    reference = np.asarray(reference, dtype=np.float64)
    displacement = [np.linalg.norm(np.asarray(s, dtype=np.float64) - reference, axis=1)
                    for s in states]
    scale = colour_scale(np.concatenate(displacement), ROBUST_PERCENTILES)
    every = np.concatenate([np.asarray(s, dtype=np.float64).reshape(-1, 3) for s in states]
                           + [np.asarray(o.vertices).reshape(-1, 3) for group in obstacles
                              for o in group])
    azimuth = visible_azimuth(states, faces, obstacles, up=up, elevation_deg=VIEWS["iso"][0])
    word = "t" if pseudo_time else "load factor"
    width, height = size
    pictures = []
    for k, (state, values, factor) in enumerate(zip(states, displacement, load_factors,
                                                    strict=True)):
        image = render_figure(state, faces, scalars=values, scalar_label="|u| [m]",
                              scalar_range=scale, obstacles=tuple(obstacles[k]), up=up,
                              width=width, height=height, frame_points=every,
                              azimuth_deg=azimuth, supersample=SUPERSAMPLE,
                              label_rows=LABEL_ROWS)
        if physical_time:
            label = f"t = {factor:.2f} s  (frame {k + 1} of {len(states)})"
        else:
            label = f"{word} {factor:.3g}" + ("" if pseudo_time else
                                               f"  (step {k + 1} of {len(states)})")
        put_label(image, label)
        pictures += [image] * (1 if physical_time else frame_repeats(len(states), fps))
    return pictures + [pictures[-1]] * int(round(HOLD_SECONDS * fps))
