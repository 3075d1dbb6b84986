"""The claim of an output directory by one run: a second run on it is refused while the first
runs, and the lock a killed run left behind is recognised and taken over.

The claim is the file ``<dir>.lock`` beside the directory, held with an exclusive `flock` for
the run's lifetime: the kernel drops that lock when the process ends, however it ends (SIGKILL,
a crash, a power cut), so a lock is never stale while its holder runs and never live after it.
The file records the holder (pid, host, the process's start time, the command line) for the
refusal's message and the takeover's log line. Where `flock` does not exclude (a filesystem
without it, a platform without `fcntl`), a holder recorded on this host whose pid still runs
the same process (same start time, so a reused pid is not mistaken for it) is refused too.
"""

from __future__ import annotations

import json
import logging
import os
import socket
import sys
import time
import weakref
from pathlib import Path

try:
    import fcntl
except ImportError:  # not POSIX: the recorded holder's liveness is the only check
    fcntl = None

__all__ = ["OutputLockedError", "RunLock", "held_by_a_live_run", "lock_path"]

logger = logging.getLogger(__name__)


class OutputLockedError(FileExistsError):
    """Another live run holds the output directory (a FileExistsError: the tools already
    report those in one line with exit code 2)."""


def lock_path(path: str | os.PathLike) -> Path:
    """The lock file of the output directory `path`: ``<path>.lock`` beside it."""
    path = Path(path)
    return path.with_name(path.name + ".lock")


def held_by_a_live_run(path: str | os.PathLike) -> bool:
    """Whether a run that still runs on this host holds the claim of output directory `path`
    (its lock file names a live process). Reads only: takes no lock, so it cannot refuse a run
    that is starting."""
    try:
        holder = json.loads(lock_path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return False
    return isinstance(holder, dict) and _alive(holder)


def _start_time(pid: int) -> str | None:
    """The start time of process `pid` in clock ticks since boot (Linux /proc), None where
    unknown."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return stat.rsplit(")", 1)[1].split()[19]  # field 22; the name in (...) may hold spaces


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    except OSError:
        return False
    return True


def _holder() -> dict:
    return {"pid": os.getpid(), "host": socket.gethostname(), "start": _start_time(os.getpid()),
            "started": time.strftime("%Y-%m-%d %H:%M:%S %Z"), "command": " ".join(sys.argv)}


def _alive(holder: dict) -> bool:
    """Whether the recorded `holder` is a process that still runs here (False for another
    host's: its liveness is not known here, and flock answers for it)."""
    if holder.get("host") != socket.gethostname() or not isinstance(holder.get("pid"), int):
        return False
    pid = holder["pid"]
    if pid == os.getpid() or not _running(pid):
        return False
    start = _start_time(pid)
    return start is None or holder.get("start") in (None, start)


def _describe(holder: dict) -> str:
    return (f"pid {holder.get('pid', '?')} on {holder.get('host', '?')}, started "
            f"{holder.get('started', '?')}")


def _read(fd: int) -> dict:
    os.lseek(fd, 0, os.SEEK_SET)
    text = b""
    while chunk := os.read(fd, 65536):
        text += chunk
    try:
        holder = json.loads(text.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError):
        return {"unreadable": True} if text else {}
    return holder if isinstance(holder, dict) else {"unreadable": True}


class RunLock:
    """The claim of output directory `path` by this process (module docstring).

    Raises OutputLockedError (one line naming the holder) if another live run holds it.
    Released by `release()`, by leaving a ``with`` block, when the object is collected, or at
    interpreter exit; the kernel drops the flock if the process dies without any of these.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self.file = lock_path(self.path)
        self.file.parent.mkdir(parents=True, exist_ok=True)
        fd = self._acquire()
        previous = _read(fd)
        if previous and _alive(previous):
            os.close(fd)
            raise OutputLockedError(self._refusal(previous))
        if previous:
            logger.warning("output directory %s: taking over the lock %s of a run that is no "
                           "longer running (%s)", self.path, self.file,
                           "unreadable" if previous.get("unreadable") else _describe(previous))
        os.ftruncate(fd, 0)
        os.lseek(fd, 0, os.SEEK_SET)
        os.write(fd, (json.dumps(_holder()) + "\n").encode("utf-8"))
        os.fsync(fd)
        self._finalizer = weakref.finalize(self, _release, fd, self.file)

    def _acquire(self) -> int:
        """An open descriptor of the lock file that this process holds the flock of."""
        while True:
            fd = os.open(self.file, os.O_RDWR | os.O_CREAT, 0o644)
            if fcntl is None:
                return fd
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _read(fd)
                os.close(fd)
                raise OutputLockedError(self._refusal(holder)) from None
            try:
                same = os.stat(self.file).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                return fd
            os.close(fd)  # the holder released (and removed) the file meanwhile: open anew

    def _refusal(self, holder: dict) -> str:
        return (f"output directory {self.path} is in use by another run ({_describe(holder)}; "
                f"lock {self.file}); wait for it to finish or choose another --out")

    @property
    def held(self) -> bool:
        return self._finalizer.alive

    def release(self) -> None:
        """Remove the lock file and drop the flock (idempotent)."""
        self._finalizer()

    def __enter__(self) -> RunLock:
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    def __repr__(self) -> str:
        return f"RunLock({str(self.path)!r}, held={self.held})"


def _release(fd: int, file: Path) -> None:
    # Removed while still locked, then closed: a run that opened the old file meanwhile finds
    # it unlinked after its flock (`_acquire`) and opens the new one.
    try:
        file.unlink(missing_ok=True)
    finally:
        os.close(fd)
