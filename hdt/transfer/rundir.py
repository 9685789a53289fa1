"""Run directories hdt owns: which directories it may write, a lock per directory, atomic replacement.

hdt writes only into a directory that does not exist yet, is empty, or is an hdt directory of the
same kind (it holds the marker ``.hdt-run``; runs written before the marker are recognised by their
``meta.json`` or saved training state). Anything else is refused with a message naming what is
there. While a process writes a directory it holds an exclusive ``flock`` on ``.hdt-lock`` inside
it; the kernel drops the lock when the process dies (even by SIGKILL), so a lock left by a dead
process is simply taken over. ``overwrite`` moves the old directory aside with one rename before
anything new is written, so the new run never shares the directory with a file of the old one.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import shutil
import signal
import threading
from pathlib import Path
from typing import Iterator

MARKER = ".hdt-run"
LOCK = ".hdt-lock"
# Writing a run under these would touch the operating system's own files.
SYSTEM_DIRS = tuple(Path(p) for p in ("/bin", "/boot", "/dev", "/etc", "/lib", "/lib64", "/proc", "/sbin",
                                      "/sys", "/usr", "/var/lib", "/var/log"))

LAST_CLAIMED: list[Path] = []  # directories claimed by this process, latest last (for the Ctrl-C message)


class RunDirError(ValueError):
  """A directory hdt may not write into, or one another process is writing."""


def _what_is_there(path: Path, limit: int = 4) -> str:
  names = sorted(p.name + ("/" if p.is_dir() else "") for p in path.iterdir())
  return ", ".join(names[:limit]) + (f" and {len(names) - limit} more" if len(names) > limit else "")


def _marker_kind(path: Path) -> str | None:
  """The kind recorded in ``path``'s marker; "run" for runs written before markers; else None."""
  try:
    kind = json.loads((path / MARKER).read_text()).get("kind")
    return kind if isinstance(kind, str) else None
  except (OSError, ValueError, AttributeError):
    pass
  legacy = [path / "meta.json", path / "state" / "state.json", path / "state.old" / "state.json"]
  return "run" if any(p.is_file() for p in legacy) else None


def check_out(out, what: str = "out") -> Path:
  """``out`` as a Path, refused (RunDirError, nothing written) if it is empty, an existing file, under
  a file or a system directory, or in a directory this process cannot write."""
  if out is None or not str(out).strip():
    raise RunDirError(f"{what} is empty, which would write into the current directory; give a directory "
                      f"name, e.g. runs/my-run")
  path = Path(out).expanduser()
  full = Path(os.path.abspath(path))
  if any(full == s or s in full.parents for s in SYSTEM_DIRS) or full == Path("/"):
    raise RunDirError(f"{what}={out} is a system directory; pick a directory of your own, e.g. runs/my-run")
  if path.exists() and not path.is_dir():
    raise RunDirError(f"{what}={out} is an existing file; pass a directory for the run (it will hold "
                      f"config.json, metrics.csv, seed_0/, state/, ...)")
  parent = next(p for p in [full, *full.parents] if p.exists())
  if not parent.is_dir():
    raise RunDirError(f"{what}={out} lies under the file {parent}; pass a path whose parents are directories")
  # Checked without writing anything: permissions, and a read-only mount (which root's access() misses).
  if not os.access(parent, os.W_OK | os.X_OK) or os.statvfs(parent).f_flag & os.ST_RDONLY:
    raise RunDirError(f"{what}={out}: cannot write in {parent} (permission denied or a read-only file "
                      f"system); pass a directory you can write to")
  return path


def is_empty(path: Path) -> bool:
  """No entries but hdt's own bookkeeping (marker, lock, a killed save's hidden temporaries)."""
  return all(p.name in (MARKER, LOCK) or (p.name.startswith(".") and p.name.endswith(".tmp"))
             for p in path.iterdir())


