"""MP4 videos in H.264 (what browsers play), written with imageio-ffmpeg and checked by
reading them back.

imageio-ffmpeg ships an ffmpeg binary with libx264 in its wheels, so a plain install writes
H.264; OpenCV's own writer has only MPEG-4 Part 2 (mp4v), which browsers do not play. Where no
ffmpeg with libx264 can be found the writer stops with a message that says so.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable

import numpy as np

from taichi_ndf.io.output_dir import atomic_path

__all__ = ["write_video", "count_video_frames", "video_info", "VIDEO_CODEC", "VIDEO_QUALITY"]

logger = logging.getLogger(__name__)

VIDEO_CODEC = "libx264"  # H.264 / AVC
VIDEO_QUALITY = 18  # x264's constant rate factor: 18 is visually lossless for renders


def write_video(path: str | os.PathLike, frames: Iterable[np.ndarray], fps: float) -> int:
    """Write uint8 frames, (H, W, 3) BGR or (H, W) grey, all the same size, as an H.264 MP4
    (yuv420p, `VIDEO_QUALITY`).

    yuv420p needs even frame sizes: an odd width or height is padded by repeating the last
    column or row. The file appears at ``path`` only once it is complete and reads back as
    H.264 with as many frames, of the written size, as were written. Returns the number of
    frames. RuntimeError (naming the cause) where imageio-ffmpeg or its libx264 is missing.
    """
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    path = os.fspath(path)
    if not path.lower().endswith(".mp4"):
        raise ValueError(f"video path must end in .mp4 (H.264), got {path}")
    ffmpeg = _imageio_ffmpeg()
    with atomic_path(path) as temporary:
        writer, first, size, count = None, None, None, 0
        try:
            for frame in frames:
                given = np.shape(frame)[1::-1]  # (width, height) before padding
                frame = _as_rgb(frame, count)
                if writer is None:
                    first, size = given, (frame.shape[1], frame.shape[0])
                    writer = ffmpeg.write_frames(
                        str(temporary), size, fps=float(fps), codec=VIDEO_CODEC,
                        pix_fmt_in="rgb24", pix_fmt_out="yuv420p", quality=None,
                        macro_block_size=1, output_params=["-crf", str(VIDEO_QUALITY),
                                                           "-movflags", "+faststart"],
                        ffmpeg_log_level="error")
                    writer.send(None)  # start ffmpeg
                elif given != first:
                    raise ValueError(f"frame {count} is {given[0]}x{given[1]}, the first was "
                                     f"{first[0]}x{first[1]}")
                writer.send(frame)
                count += 1
        except (OSError, RuntimeError) as err:
            raise RuntimeError(f"ffmpeg could not write {path} with {VIDEO_CODEC}: {err}"
                               ) from err
        finally:
            if writer is not None:
                writer.close()
        if count == 0:
            raise ValueError(f"no frames to write to {path}")
        info = video_info(temporary)
        if info["frames"] != count or info["size"] != size or "h264" not in info["codec"]:
            raise RuntimeError(
                f"{path}: wrote {count} H.264 frames of {size[0]}x{size[1]} but read back "
                f"{info['frames']} of {info['size'][0]}x{info['size'][1]} ({info['codec']})"
            )
    logger.info("wrote %d frames to %s", count, path)
    return count


def video_info(path: str | os.PathLike) -> dict:
    """What ffmpeg decodes from a video: codec (ffmpeg's description, e.g. 'h264 (High)
    (avc1 / ...)'), size (width, height), fps and the number of frames (all decoded)."""
    ffmpeg = _imageio_ffmpeg()
    reader = ffmpeg.read_frames(os.fspath(path))
    try:
        meta = next(reader)
        frames = sum(1 for _ in reader)
    except (OSError, RuntimeError, StopIteration) as err:
        raise RuntimeError(f"ffmpeg cannot read the video {path}: {err}") from err
    finally:
        reader.close()
    return {"codec": meta.get("codec", ""), "size": tuple(meta.get("size", (0, 0))),
            "fps": meta.get("fps"), "frames": frames}


def count_video_frames(path: str | os.PathLike) -> int:
    """Number of frames ffmpeg decodes from a video file (reads them all)."""
    return video_info(path)["frames"]


def _imageio_ffmpeg():
    """The imageio_ffmpeg module with a usable ffmpeg binary, or RuntimeError saying why."""
    try:
        import imageio_ffmpeg
    except ImportError as err:
        raise RuntimeError("H.264 video needs imageio-ffmpeg (a dependency of taichi-ndf): "
                           "pip install imageio-ffmpeg") from err
    try:
        imageio_ffmpeg.get_ffmpeg_exe()
    except RuntimeError as err:
        raise RuntimeError(f"H.264 video needs an ffmpeg binary with libx264: imageio-ffmpeg "
                           f"found none ({err}); set IMAGEIO_FFMPEG_EXE to one") from err
    return imageio_ffmpeg


def _as_rgb(frame: np.ndarray, index: int) -> np.ndarray:
    frame = np.asarray(frame)
    if frame.dtype != np.uint8:
        raise ValueError(f"frame {index} must be uint8, got {frame.dtype}")
    if frame.ndim == 2:
        frame = np.repeat(frame[:, :, None], 3, axis=2)
    if frame.ndim != 3 or frame.shape[2] != 3:
        raise ValueError(f"frame {index} must have shape (H, W) or (H, W, 3), got {frame.shape}")
    pad_rows, pad_columns = frame.shape[0] % 2, frame.shape[1] % 2
    if pad_rows or pad_columns:
        frame = np.pad(frame, ((0, pad_rows), (0, pad_columns), (0, 0)), mode="edge")
    return np.ascontiguousarray(frame[:, :, ::-1])
