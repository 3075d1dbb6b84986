"""Memory an exported grid mesh needs, and what the machine has: refuse before the work."""

from __future__ import annotations

import os

__all__ = ["available_memory", "check_export_memory", "export_memory", "physical_memory"]

# Peak memory per vertex of evaluating, writing (OBJ + PLY) and rendering a grid mesh: measured
# 1.3-2.3 kB at 513² and 1025² vertices (f32 and f64, CPU; ru_maxrss growth over the run).
BYTES_PER_VERTEX = 2048
# Kept per vertex and frame for a trajectory video: positions (3 float64) and faces (2 per
# vertex, 3 int64).
BYTES_PER_FRAME_VERTEX = 72


def _meminfo(field: str) -> int | None:
    """A field of /proc/meminfo [bytes], None where it cannot be read."""
    try:
        with open("/proc/meminfo", encoding="ascii") as meminfo:
            for line in meminfo:
                if line.startswith(f"{field}:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def physical_memory() -> int | None:
    """Bytes of physical memory (MemTotal of /proc/meminfo, else sysconf); None where
    unknown."""
    total = _meminfo("MemTotal")
    if total is not None:
        return total
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (MemAvailable of /proc/meminfo, else the
    physical memory); None where neither is known."""
    available = _meminfo("MemAvailable")
    return available if available is not None else physical_memory()


def export_memory(resolution: tuple[int, int], frames: int = 0) -> int:
    """Estimated peak bytes of exporting a grid of `resolution` cells (and `frames` trajectory
    frames of it)."""
    vertices = (resolution[0] + 1) * (resolution[1] + 1)
    return vertices * (BYTES_PER_VERTEX + frames * BYTES_PER_FRAME_VERTEX)


def check_export_memory(resolution: tuple[int, int], what: str, frames: int = 0) -> None:
    """Raise ValueError naming `what` when exporting `resolution` needs more memory than the
    machine has available."""
    need = export_memory(resolution, frames)
    have = available_memory()
    if have is not None and need > have:
        raise ValueError(f"{what} {list(resolution)}: exporting it needs about "
                         f"{need / 2**30:.3g} GiB of memory, this machine has "
                         f"{have / 2**30:.3g} GiB available; choose a smaller resolution")
