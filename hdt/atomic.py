"""Atomic writes: a file or directory appears whole under its final name or not at all.

Everything hdt writes goes through here. A file is written to a hidden temporary sibling
(``.<name>.<random>.tmp``) and renamed over its final name; a directory is written under such a name
and swapped in with two renames (:func:`replace_dir`). A write that fails (a full disk, a read-only
file system) removes its temporary and raises the OSError with the path in ``filename``. Files and
directories get the permissions the user's umask gives (``tempfile`` alone would make them private),
so a colleague can read a shared run. Standard library only: every layer of hdt may import it.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import IO, Any, Callable, Iterator

TMP_SUFFIX = ".tmp"


def umask() -> int:
  """The process's umask, read without changing it where the kernel reports it."""
  try:
    with open("/proc/self/status") as f:
      return next(int(line.split()[1], 8) for line in f if line.startswith("Umask:"))
  except (OSError, StopIteration, ValueError, IndexError):
    old = os.umask(0o022)  # no /proc: set and restore (not thread-safe, but only off Linux)
    os.umask(old)
    return old


def file_mode() -> int:
  return 0o666 & ~umask()


def dir_mode() -> int:
  return 0o777 & ~umask()


def _prefix(path: Path) -> str:
  return f".{path.name}."


def is_temp(name: str) -> bool:
  """Whether ``name`` is one of the hidden temporaries of this module."""
  return name.startswith(".") and name.endswith(TMP_SUFFIX)


def remove(path: Path, settle: float = 0.0) -> None:
  """Deletes a file or directory tree; one that is already gone is fine. ``settle``: seconds it must
  stay gone, deleted again meanwhile (a failed writer's threads may still be creating files in it)."""
  path = Path(path)
  deadline = time.monotonic() + 10 * settle
  gone_since = None
  while True:
    if path.is_dir() and not path.is_symlink():
      shutil.rmtree(path, ignore_errors=True)
    else:
      with contextlib.suppress(FileNotFoundError):
        path.unlink()
    now = time.monotonic()
    if os.path.lexists(path):
      gone_since = None
    elif gone_since is None:
      gone_since = now
    if (gone_since is not None and now - gone_since >= settle) or now >= deadline:
      return
    time.sleep(0.1)


@contextlib.contextmanager
def open_atomic(path, mode: str = "w", **kw) -> Iterator[IO]:
  """``open`` for writing ``path`` in full: the file appears under its name only when the block ends
  without an error; otherwise the temporary is removed and the error raised."""
  with temp_path(path) as tmp, open(tmp, mode, **kw) as f:
    yield f


@contextlib.contextmanager
def temp_path(path) -> Iterator[str]:
  """The name of an empty hidden temporary beside ``path``, for writers that open files by name (a
  compiler, a video encoder): renamed over ``path`` when the block ends without an error, otherwise
  removed and the error raised. ``path`` never holds a half-written file."""
  path = Path(path)
  fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=_prefix(path), suffix=TMP_SUFFIX)
  os.close(fd)
  try:
    yield tmp
    os.chmod(tmp, file_mode())
    os.replace(tmp, path)
  except BaseException as e:
    with contextlib.suppress(OSError):
      os.unlink(tmp)
    if isinstance(e, OSError) and not e.filename:
      e.filename = str(path)
    raise


def write_text(path, text: str) -> Path:
  with open_atomic(path, "w") as f:
    f.write(text)
  return Path(path)


def write_bytes(path, data: bytes) -> Path:
  with open_atomic(path, "wb") as f:
    f.write(data)
  return Path(path)


def write_json(path, obj: Any, default: Callable | None = None) -> Path:
  """``obj`` as indented JSON with sorted keys (``default``: as ``json.dump``'s)."""
  with open_atomic(path, "w") as f:
    json.dump(obj, f, indent=1, sort_keys=True, default=default)
  return Path(path)


def temp_dir(parent, name: str) -> Path:
  """A new hidden directory ``parent/.<name>.<random>.tmp`` with the umask's permissions."""
  tmp = Path(tempfile.mkdtemp(dir=parent, prefix=f".{name}.", suffix=TMP_SUFFIX))
  os.chmod(tmp, dir_mode())
  return tmp


def make_dirs(path) -> Path:
  """``path`` and its missing parents (``mkdir -p``; the umask gives their permissions)."""
  Path(path).mkdir(parents=True, exist_ok=True)
  return Path(path)


def old(final: Path) -> Path:
  """Where :func:`replace_dir` keeps the previous version between its two renames."""
  return final.with_name(final.name + ".old")


def replace_dir(final, write: Callable[[Path], None]) -> Path:
  """Runs ``write(tmp)`` on a fresh temporary sibling of ``final``, then swaps it in with two renames
  (final -> final.old, tmp -> final). Killed at any point, either ``final`` or ``final.old`` is a
  complete earlier version (readers fall back to ``.old``); a killed write leaves only a hidden
  temporary, removed by the next write of the same name (one writer per name)."""
  final = Path(final)
  make_dirs(final.parent)
  for stale in final.parent.glob(f".{final.name}.*{TMP_SUFFIX}"):
    remove(stale)
  tmp = temp_dir(final.parent, final.name)
  try:
    write(tmp)
    if final.exists():
      if old(final).exists():
        shutil.rmtree(old(final))
      os.replace(final, old(final))
    os.replace(tmp, final)
    if old(final).exists():
      shutil.rmtree(old(final))
  except BaseException as e:
    remove(tmp, settle=1.0 if isinstance(e, OSError) else 0.0)  # a failed write's stragglers too
    if isinstance(e, OSError) and (not e.filename or str(e.filename).startswith(str(tmp))):
      e.filename = str(final) + str(e.filename or "")[len(str(tmp)):]  # the temporary is gone
    raise
  return final
