"""Synthetic shape-from-template sequences with exact ground truth.

A textured sheet deforms (exactly isometric roll or fold, or any given sequence of vertex
arrays, e.g. the toolkit's own simulated equilibria), is rendered by the z-buffered, supersampled
rasteriser of ``taichi_ndf.render`` over a background, and degraded like a camera image.
Everything is deterministic by seed. ``write_sequence`` lays the result out as the input contract
of ``docs/sft.md`` plus ground truth::

    DIR/frames/000000.jpg ...   (or .png files, or DIR/frames.mp4)
    DIR/masks/000000.png ...    rendered silhouettes (255 on the sheet)
    DIR/gt/000000.obj ...       ground-truth meshes, template vertex order
    DIR/camera.json  DIR/template.obj (frame-0 ground truth with UVs)  DIR/texture.png
    DIR/synth.json              the generation settings

Command line: ``python -m inverse.sft.synth --out DIR --sequence roll --frames 30``.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from inverse.sft.camera import Camera, write_camera
from inverse.sft.deformations import CornerLift, Fold, Pose, Roll, Wave
from inverse.sft.degradations import Degradations
from inverse.sft.inputs import Template
from inverse.sft.texture import cluttered_background, sheet_texture
from taichi_ndf.io import OutputDir, grid_mesh, write_obj
from taichi_ndf.render import render_textured, write_video

log = logging.getLogger(__name__)

FRAME_FORMATS = ("jpg", "png", "mp4")
SEQUENCES = ("roll", "fold", "corner", "wave")  # the motion families (`deformations`)


def default_camera(width: int = 640, height: int = 480, *, focal: float = 600.0) -> Camera:
    """Pinhole camera with square pixels and the principal point at the image centre."""
    return Camera(fx=focal, fy=focal, cx=(width - 1) / 2.0, cy=(height - 1) / 2.0,
                  width=width, height=height)


@dataclass(frozen=True)
class SynthConfig:
    """A synthetic sequence.

    sequence: one of SEQUENCES (roll, fold, corner lift-and-drop, flag-like wave); frames:
    number of frames (t = 0 … 1); seed: texture, background
    and noise; sheet_size: (width, height) [m]; cells: grid cells along (width, height);
    texture_size: (width, height) [px]; supersample: sub-pixels per pixel and axis;
    clutter: cluttered background (else mid grey); degradations: camera effects.
    """

    sequence: str = "roll"
    frames: int = 30
    seed: int = 0
    image_size: tuple[int, int] = (640, 480)
    focal: float = 600.0
    sheet_size: tuple[float, float] = (0.28, 0.21)
    cells: tuple[int, int] = (28, 21)
    texture_size: tuple[int, int] = (1024, 768)
    supersample: int = 3
    clutter: bool = True
    roll: Roll = field(default_factory=Roll)
    fold: Fold = field(default_factory=Fold)
    corner: CornerLift = field(default_factory=CornerLift)
    wave: Wave = field(default_factory=Wave)
    pose: Pose = field(default_factory=Pose)
    degradations: Degradations = field(default_factory=Degradations)

    def __post_init__(self):
        if self.sequence not in SEQUENCES:
            raise ValueError(f"sequence must be one of {SEQUENCES}, got {self.sequence!r}")
        if self.frames < 1:
            raise ValueError(f"frames must be >= 1, got {self.frames}")
        if min(self.sheet_size) <= 0:
            raise ValueError(f"sheet_size must be positive, got {self.sheet_size}")
        if min(self.cells) < 1:
            raise ValueError(f"cells must be positive, got {self.cells}")
        if self.supersample < 1:
            raise ValueError(f"supersample must be >= 1, got {self.supersample}")


@dataclass(frozen=True)
class SyntheticSequence:
    """A rendered sequence with its ground truth.

    vertices: ground-truth positions per frame, camera coordinates [m], shape (n, 3) each;
    frames: degraded BGR uint8 images; masks: bool silhouettes (h, w); encoded: the JPEG bytes
    of each frame when the degradations include a JPEG round trip, else None.
    """

    camera: Camera
    faces: np.ndarray
    uvs: np.ndarray
    texture: np.ndarray
    vertices: list[np.ndarray]
    frames: list[np.ndarray]
    masks: list[np.ndarray]
    encoded: list[bytes] | None = None

    @property
    def template(self) -> Template:
        """Frame-0 ground truth as the template of the input contract."""
        return Template(vertices=self.vertices[0], faces=self.faces, uvs=self.uvs)


def flat_sheet(
    sheet_size: tuple[float, float], cells: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flat sheet centred at the origin of its frame.

    Returns points (n, 2) [m], faces (m, 3) and UVs (n, 2), with the texture upright when the
    sheet frame's y axis points down the image (OpenCV camera axes).
    """
    w, h = sheet_size
    grid = grid_mesh(((-w / 2, w / 2), (-h / 2, h / 2)), cells)
    uvs = np.column_stack([grid.uv[:, 0], 1.0 - grid.uv[:, 1]])
    return grid.xi, grid.faces, uvs


