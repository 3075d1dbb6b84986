"""The per-frame confidence of ndf-sft: how far each template vertex lies from the frame's
tracked points (`inverse.sft.correspondences.track_gaps`, `inverse.cli.sft_run.track_coverage`)."""

import numpy as np
from test_sft_outline import grid

from inverse.cli.sft import confidence_line
from inverse.cli.sft_run import track_coverage
from inverse.sft.correspondences import FrameCorrespondences, track_gaps
from inverse.sft.inputs import Template, mean_edge_length


def seen_at(faces: np.ndarray, chosen: np.ndarray) -> FrameCorrespondences:
    """One tracked point at the centroid of each chosen face (pixels unused here)."""
    n = len(chosen)
    return FrameCorrespondences(face=chosen.astype(np.int64), bary=np.full((n, 3), 1 / 3),
                                xy=np.zeros((n, 2)), confidence=np.ones(n),
                                track_id=np.arange(n, dtype=np.int64))


def test_gaps_are_template_distances_to_the_nearest_tracked_point_in_mean_edges():
    vertices, faces = grid(n=9, size=0.8)  # 8 × 8 cells, edges 0.1 m (diagonals 0.141)
    h = mean_edge_length(vertices, faces)
    chosen = np.array([0])  # the triangle (0, 1, 10): centroid (−0.4 + 0.2/3, −0.4 + 0.1/3)
    gaps = track_gaps(vertices, faces, seen_at(faces, chosen), h)
    centroid = vertices[faces[0]].mean(axis=0)
    expected = np.linalg.norm(vertices - centroid, axis=1) / h
    np.testing.assert_allclose(gaps, expected, rtol=1e-12)
    assert np.all(np.isinf(track_gaps(vertices, faces, seen_at(faces, np.array([], int)), h)))


def test_coverage_flags_only_the_frames_where_part_of_the_sheet_lost_its_tracks():
    vertices, faces = grid(n=13, size=1.2)  # 12 × 12 cells
    template = Template(vertices=vertices, faces=faces,
                        uvs=vertices[:, :2] - vertices[:, :2].min(0))
    every = seen_at(faces, np.arange(len(faces)))
    # The left half of the sheet only (cell columns 0–5): the right columns lose their tracks.
    column = (np.arange(len(faces)) // 2) % 12
    left = seen_at(faces, np.flatnonzero(column < 6))
    coverage = track_coverage(template, [every, left, every], reach=3.5)
    assert coverage["frames_with_unobserved_parts"] == [1]
    assert coverage["unobserved_vertices"][0] == coverage["unobserved_vertices"][2] == 0
    # The last tracked centroids sit at x = 5 2/3 cells; 3.5 mean edges (incl. the diagonals:
    # h = 0.114 m) reach x = 9.65 (column 9 is at most 3.4 cells away): columns 10–12 (3 × 13
    # vertices) are unobserved.
    assert abs(mean_edge_length(vertices, faces) - 0.1138) < 1e-3
    assert coverage["unobserved_vertices"][1] == 39
    assert coverage["largest_gap_mean_edges"][1] > 3.5 > coverage["largest_gap_mean_edges"][0]
    line = confidence_line(coverage, len(vertices))
    assert "1 frame(s) (1–1)" in line and "prior" in line
    assert "every vertex" in confidence_line(track_coverage(template, [every], reach=3.0),
                                             len(vertices))