def check_claimable(out, kind: str = "run", resume: bool = False, overwrite: bool = False,
                    reuse: bool = False, what: str = "out") -> Path:
  """Read-only checks of :func:`claim`: ``out`` must be new, empty, or an hdt directory of ``kind``
  that ``resume`` / ``overwrite`` / ``reuse`` (add to it) allows writing."""
  path = check_out(out, what)
  if not path.exists() or is_empty(path):
    return path
  found = _marker_kind(path)
  if found is None:
    raise RunDirError(f"{what}={out} is not an hdt directory and not empty (it holds {_what_is_there(path)}); "
                      f"hdt writes only into new or empty directories or its own runs: pass another {what}")
  if found != kind:
    raise RunDirError(f"{what}={out} holds an hdt {found} directory where this command writes {'an' if kind[0] in 'aeiou' else 'a'} {kind} "
                      f"directory; pass another {what}")
  if not (resume or overwrite or reuse):
    raise RunDirError(f"{out} already holds a {kind}: pass --resume (resume=True) to continue it, --overwrite "
                      f"(overwrite=True) to replace it, or another {what}")
  return path


def _holder(lock_path: Path) -> str:
  try:
    return f"PID {int(lock_path.read_text().split()[0])}"
  except (OSError, ValueError, IndexError):
    return "another process"


@contextlib.contextmanager
def _locked(path: Path, kind: str) -> Iterator[None]:
  """Holds ``path``/.hdt-lock (creating ``path`` and its marker) until the block ends."""
  path.mkdir(parents=True, exist_ok=True)
  lock_path = path / LOCK
  fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)
  try:
    try:
      fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as e:
      if e.errno not in (errno.EAGAIN, errno.EACCES):
        raise
      raise RunDirError(f"{path} is in use by {_holder(lock_path)}, which is writing to it; wait for it to "
                        f"finish (or stop it), or pass another --out") from None
    os.ftruncate(fd, 0)
    os.write(fd, f"{os.getpid()}\n".encode())
    if not (path / MARKER).exists():
      from hdt.transfer.checkpoint import write_json_atomic  # checkpoint imports nothing from here
      write_json_atomic(path / MARKER, {"kind": kind})
    LAST_CLAIMED.append(path)
    yield
  finally:
    os.close(fd)  # releases the flock


def _aside(path: Path) -> Path:
  return path.with_name(f".{path.name}.replaced-{os.getpid()}")


@contextlib.contextmanager
def claim(out, kind: str = "run", resume: bool = False, overwrite: bool = False,
          reuse: bool = False) -> Iterator[Path]:
  """Checks ``out`` (:func:`check_claimable`), locks it, and yields it as a Path. With ``overwrite``
  an existing directory is first locked (so nobody is writing it), moved aside in one rename and
  deleted; the block then writes a fresh directory."""
  path = check_claimable(out, kind, resume, overwrite, reuse)
  for stale in path.parent.glob(f".{path.name}.replaced-*"):  # left by a killed overwrite
    shutil.rmtree(stale, ignore_errors=True)
  if overwrite and not resume and path.exists() and not is_empty(path):
    with _locked(path, kind):
      aside = _aside(path)
      os.replace(path, aside)
    shutil.rmtree(aside)
  with _locked(path, kind):
    yield path


def discard(out, kind: str = "run") -> None:
  """Deletes the hdt directory ``out`` of ``kind`` (refused as :func:`claim` refuses), e.g. a run to
  be retrained; a directory of anything else is never deleted."""
  with claim(out, kind, overwrite=True):
    pass


@contextlib.contextmanager
def deferred_interrupt() -> Iterator[None]:
  """Ctrl-C (SIGINT) inside the block is held back until the block ends, so a checkpoint being
  written is finished rather than left half done (only in the main thread; elsewhere a no-op)."""
  if threading.current_thread() is not threading.main_thread():
    yield
    return
  caught = []
  previous = signal.signal(signal.SIGINT, lambda *a: caught.append(a))
  try:
    yield
  finally:
    signal.signal(signal.SIGINT, previous)
    if caught:
      if callable(previous):
        previous(*caught[0])
      else:
        os.kill(os.getpid(), signal.SIGINT)