def deformed_vertices(config: SynthConfig) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """Ground-truth camera-frame vertices per frame, faces and UVs of the configured sequence."""
    points, faces, uvs = flat_sheet(config.sheet_size, config.cells)
    motion = getattr(config, config.sequence)
    times = np.linspace(0.0, 1.0, config.frames) if config.frames > 1 else np.zeros(1)
    vertices = [
        config.pose.apply(motion.shape(points, t, sheet_width=config.sheet_size[0]), t)
        for t in times
    ]
    return vertices, faces, uvs


def render_sequence(
    vertices: Sequence[np.ndarray],
    faces: np.ndarray,
    uvs: np.ndarray,
    texture: np.ndarray,
    camera: Camera,
    *,
    background: np.ndarray | None = None,
    degradations: Degradations | None = None,
    supersample: int = 3,
    seed: int = 0,
) -> tuple[list[np.ndarray], list[np.ndarray], list[bytes] | None]:
    """Render any sequence of vertex arrays (camera coordinates [m], shape (n, 3) each).

    This is the hook for rendering meshes from elsewhere, e.g. simulated equilibria.
    texture: BGR uint8; background: BGR uint8 image of the camera size or None (mid grey).
    Returns degraded frames, silhouette masks and, with JPEG, the encoded frames.
    """
    degradations = degradations or Degradations()
    width, height = camera.size
    if background is None:
        background = np.full((height, width, 3), 128, dtype=np.uint8)
    frames, masks, encoded = [], [], []
    n = len(vertices)
    for i, v in enumerate(vertices):
        image, mask = render_textured(
            v, faces, uvs, texture, camera.K, width, height,
            supersample=supersample, background=background,
        )
        rng = np.random.default_rng([seed, i])
        degraded, jpeg = degradations.apply(image, i / max(n - 1, 1), rng)
        frames.append(degraded)
        masks.append(mask)
        encoded.append(jpeg)
    return frames, masks, (encoded if degradations.jpeg_quality is not None else None)


def generate(config: SynthConfig) -> SyntheticSequence:
    """Render the configured sequence with its ground truth (deterministic by config.seed)."""
    camera = default_camera(*config.image_size, focal=config.focal)
    vertices, faces, uvs = deformed_vertices(config)
    texture = sheet_texture(*config.texture_size, seed=config.seed)
    background = (
        cluttered_background(*config.image_size, seed=config.seed + 1) if config.clutter else None
    )
    frames, masks, encoded = render_sequence(
        vertices, faces, uvs, texture, camera, background=background,
        degradations=config.degradations, supersample=config.supersample, seed=config.seed,
    )
    log.info("rendered %d %s frames %dx%d", len(frames), config.sequence, *config.image_size)
    return SyntheticSequence(camera=camera, faces=faces, uvs=uvs, texture=texture,
                             vertices=vertices, frames=frames, masks=masks, encoded=encoded)


