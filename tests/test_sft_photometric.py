"""The photometric term (inverse.sft.photometric): lighting-free levels, the residual is smallest
at the true surface, its Gauss–Newton rows are the value's slope, and a fit uses it."""

import numpy as np
import pytest
import torch

from inverse.sft.photometric import PhotometricEvidence, normalised, photometric_evidence
from inverse.sft.settings import ReconstructionConfig, SplinePriorConfig
from inverse.sft.surface import surface_positions
from inverse.sft.synth import SynthConfig, generate
from taichi_ndf import jets


@pytest.fixture(scope="module")
def sequence():
    return generate(SynthConfig(sequence="fold", frames=3, seed=0, image_size=(320, 240),
                                focal=300.0, texture_size=(512, 384), supersample=1))


def evidence(synth, **kwargs):
    return PhotometricEvidence(synth.frames, synth.camera, synth.template, synth.texture,
                               masks=synth.masks, **kwargs)


def test_the_level_ignores_gain_and_offset():
    gray = np.random.default_rng(0).uniform(0, 255, (60, 80)).astype(np.float32)
    a, b = normalised(gray, 2.0), normalised(0.5 * gray + 40.0, 2.0)
    np.testing.assert_allclose(a, b, atol=1e-3)
    assert abs(float(a.std()) - 1.0) < 0.3


def residual_rms(term, u):
    return term.parts(u)["photometric"] ** 0.5


def jets_of(u):
    out = torch.zeros(len(u), jets.CHANNELS, 3, dtype=torch.float64)
    out[:, jets.VALUE] = u
    return out


def test_the_residual_is_smallest_on_the_true_surface(sequence):
    ev = evidence(sequence, sigma=1.5, points=800)
    truth = sequence.vertices[2]
    frame = ev.frame(2, truth)
    assert len(frame.xi) > 400
    term = frame.term(sequence.camera, torch.arange(len(frame.xi)))
    # the visible points' displacements from the template to the truth
    moved = surface_positions(truth, sequence.template.faces, ev.face, ev.bary)
    u = torch.from_numpy(moved[frame.index] - ev.rest[frame.index])
    at_truth = residual_rms(term, jets_of(u))
    # 2 px sideways at the sheet's depth
    shift = torch.tensor([2.0 * float(truth[:, 2].mean()) / sequence.camera.fx, 0.0, 0.0],
                         dtype=torch.float64)
    shifted = residual_rms(term, jets_of(u + shift))
    assert at_truth < 0.6 * shifted, (at_truth, shifted)


def test_the_rows_are_the_slope_of_the_value(sequence):
    ev = evidence(sequence, sigma=3.0, points=300, huber_px=100.0)
    frame = ev.frame(1, sequence.vertices[1])
    rows = torch.arange(len(frame.xi))
    term = frame.term(sequence.camera, rows)
    u = jets_of(torch.zeros(len(rows), 3, dtype=torch.float64))
    value, grad = term.evaluate(None, u)
    blocks = term.hessian_blocks(None, u, steps=None)
    # Gauss–Newton at a quadratic: E(u + h) ≈ E + g·h + ½ hᵀHh along a small shift
    h = torch.zeros_like(u)
    h[:, jets.VALUE] = 1e-4 * torch.tensor([1.0, -0.5, 0.3], dtype=torch.float64)
    change = term.evaluate(None, u + h, grad=False)[0] - value
    linear = float((grad * h).sum())
    quadratic = 0.5 * float(torch.einsum("nai,naibj,nbj->", h, blocks, h))
    assert change == pytest.approx(linear + quadratic, rel=0.1, abs=1e-3 * abs(value))


def test_only_a_spline_config_with_a_weight_asks_for_it(sequence):
    args = (sequence.frames, sequence.camera, sequence.template, sequence.texture)
    assert photometric_evidence(SplinePriorConfig(), *args) is None
    assert photometric_evidence(ReconstructionConfig(), *args) is None
    ev = photometric_evidence(SplinePriorConfig(photometric_weight=2.0, photometric_points=500),
                              *args, masks=sequence.masks)
    assert ev.weight == 2.0 and 300 < len(ev.rest) < 700


@pytest.mark.parametrize("name, value", [("photometric_weight", -1.0),
                                         ("photometric_sigma", 0.0),
                                         ("photometric_points", 0)])
def test_config_refuses_bad_photometric_values(name, value):
    with pytest.raises(ValueError, match=name):
        SplinePriorConfig(**{name: value})


def test_with_few_tracks_the_texture_brings_the_fit_closer(sequence):
    """Frame 2 of the fold from 12 exact tracks: the photometric term sees the rest."""
    from test_sft_reconstruct import exact_tracks

    from inverse.sft.frame_fits import reconstruct_sequence

    tracks = [exact_tracks(sequence.template, v, sequence.camera, count=12, seed=i)
              for i, v in enumerate(sequence.vertices)]
    errors = {}
    for weight in (0.0, 1.0):
        config = SplinePriorConfig(photometric_weight=weight, photometric_points=600)
        result = reconstruct_sequence(
            sequence.template, sequence.camera, tracks, config, masks=sequence.masks,
            photometric=photometric_evidence(config, sequence.frames, sequence.camera,
                                             sequence.template, sequence.texture,
                                             masks=sequence.masks))
        errors[weight] = float(np.linalg.norm(result.vertices[2] - sequence.vertices[2],
                                              axis=1).mean())
        assert ("photometric" in result.losses[2]) == (weight > 0)
    assert errors[1.0] < 0.8 * errors[0.0], errors


def test_the_cli_refuses_the_term_on_the_siren(tmp_path, capsys):
    from inverse.cli import sft as sft_cli

    status = sft_cli.main(["--frames", str(tmp_path / "none"), "--camera", "c.json",
                           "--template", "t.obj", "--texture", "x.png", "--out",
                           str(tmp_path / "out"), "--precision", "f64", "--field", "siren",
                           "--photometric-weight", "1"])
    assert status == 2
    assert "--photometric-weight" in capsys.readouterr().err


def test_a_library_caller_handing_the_term_to_the_siren_is_refused(sequence):
    """The SIREN's frame fit does not take the term: refused, not silently dropped."""
    from inverse.sft.frame_fits import reconstruct_sequence

    evidence = photometric_evidence(SplinePriorConfig(photometric_weight=1.0,
                                                      photometric_points=100),
                                    sequence.frames, sequence.camera, sequence.template,
                                    sequence.texture, masks=sequence.masks)
    with pytest.raises(ValueError, match="photometric term is for the spline field"):
        reconstruct_sequence(sequence.template, sequence.camera, [], ReconstructionConfig(),
                             photometric=evidence)
