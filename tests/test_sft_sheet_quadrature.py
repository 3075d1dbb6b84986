"""The prior's energy samples cover the sheet: span Gauss points on a chart that fills its
rectangle, one point per triangle on a tilted chart (UVs projected from a first frame)."""

import numpy as np
import torch

from inverse.sft.inputs import Template
from inverse.sft.reconstruct import FrameReconstructor
from inverse.sft.settings import SplinePriorConfig
from inverse.sft.synth import flat_sheet


def sheet():
    points, faces, uvs = flat_sheet((0.2, 0.15), (10, 8))
    vertices = np.column_stack([points, np.full(len(points), 0.5)])
    return vertices, faces, uvs


def reconstructor(uvs, vertices, faces):
    template = Template(vertices=vertices, faces=faces, uvs=uvs)
    return FrameReconstructor(template, config=SplinePriorConfig()).frame_field


def chart_area(uvs, faces):
    t = uvs[faces]
    a, b = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    return 0.5 * np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]).sum()


def test_rectangular_chart_keeps_span_gauss_points():
    vertices, faces, uvs = sheet()
    solver = reconstructor(uvs, vertices, faces)
    spans = solver.field.config.spans
    assert len(solver.quadrature) == spans[0] * spans[1] * 9  # 3 x 3 per span
    np.testing.assert_allclose(float(solver.quadrature.weight.sum()), chart_area(uvs, faces),
                               rtol=1e-12)


def test_tilted_chart_is_covered_to_its_outline():
    vertices, faces, uvs = sheet()
    angle = 0.15  # rad: the chart no longer fills its bounding rectangle
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    tilted = (uvs - 0.5) @ rotation.T + 0.5
    solver = reconstructor(tilted, vertices, faces)
    samples = solver.quadrature
    assert len(samples) == len(faces)
    np.testing.assert_allclose(float(samples.weight.sum()), chart_area(tilted, faces),
                               rtol=1e-12)
    assert bool(solver.surface.domain.contains(samples.xi).all())
    # every triangle has its point: the centroids
    np.testing.assert_allclose(samples.xi.numpy(), tilted[faces].mean(axis=1), atol=1e-12)
    assert torch.isfinite(samples.r_jets).all()
