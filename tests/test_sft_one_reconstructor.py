"""One SfT reconstruction for both field types (issue 26): the spline and the SIREN settings go
through the same reconstructor (`inverse.sft.reconstruct.FrameReconstructor`, one `fit_frame`)
with the field their settings name, and both recover a tiny bent sequence."""

import numpy as np
import pytest
import torch
from test_sft_reconstruct import bent_pair, exact_tracks

from inverse.sft.frame_fits import reconstruct_sequence
from inverse.sft.metrics import relative_error
from inverse.sft.reconstruct import FrameReconstructor
from inverse.sft.settings import ReconstructionConfig, SplinePriorConfig
from inverse.sft.siren_prior import SirenFrameField
from inverse.sft.spline_prior import SplineFrameField
from inverse.sft.synth import default_camera

SETTINGS = {
    "spline": (SplinePriorConfig(span_edges=1.0, max_iterations=20), SplineFrameField),
    "siren": (ReconstructionConfig(width=16, energy_samples=128, steps=150, lr=3e-3,
                                   init_steps=0), SirenFrameField),
}


class Seen:
    """The fit the frame loop ran (the loop's callbacks see it as their subject)."""

    def __init__(self):
        self.fits = []

    def on_start(self, fit):
        self.fits.append(fit)


@pytest.mark.parametrize("name", sorted(SETTINGS))
def test_both_fields_go_through_the_one_reconstructor(name):
    config, frame_field = SETTINGS[name]
    camera = default_camera()
    template, bent = bent_pair()
    shapes = [template.vertices, bent]
    tracks = [exact_tracks(template, v, camera) for v in shapes]
    seen = Seen()
    result = reconstruct_sequence(template, camera, tracks, config, callbacks=[seen])
    (fit,) = seen.fits
    assert type(fit) is FrameReconstructor
    assert type(fit.frame_field) is frame_field
    assert fit.field is fit.frame_field.field
    np.testing.assert_array_equal(result.vertices[0], template.vertices)
    before = relative_error(template.vertices, bent)
    after = relative_error(result.vertices[1], bent)
    assert after < 0.3 * before, (name, before, after)
    assert result.losses[1]["reprojection"] < 1.0
    assert result.losses[1]["energy"] > 0


def test_initial_guesses_only_for_a_field_that_takes_them():
    template, _ = bent_pair()
    with pytest.raises(ValueError, match="initial guesses are not for the spline field"):
        FrameReconstructor(template, initial=[template.vertices],
                           config=SETTINGS["spline"][0])


def test_the_spline_field_keeps_the_samples_of_the_blocks_every_frame_passes(monkeypatch):
    """The template's vertices (the same tensor every frame) are sampled once; a frame's own
    points (a new tensor) are sampled anew; the rows are those of fresh samples."""
    config, _ = SETTINGS["spline"]
    camera = default_camera()
    template, bent = bent_pair()
    tracks = [exact_tracks(template, v, camera) for v in (template.vertices, bent)]
    seen = Seen()
    reconstruct_sequence(template, camera, tracks, config, callbacks=[seen])
    (fit,) = seen.fits
    field = fit.frame_field
    sampled = []
    original = field._samples_at
    monkeypatch.setattr(field, "_samples_at", lambda xi: sampled.append(xi) or original(xi))
    frame_points = fit.vertex_xi[:5].clone()
    field.rows([frame_points, fit.vertex_xi])
    kept = field.rows([frame_points.clone(), fit.vertex_xi])
    kept_jets = field.linearisation.assembly.samples.r_jets
    # the vertices kept from the sequence's last frame: only the frame's points sampled
    assert len(sampled) == 2 and not any(xi is fit.vertex_xi for xi in sampled)
    monkeypatch.setattr(field, "_last_blocks", {})
    fresh = field.rows([frame_points, fit.vertex_xi])
    assert len(sampled) == 4 and sampled[3] is fit.vertex_xi
    for a, b in zip(kept, fresh, strict=True):
        assert torch.equal(a, b)
    assert torch.equal(kept_jets, field.linearisation.assembly.samples.r_jets)
