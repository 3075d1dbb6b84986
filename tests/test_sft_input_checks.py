"""Inputs that do not fit together are refused by ndf-sft before any expensive work, in one
line (exit 2): a template in other axes, UVs that do not match the texture, a NaN vertex,
textures and frames too large for the memory, point clouds in another frame."""

import struct
import zlib

import cv2
import numpy as np
import pytest

from inverse.cli import sft
from inverse.sft import limits
from inverse.sft.metrics import surface_samples
from inverse.sft.synth import SynthConfig, generate, write_sequence
from taichi_ndf.io import write_obj


@pytest.fixture(scope="module")
def sequence():
    return generate(SynthConfig(sequence="fold", frames=2, image_size=(320, 240), focal=300.0,
                                texture_size=(256, 192), cells=(14, 10), supersample=1))


@pytest.fixture
def contract(sequence, tmp_path):
    """The sequence written as the input contract (png frames, masks, template, texture)."""
    return write_sequence(sequence, tmp_path / "inputs", frame_format="png")


def run(d, *extra, template=None, texture=None, tmp=None):
    return sft.main(["--frames", str(d / "frames"), "--camera", str(d / "camera.json"),
                     "--template", str(template or d / "template.obj"),
                     "--texture", str(texture or d / "texture.png"), "--masks", str(d / "masks"),
                     "--method", "baseline", "--out", str(d.parent / "out"), *extra])


def refused(capsys, code) -> str:
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_a_template_in_other_axes_is_refused(sequence, contract, capsys):
    flipped = contract / "flipped.obj"
    write_obj(flipped, sequence.vertices[0] * [-1, -1, 1], sequence.faces, uvs=sequence.uvs)
    line = refused(capsys, run(contract, template=flipped))
    # The sheet is near the image centre, so its point reflection still overlaps the mask: the
    # texture check catches it and finds the flip that fits.
    assert "flipped.obj UVs: the texture mapped through them does not match frame 0" in line
    assert "the template's axes look flipped: with x and y negated the texture matches" in line
    aside = contract / "aside.obj"
    write_obj(aside, sequence.vertices[0] + [1.0, 0, 0], sequence.faces, uvs=sequence.uvs)
    line = refused(capsys, run(contract, template=aside))
    assert "aside.obj: only 0 % of its vertices project inside the 320x240 image" in line


def test_uvs_that_do_not_match_the_texture_are_refused(sequence, contract, capsys):
    flipped_uvs = contract / "vflip.obj"
    write_obj(flipped_uvs, sequence.vertices[0], sequence.faces,
              uvs=sequence.uvs * [1, -1] + [0, 1])
    line = refused(capsys, run(contract, template=flipped_uvs))
    assert "vflip.obj UVs: the texture mapped through them does not match frame 0" in line
    assert "median patch NCC -" in line


def test_a_nan_template_vertex_is_named(contract, capsys):
    lines = (contract / "template.obj").read_text().splitlines()
    row = [i for i, line in enumerate(lines) if line.startswith("v ")][7]
    lines[row] = "v nan 0 0.5"
    (contract / "nan.obj").write_text("\n".join(lines) + "\n")
    line = refused(capsys, run(contract, template=contract / "nan.obj"))
    assert "nan.obj: vertices [7] are not finite (NaN or inf)" in line


def png_header(path, width, height):
    """A PNG signature and IHDR chunk of the given size (no image data: never decodable)."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    chunk = b"IHDR" + ihdr
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + struct.pack(">I", len(ihdr)) + chunk
                     + struct.pack(">I", zlib.crc32(chunk)))
    return path


def test_a_huge_texture_is_refused_from_its_header(contract, capsys):
    huge = png_header(contract / "huge.png", 20000, 20000)
    line = refused(capsys, run(contract, texture=huge))
    assert "huge.png: 20000x20000 needs about 89.4 GiB of memory" in line


def test_frames_beyond_the_memory_are_refused(contract, capsys, monkeypatch):
    # 1 MiB "available": a 32 x 24 texture fits (0.18 MB), two 320 x 240 frames do not (1.2 MB).
    monkeypatch.setattr(limits, "available_memory", lambda: 1 << 20)
    small = contract / "small.png"
    cv2.imwrite(str(small), np.zeros((24, 32, 3), np.uint8))
    line = refused(capsys, run(contract, texture=small))
    assert "frames: 2 images of 320x240 need about" in line and "GiB available" in line


def test_clouds_in_another_frame_are_refused(sequence, contract, capsys):
    gt = contract / "clouds"
    gt.mkdir()
    for i, v in enumerate(sequence.vertices):
        np.save(gt / f"{i:03d}.npy", surface_samples(v, sequence.faces, count=500) * [-1, -1, 1])
    line = refused(capsys, run(contract, "--gt", str(gt)))
    assert "000.npy: the template's vertices are" in line
    assert "not in the camera's coordinates of frame 0" in line


def test_fitting_inputs_pass_the_checks(sequence, contract):
    from inverse.cli.sft_inputs import load_run_inputs

    gt = contract / "clouds"
    gt.mkdir()
    for i, v in enumerate(sequence.vertices):
        np.save(gt / f"{i:03d}.npy", surface_samples(v, sequence.faces, count=500))
    args = sft.build_parser().parse_args([
        "--frames", str(contract / "frames"), "--camera", str(contract / "camera.json"),
        "--template", str(contract / "template.obj"), "--texture", str(contract / "texture.png"),
        "--masks", str(contract / "masks"), "--gt", str(gt), "--out", str(contract / "o")])
    loaded = load_run_inputs(args)
    assert loaded.gt_kind == "clouds" and len(loaded.gt) == 2


@pytest.mark.parametrize("suffix", [".png", ".jpg", ".bmp", ".tif"])
def test_image_sizes_come_from_the_headers(tmp_path, suffix):
    path = tmp_path / f"image{suffix}"
    cv2.imwrite(str(path), np.zeros((37, 53, 3), np.uint8))
    assert limits.image_size(path) == (53, 37)
    (tmp_path / "other.png").write_bytes(b"not an image")
    assert limits.image_size(tmp_path / "other.png") is None
