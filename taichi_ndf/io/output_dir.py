"""Run directories that are never silently reused nor mixed, and atomic file writes."""

from __future__ import annotations

import fnmatch
import json
import logging
import os
import shutil
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from taichi_ndf.io.run_lock import RunLock

__all__ = ["OutputDir", "atomic_path", "check_output_dir", "incomplete_path", "staged_run"]

logger = logging.getLogger(__name__)


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary sibling of ``path`` to write; on success it replaces ``path`` at once.

    The temporary name keeps the suffix, so writers that pick a format from the extension
    (OpenCV) work. Readers never see a half-written file; on error the temporary is removed and
    ``path`` is left as it was.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.stem}.{uuid.uuid4().hex[:8]}.partial{path.suffix}")
    try:
        yield temporary
        if not temporary.exists():
            raise FileNotFoundError(f"nothing was written to {temporary} for {path}")
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)


def check_output_dir(path: str | os.PathLike, overwrite: bool = False) -> None:
    """Raise FileExistsError if `path` cannot hold a new run: it is a file, or a non-empty
    directory and not `overwrite`. Creates nothing."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise FileExistsError(f"output path {path} exists and is not a directory")
    if not overwrite and path.is_dir() and any(path.iterdir()):
        raise FileExistsError(f"output directory {path} is not empty; choose a new directory or "
                              "allow overwriting (overwrite=True, --overwrite)")


class OutputDir:
    """A run's output directory: created if missing, refused if it already holds files or
    another live run holds it (`RunLock`: ``<path>.lock``, held until `release()`, the end of a
    ``with`` block, the object's collection or the process's end).

    path: the directory; its parents are created.
    overwrite: allow a non-empty directory (files written again are replaced, others are kept;
        this is also how a run is resumed in place).
    lock: the claim to hold; None: claim `path` here (`staged_run` passes the claim of the
        final directory it stages).
    """

    def __init__(self, path: str | os.PathLike, *, overwrite: bool = False,
                 lock: RunLock | None = None):
        self.path = Path(path)
        self.lock = RunLock(self.path) if lock is None else lock
        try:
            check_output_dir(self.path, overwrite)
        except BaseException:
            if lock is None:
                self.lock.release()
            raise
        if self.path.is_dir() and any(self.path.iterdir()):
            logger.warning("writing into non-empty output directory %s", self.path)
        self.path.mkdir(parents=True, exist_ok=True)

    def file(self, name: str) -> Path:
        """Path of the file ``name`` (may contain sub-folders, which are created) in the run."""
        relative = Path(name)
        if relative.is_absolute() or ".." in relative.parts:
            raise ValueError(f"output file name must be relative and inside the run: {name!r}")
        target = self.path / relative
        target.parent.mkdir(parents=True, exist_ok=True)
        return target

    def write_text(self, name: str, text: str) -> Path:
        """Write a text file atomically; returns its path."""
        target = self.file(name)
        with atomic_path(target) as temporary:
            temporary.write_text(text, encoding="utf-8")
        return target

    def write_json(self, name: str, data) -> Path:
        """Write strict JSON (NaN and infinity are refused: they are not JSON) atomically."""
        return self.write_text(name, json.dumps(data, indent=2, allow_nan=False) + "\n")

    def release(self) -> None:
        """Let other runs claim the directory (`RunLock.release`)."""
        self.lock.release()

    def __enter__(self) -> OutputDir:
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    def __repr__(self) -> str:
        return f"OutputDir({str(self.path)!r})"


def incomplete_path(path: str | os.PathLike) -> Path:
    """The staging folder of the run in `path`: ``<path>.incomplete`` beside it."""
    path = Path(path)
    return path.with_name(path.name + ".incomplete")


@contextmanager
def staged_run(path: str | os.PathLike, *, overwrite: bool = False, resume: bool = False,
               products: tuple[str, ...] = ()) -> Iterator[OutputDir]:
    """Yield the OutputDir of a run that is written into ``<path>.incomplete`` and moved into
    place as `path` only when the block completes.

    So `path` holds one complete run; after an error or Ctrl-C it holds the previous complete
    run (if any) and the failed attempt lies beside it in ``<path>.incomplete``.
    overwrite: allow replacing the run in a non-empty `path`; entries of `path` named in
        `products` (the files a run writes; a name or a glob pattern such as "mesh_*.obj") that
        the new run did not write are removed with the previous run, other entries (a user's
        notes) are kept.
    resume: continue from ``<path>.incomplete`` if it holds checkpoint.pt, else from the
        complete run in `path` (copied into the staging folder first); FileNotFoundError if
        neither has a checkpoint.
    A fresh run (no `resume`) removes an earlier incomplete attempt, never that of a live run:
    the run claims `path` (`RunLock`) before it looks at either folder, and holds the claim
    until the run is in place (OutputLockedError while another live run holds it).
    """
    path = Path(path)
    with RunLock(path) as lock:
        yield from _staged(path, overwrite, resume, products, lock)


def _staged(path: Path, overwrite: bool, resume: bool, products: tuple[str, ...],
            lock: RunLock) -> Iterator[OutputDir]:
    stage = incomplete_path(path)
    check_output_dir(path, overwrite or resume)
    if stage.exists() and not stage.is_dir():
        raise FileExistsError(f"{stage} exists and is not a directory")
    if resume:
        if (stage / "checkpoint.pt").is_file():
            logger.info("resuming the incomplete attempt in %s", stage)
        elif (path / "checkpoint.pt").is_file():
            shutil.rmtree(stage, ignore_errors=True)
            shutil.copytree(path, stage)
        else:
            raise FileNotFoundError(f"--resume: no checkpoint at {stage / 'checkpoint.pt'} or "
                                    f"{path / 'checkpoint.pt'}")
    elif stage.exists():
        logger.warning("removing the earlier incomplete attempt %s", stage)
        shutil.rmtree(stage)
    stage.mkdir(parents=True, exist_ok=True)
    try:
        yield OutputDir(stage, overwrite=True, lock=lock)
    except BaseException:
        if not any(stage.iterdir()):
            stage.rmdir()  # nothing was written: no attempt to keep
        raise
    _commit(stage, path, products)


def _commit(stage: Path, path: Path, products: tuple[str, ...]) -> None:
    """Move the complete run in `stage` into place as `path` (see `staged_run`)."""
    if not path.exists():
        os.replace(stage, path)
        return
    for entry in path.iterdir():
        ours = any(fnmatch.fnmatchcase(entry.name, product) for product in products)
        if not ours and not (stage / entry.name).exists():
            os.replace(entry, stage / entry.name)  # not the run's: kept
    previous = path.with_name(f".{path.name}.previous-{uuid.uuid4().hex[:8]}")
    os.replace(path, previous)
    os.replace(stage, path)
    shutil.rmtree(previous)
