"""Re-found points carried forward as tracks (`inverse.sft.carried`, `GuidedConfig.carry`): a
point found in frame k is followed into k+1..k+3 and dropped when it is occluded."""

import cv2
import numpy as np

from inverse.sft.carried import CarriedTracks
from inverse.sft.correspondences import FrameCorrespondences
from inverse.sft.guided import GUIDED_TRACK_ID, GuidedConfig, GuidedSearch
from tests.test_sft_guided import OFFSET, flat_sheet

SHIFTS = [(0.0, 0.0), (1.7, -0.8), (3.1, -1.9), (4.2, -2.6), (5.6, -3.1)]  # px per frame


def random_texture(seed: int = 1) -> np.ndarray:
    """A 200 × 200 blurred random print (grey uint8): corners everywhere, no repeats."""
    noise = np.random.default_rng(seed).integers(0, 256, (50, 50)).astype(np.float32)
    image = cv2.resize(noise, (200, 200), interpolation=cv2.INTER_CUBIC)
    return np.clip(cv2.GaussianBlur(image, (0, 0), 1.0), 0, 255).astype(np.uint8)


def frames_of(texture: np.ndarray, occluder: tuple[int, int, int, int] | None = None):
    """Frames showing the texture shifted by SHIFTS; the last one with a black square
    (x0, y0, x1, y1) over it when `occluder` is given, and the masks without that square."""
    frames, masks = [], []
    for i, s in enumerate(SHIFTS):
        m = np.float32([[1, 0, OFFSET + s[0]], [0, 1, OFFSET + s[1]]])
        frame = cv2.warpAffine(texture, m, (300, 300), flags=cv2.INTER_CUBIC)
        mask = cv2.warpAffine(np.full_like(texture, 255), m, (300, 300)) > 128
        if occluder is not None and i == len(SHIFTS) - 1:
            x0, y0, x1, y1 = occluder
            frame[y0:y1, x0:x1] = 0
            mask[y0:y1, x0:x1] = False
        frames.append(frame)
        masks.append(mask)
    return frames, masks


def found_at(xy: np.ndarray) -> FrameCorrespondences:
    n = len(xy)
    return FrameCorrespondences(np.arange(n, dtype=np.int64), np.full((n, 3), 1 / 3), xy,
                                np.ones(n), GUIDED_TRACK_ID + np.arange(n, dtype=np.int64))


def test_a_found_point_is_followed_three_frames_and_dropped_when_occluded():
    texture = random_texture()
    start = np.array([[100.0, 120.0], [180.0, 160.0], [140.0, 220.0]])  # frame 1 [px]
    frames, masks = frames_of(texture, occluder=(160, 140, 200, 180))  # hides point 1 in 4
    carried = CarriedTracks()
    carried.advance(1, frames, masks)
    carried.add(1, found_at(start))
    for t in (2, 3, 4):
        carried.advance(t, frames, masks)
        truth = start + np.subtract(SHIFTS[t], SHIFTS[1])
        seen = carried.current()
        if t < 4:
            assert list(seen.track_id - GUIDED_TRACK_ID) == [0, 1, 2]
            assert np.abs(seen.xy - truth).max() < 0.2
            assert (seen.confidence > 0.3).all()
        else:  # the occluded point is gone, the others go on
            assert list(seen.track_id - GUIDED_TRACK_ID) == [0, 2]
            assert np.abs(seen.xy - truth[[0, 2]]).max() < 0.2


def test_points_not_seen_in_the_frame_before_are_not_carried():
    texture = random_texture()
    frames, masks = frames_of(texture)
    carried = CarriedTracks()
    carried.add(1, found_at(np.array([[100.0, 120.0]])))
    carried.advance(3, frames, masks)  # frame 2 skipped: nothing to follow from
    assert len(carried) == 0


def test_the_guided_search_carries_what_it_found():
    """Frame 1: the guided search re-finds the lost points; frames 2–3: they come back as
    the same tracks, followed from the image (not searched again), at the true pixels."""
    texture = random_texture()
    template, camera = flat_sheet()
    frames, masks = frames_of(texture)
    metres = [np.array([s[0], s[1], 0.0]) / camera.fx for s in SHIFTS]  # shift at z = 1
    history = [template.vertices + metres[0]]
    nothing = found_at(np.zeros((0, 2)))
    results = {}
    for carry in (True, False):
        search = GuidedSearch(frames, camera, template, texture, masks=masks,
                              config=GuidedConfig(carry=carry))
        out = [search.correspondences(1, history, nothing)]
        history1 = history + [template.vertices + metres[1]]
        out.append(search.correspondences(2, history1, nothing))
        out.append(search.correspondences(3, history1 + [template.vertices + metres[2]],
                                          nothing))
        results[carry] = (out, search.stats)
    out, stats = results[True]
    assert len(out[0]) > 20
    assert stats[2]["carried"] >= 0.9 * len(out[0])
    assert set(out[0].track_id) <= set(out[2].track_id)
    for t, seen in ((2, out[1]), (3, out[2])):
        rest = np.einsum("nk,nkd->nd", seen.bary, template.vertices[template.faces[seen.face]])
        truth = camera.project(rest + metres[t])
        assert np.median(np.linalg.norm(seen.xy - truth, axis=1)) < 0.2
    # Without carrying, each frame is searched afresh and nothing is carried.
    assert "carried" not in results[False][1][2]
