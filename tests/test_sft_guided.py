"""The guided search (`inverse.sft.guided`): a repeating print that defeats a global match is
re-found near the reconstruction's prediction; ambiguous and out-of-window peaks are refused."""

import cv2
import numpy as np
import pytest

from inverse.sft.camera import Camera
from inverse.sft.correspondences import FrameCorrespondences
from inverse.sft.guided import GuidedConfig, GuidedSearch, search
from inverse.sft.inputs import Template
from inverse.sft.surface import surface_positions

PERIOD = 12  # px: the print repeats every 12 px in x and y
SIZE = 200  # texture px = image px of the flat sheet (fx = 200 at z = 1)
OFFSET = 50.0  # where the texture's origin lies in frame 0 [px]


def repeating_texture(seed: int = 0) -> np.ndarray:
    """A random 12 × 12 tile repeated over a 200 × 200 texture (grey uint8), lightly blurred."""
    tile = np.random.default_rng(seed).integers(0, 256, (PERIOD, PERIOD)).astype(np.float32)
    reps = SIZE // PERIOD + 2
    image = np.tile(tile, (reps, reps))[:SIZE, :SIZE]
    image = cv2.resize(cv2.resize(image, None, fx=4, fy=4, interpolation=cv2.INTER_NEAREST),
                       None, fx=0.25, fy=0.25, interpolation=cv2.INTER_AREA)
    return np.clip(cv2.GaussianBlur(image, (0, 0), 0.7), 0, 255).astype(np.uint8)


