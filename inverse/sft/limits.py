"""Image sizes from file headers, and the memory that frames and textures of those sizes need:
refused before anything is decoded (``docs/sft.md`` §1).

Headers read: PNG, JPEG, BMP and TIFF (the formats of the input contract); a file whose header
cannot be read is left to the image reader, which names it.
"""

from __future__ import annotations

import struct
from pathlib import Path

from inverse.sft.errors import InputError
from taichi_ndf.io.memory import available_memory

# Peak bytes per texture pixel of a run's texture stages (decoding, grey and prefiltered
# copies, the UV chart's raster, SIFT's scale space): measured 220 and 242 B/px (peak RSS
# growth of loading the texture and tracking two frames of data/sft/roll with its texture
# resized to 0.8 and 12.6 Mpx).
BYTES_PER_TEXTURE_PIXEL = 240
# Bytes per frame pixel kept for the whole run: the BGR frame (3), its mask (1), the overlay
# video's copy (3), rounded up for the tracker's transient grey images.
BYTES_PER_FRAME_PIXEL = 8
# Larger textures are refused whatever the memory: detail beyond a few texels per image pixel
# is blurred away before use (matching.prefiltered_texture), and the tracker's start costs
# about 2.3 s per texture Mpx (34 s at 12.6 Mpx, same measurement).
MAX_TEXTURE_PIXELS = 8192 * 8192


def image_size(path: str | Path) -> tuple[int, int] | None:
    """(width, height) [px] from the image file's header, or None if it cannot be read."""
    try:
        with open(path, "rb") as f:
            head = f.read(32)
            if head.startswith(b"\x89PNG\r\n\x1a\n") and head[12:16] == b"IHDR":
                return struct.unpack(">II", head[16:24])
            if head.startswith(b"BM") and len(head) >= 26:
                w, h = struct.unpack("<ii", head[18:26])
                return w, abs(h)
            if head[:4] in (b"II*\x00", b"MM\x00*"):
                return _tiff_size(f, "<" if head[:2] == b"II" else ">")
            if head.startswith(b"\xff\xd8"):
                return _jpeg_size(f)
    except (OSError, struct.error):
        return None
    return None


def check_texture_memory(path: str | Path) -> None:
    """InputError when the texture is larger than MAX_TEXTURE_PIXELS or needs more memory than
    the machine has available (estimate from its header)."""
    size = image_size(path)
    if size is None:
        return
    pixels = size[0] * size[1]
    need = pixels * BYTES_PER_TEXTURE_PIXEL
    have = available_memory()
    if pixels > MAX_TEXTURE_PIXELS or (have is not None and need > have):
        raise InputError(
            f"texture image {path}: {size[0]}x{size[1]} needs about {need / 2**30:.3g} GiB of "
            f"memory ({'unknown' if have is None else f'{have / 2**30:.3g} GiB'} available; at "
            f"most {MAX_TEXTURE_PIXELS / 1e6:.0f} Mpx are used); give a smaller texture")


def check_frames_memory(files: list[Path], what: str = "frames") -> None:
    """InputError when the images of `files` need more memory together than is available,
    from the first file's header times their number; also when a header's size differs from
    the first's (named)."""
    if not files:
        return
    first = image_size(files[0])
    if first is None:
        return
    need = len(files) * first[0] * first[1] * BYTES_PER_FRAME_PIXEL
    have = available_memory()
    if have is not None and need > have:
        raise InputError(
            f"{what} {files[0].parent}: {len(files)} images of {first[0]}x{first[1]} need about "
            f"{need / 2**30:.3g} GiB of memory, {have / 2**30:.3g} GiB available; use fewer "
            "or smaller frames")


def check_image_folder_memory(folder: Path) -> None:
    """check_frames_memory for the images of a folder (natural order)."""
    from inverse.sft.inputs import list_images

    check_frames_memory(list_images(folder), folder.name)


def _jpeg_size(f) -> tuple[int, int] | None:
    f.seek(2)
    while True:
        marker = f.read(2)
        if len(marker) < 2 or marker[0] != 0xFF:
            return None
        code = marker[1]
        if code in (0xD8, 0x01) or 0xD0 <= code <= 0xD7:
            continue
        (length,) = struct.unpack(">H", f.read(2))
        if code in (0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE,
                    0xCF):
            h, w = struct.unpack(">HH", f.read(5)[1:5])
            return w, h
        f.seek(length - 2, 1)


def _tiff_size(f, order: str) -> tuple[int, int] | None:
    f.seek(4)
    (offset,) = struct.unpack(order + "I", f.read(4))
    f.seek(offset)
    (count,) = struct.unpack(order + "H", f.read(2))
    found = {}
    for _ in range(count):
        tag, kind, _, value = struct.unpack(order + "HHI4s", f.read(12))
        if tag in (256, 257):
            found[tag] = struct.unpack(order + ("H" if kind == 3 else "I"),
                                       value[:2] if kind == 3 else value)[0]
    return (found[256], found[257]) if len(found) == 2 else None
