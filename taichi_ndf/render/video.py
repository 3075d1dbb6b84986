"""MP4 videos written with OpenCV and checked by reading them back."""

import logging
import os
from collections.abc import Iterable

import cv2
import numpy as np

from taichi_ndf.io.output_dir import atomic_path

__all__ = ["write_video", "count_video_frames"]

logger = logging.getLogger(__name__)


def write_video(path: str | os.PathLike, frames: Iterable[np.ndarray], fps: float) -> int:
    """Write uint8 frames, (H, W, 3) BGR or (H, W) grey, all the same size, as an MP4 (mp4v).

    MPEG-4 needs even frame sizes: an odd width or height is padded by repeating the last column
    or row. The file appears at ``path`` only once it is complete and OpenCV has read back as
    many frames, of the written size, as were written. Returns the number of frames.
    """
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    path = os.fspath(path)
    if not path.lower().endswith(".mp4"):
        raise ValueError(f"video path must end in .mp4 (mp4v codec), got {path}")
    with atomic_path(path) as temporary:
        writer = None
        count = 0
        try:
            for frame in frames:
                frame = _as_bgr(frame, count)
                if writer is None:
                    size = (frame.shape[1], frame.shape[0])
                    writer = cv2.VideoWriter(
                        str(temporary), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), size
                    )
                    if not writer.isOpened():
                        raise RuntimeError(
                            f"cv2.VideoWriter could not open {path} with codec mp4v at "
                            f"{size[0]}x{size[1]}; this OpenCV build may lack a video backend"
                        )
                elif (frame.shape[1], frame.shape[0]) != size:
                    raise ValueError(
                        f"frame {count} is {frame.shape[1]}x{frame.shape[0]}, "
                        f"the first was {size[0]}x{size[1]}"
                    )
                writer.write(frame)
                count += 1
        finally:
            if writer is not None:
                writer.release()
        if count == 0:
            raise ValueError(f"no frames to write to {path}")
        read_back, read_size = _probe(temporary)
        if read_back != count or read_size != size:
            raise RuntimeError(
                f"{path}: wrote {count} frames of {size[0]}x{size[1]} but OpenCV reads back "
                f"{read_back} of {read_size[0]}x{read_size[1]}"
            )
    logger.info("wrote %d frames to %s", count, path)
    return count


def count_video_frames(path: str | os.PathLike) -> int:
    """Number of frames OpenCV decodes from a video file (reads them all)."""
    return _probe(path)[0]


def _probe(path) -> tuple[int, tuple[int, int]]:
    """Frames OpenCV decodes from a video and their (width, height)."""
    capture = cv2.VideoCapture(os.fspath(path))
    if not capture.isOpened():
        raise RuntimeError(f"OpenCV cannot open the video {path}")
    count, size = 0, (0, 0)
    try:
        while True:
            ok, frame = capture.read()
            if not ok:
                break
            count, size = count + 1, (frame.shape[1], frame.shape[0])
    finally:
        capture.release()
    return count, size


def _as_bgr(frame: np.ndarray, index: int) -> np.ndarray:
    frame = np.asarray(frame)
    if frame.dtype != np.uint8:
        raise ValueError(f"frame {index} must be uint8, got {frame.dtype}")
    if frame.ndim == 2:
        frame = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    if frame.ndim != 3 or frame.shape[2] != 3:
        raise ValueError(f"frame {index} must have shape (H, W) or (H, W, 3), got {frame.shape}")
    pad_rows, pad_columns = frame.shape[0] % 2, frame.shape[1] % 2
    if pad_rows or pad_columns:
        frame = cv2.copyMakeBorder(frame, 0, pad_rows, 0, pad_columns, cv2.BORDER_REPLICATE)
    return np.ascontiguousarray(frame)