def shifted(texture: np.ndarray, shift) -> np.ndarray:
    """A 300 × 300 frame showing the texture with its origin at OFFSET + shift [px]."""
    m = np.float32([[1, 0, OFFSET + shift[0]], [0, 1, OFFSET + shift[1]]])
    return cv2.warpAffine(texture, m, (300, 300), flags=cv2.INTER_CUBIC,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def flat_sheet(cells: int = 10) -> tuple[Template, Camera]:
    """A flat square sheet facing the camera at z = 1 m whose texture maps 1:1 to image px."""
    camera = Camera(fx=SIZE, fy=SIZE, cx=OFFSET + SIZE / 2 - 0.5,
                    cy=OFFSET + SIZE / 2 - 0.5, width=300, height=300)
    g = np.linspace(-0.5, 0.5, cells + 1)
    x, y = np.meshgrid(g, g)
    vertices = np.column_stack([x.ravel(), y.ravel(), np.ones(x.size)])
    uvs = np.column_stack([x.ravel() + 0.5, 0.5 - y.ravel()])
    n = cells + 1
    quads = [(r * n + c, r * n + c + 1, (r + 1) * n + c + 1, (r + 1) * n + c)
             for r in range(cells) for c in range(cells)]
    faces = np.array([(a, b, c) for a, b, c, _ in quads] + [(a, c, d) for a, _, c, d in quads])
    return Template(vertices=vertices, faces=faces, uvs=uvs), camera


def test_a_repeating_print_defeats_a_global_match_but_not_a_guided_one():
    texture = repeating_texture()
    truth = np.array([5.3, -3.6])  # the sheet moved by this in the image [px]
    frame = shifted(texture, truth).astype(np.float32)
    tex_xy = np.array([100.0, 90.0])
    image_xy = tex_xy + OFFSET + truth
    patch = cv2.GaussianBlur(texture.astype(np.float32), (0, 0), 0.5)
    # Globally the patch correlates as well one period away as at the truth.
    r = 10
    template_patch = patch[90 - r:90 + r + 1, 100 - r:100 + r + 1]
    score = cv2.matchTemplate(frame, template_patch, cv2.TM_CCOEFF_NORMED)
    repeats = np.argwhere(score > 0.8 * score.max())
    assert len(repeats) >= 9  # ≥ 3 × 3 periods look like the match
    # Guided: predicted 2.5 px off, searched within 4 px: the right repeat, sub-pixel.
    config = GuidedConfig()
    found = search(frame, patch, image_xy + [2.0, -1.5], tex_xy, np.eye(2), 4, config)
    assert not isinstance(found, str), found
    assert np.linalg.norm(found[0] - image_xy) < 0.2
    assert found[1] < config.fb_threshold


def test_a_window_holding_two_repeats_is_refused_as_ambiguous():
    texture = repeating_texture()
    frame = shifted(texture, (0.0, 0.0)).astype(np.float32)
    patch = cv2.GaussianBlur(texture.astype(np.float32), (0, 0), 0.5)
    tex_xy = np.array([100.0, 90.0])
    image_xy = tex_xy + OFFSET
    # A window wider than the period holds the next repeat as well.
    assert search(frame, patch, image_xy, tex_xy, np.eye(2), PERIOD + 2,
                  GuidedConfig()) == "ambiguous"


def test_a_match_outside_the_window_is_not_found_and_an_edge_peak_is_refused():
    rng = np.random.default_rng(1)
    texture = cv2.GaussianBlur(rng.integers(0, 256, (SIZE, SIZE)).astype(np.float32),
                               (0, 0), 1.5)  # no repeat
    frame = shifted(texture.astype(np.uint8), (0.0, 0.0)).astype(np.float32)
    tex_xy = np.array([100.0, 90.0])
    image_xy = tex_xy + OFFSET
    config = GuidedConfig()
    assert not isinstance(search(frame, texture, image_xy + 2.0, tex_xy, np.eye(2), 4, config),
                          str)
    # The truth just past the window's edge: the correlation rises out of it, no peak inside.
    assert search(frame, texture, image_xy + [5.0, 0.0], tex_xy, np.eye(2), 4,
                  config) == "edge"
    # The truth 9 px from the prediction, window 4 px: nothing there correlates.
    assert search(frame, texture, image_xy + [9.0, 0.0], tex_xy, np.eye(2), 4,
                  config) == "low_peak"


def test_lost_points_are_refound_where_the_reconstruction_predicts_them():
    template, camera = flat_sheet()
    texture = repeating_texture(seed=2)
    # The sheet moves right by 1, 2, then 5 px (it accelerates): the constant-velocity
    # prediction for the last frame is 2 px short.
    steps = [(0.0, 0.0), (1.0, 0.5), (2.0, 1.0), (5.0, 1.5)]
    frames = [shifted(texture, s) for s in steps]
    history = [template.vertices + [s[0] / SIZE, s[1] / SIZE, 0.0] for s in steps[1:3]]
    search_ = GuidedSearch(frames, camera, template, cv2.cvtColor(texture, cv2.COLOR_GRAY2BGR))
    truth = template.vertices + [steps[3][0] / SIZE, steps[3][1] / SIZE, 0.0]
    # The tracker kept the left half of the sheet only; its points tell the prediction error.
    left = np.flatnonzero(template.vertices[template.faces].mean(1)[:, 0] < -0.1)
    bary = np.full((len(left), 3), 1 / 3)
    tracked = FrameCorrespondences(
        face=left, bary=bary,
        xy=camera.project(surface_positions(truth, template.faces, left, bary)),
        confidence=np.ones(len(left)), track_id=np.arange(len(left)))
    found = search_.correspondences(3, history, tracked)
    stats = search_.stats[3]
    assert stats["candidates"] > 20 and stats["accepted"] >= 0.5 * stats["searched"]
    at = camera.project(surface_positions(truth, template.faces, found.face, found.bary))
    error = np.linalg.norm(found.xy - at, axis=1)
    assert np.median(error) < 0.2 and error.max() < 0.5
    # Every re-found point lies on the right half, away from the tracked left half.
    assert surface_positions(template.vertices, template.faces, found.face,
                             found.bary)[:, 0].min() > -0.1 - 0.1


def test_points_near_a_track_are_not_searched():
    template, camera = flat_sheet()
    texture = repeating_texture(seed=2)
    frames = [shifted(texture, (0.0, 0.0))] * 2
    search_ = GuidedSearch(frames, camera, template, cv2.cvtColor(texture, cv2.COLOR_GRAY2BGR))
    faces = np.arange(len(template.faces))
    bary = np.full((len(faces), 3), 1 / 3)
    everywhere = FrameCorrespondences(
        face=faces, bary=bary,
        xy=camera.project(surface_positions(template.vertices, template.faces, faces, bary)),
        confidence=np.ones(len(faces)), track_id=faces)
    assert len(search_.correspondences(1, [template.vertices], everywhere)) == 0
    assert search_.stats[1]["candidates"] == 0


def test_config_is_validated():
    with pytest.raises(ValueError):
        GuidedConfig(min_window=9.0, max_window=8.0)
    with pytest.raises(ValueError):
        GuidedConfig(peak_ratio=1.0)