def write_sequence(
    sequence: SyntheticSequence,
    out: str | Path,
    *,
    frame_format: str = "jpg",
    settings: dict | None = None,
    overwrite: bool = False,
) -> Path:
    """Write the sequence as the SfT input contract plus ground truth (layout in module doc).

    frame_format: "jpg" (the JPEG round-trip bytes themselves, so files hold exactly the
    degraded frames; needs a JPEG degradation), "png" (lossless) or "mp4" (H.264, lossy).
    settings: generation settings recorded in synth.json.
    """
    if frame_format not in FRAME_FORMATS:
        raise ValueError(f"frame_format must be one of {FRAME_FORMATS}, got {frame_format!r}")
    if frame_format == "jpg" and sequence.encoded is None:
        raise ValueError("frame_format 'jpg' needs a JPEG degradation (jpeg_quality); use 'png'")
    run = OutputDir(out, overwrite=overwrite)
    for i, frame in enumerate(sequence.frames):
        if frame_format == "jpg":
            run.file(f"frames/{i:06d}.jpg").write_bytes(sequence.encoded[i])
        elif frame_format == "png":
            _write_image(run.file(f"frames/{i:06d}.png"), frame)
        _write_image(run.file(f"masks/{i:06d}.png"), sequence.masks[i].astype(np.uint8) * 255)
        write_obj(run.file(f"gt/{i:06d}.obj"), sequence.vertices[i], sequence.faces)
    if frame_format == "mp4":
        write_video(run.file("frames.mp4"), sequence.frames, fps=30.0)
    write_camera(sequence.camera, run.file("camera.json"))
    write_obj(run.file("template.obj"), sequence.vertices[0], sequence.faces, uvs=sequence.uvs)
    _write_image(run.file("texture.png"), sequence.texture)
    run.write_json("synth.json", settings or {})
    log.info("wrote %d frames to %s", len(sequence.frames), run.path)
    return run.path


def _write_image(path: Path, image: np.ndarray) -> None:
    if not cv2.imwrite(str(path), image):
        raise OSError(f"OpenCV could not write {path}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m inverse.sft.synth",
        description="Render a synthetic shape-from-template sequence with exact ground truth.",
    )
    parser.add_argument("--out", required=True, help="output directory (must be new or empty)")
    parser.add_argument("--sequence", choices=SEQUENCES, default="roll")
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--format", choices=FRAME_FORMATS, default="jpg", dest="frame_format")
    parser.add_argument("--noise", type=float, default=2.0, help="noise std [1/255 units]")
    parser.add_argument("--blur", type=float, default=0.5, help="Gaussian blur std [px]")
    parser.add_argument("--jpeg", type=int, default=80, help="JPEG quality; 0 for none")
    parser.add_argument("--gain-drift", type=float, default=0.1)
    parser.add_argument("--offset-drift", type=float, default=0.02)
    parser.add_argument("--no-clutter", action="store_true", help="plain grey background")
    parser.add_argument("--texture-size", type=int, nargs=2, default=(1024, 768),
                        metavar=("W", "H"))
    parser.add_argument("--supersample", type=int, default=3)
    parser.add_argument("--overwrite", action="store_true")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    degradations = Degradations(
        noise_sigma=args.noise / 255.0, blur_sigma=args.blur,
        jpeg_quality=args.jpeg or None, gain_drift=args.gain_drift, offset_drift=args.offset_drift,
    )
    config = SynthConfig(
        sequence=args.sequence, frames=args.frames, seed=args.seed, clutter=not args.no_clutter,
        texture_size=tuple(args.texture_size), supersample=args.supersample,
        degradations=degradations,
    )
    sequence = generate(config)
    settings = {"command": "python -m inverse.sft.synth " + " ".join(argv),
                "config": asdict(config)}
    write_sequence(sequence, args.out, frame_format=args.frame_format, settings=settings,
                   overwrite=args.overwrite)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
