"""Run directories hdt owns: the one rule for where hdt writes, a lock per directory, atomic replacement.

hdt writes only into a directory that is new or empty, or that it wrote itself: one holding its marker
``.hdt-run`` (written by hdt with the directory's kind and identity when it first claims it). Runs
written before the marker count as hdt's only with all of hdt's own structure (``config.json``,
``meta.json`` and a ``seed_<i>/meta.json`` checkpoint, or a saved training state): a directory that
merely holds a ``meta.json`` is the user's. The directory must also not lie inside another hdt run (a
sweep, a quickstart or an experiment holds runs), not be, hold or lie inside a run the command reads
(its LL, HL or imitated LL, resolved through symlinks and ``zoo:``), not be a symbolic link, and not
lie in the model zoo unless the command is ``hdt zoo export``. Anything else is refused with a message
naming what is there, and never with the advice to overwrite it.

While a process writes a directory it holds an exclusive ``flock`` on the directory itself (and on
``.hdt-lock`` in it, which names its PID); the kernel drops the locks when the process dies (even by
SIGKILL), so a lock left by a dead process is simply taken over, and deleting ``.hdt-lock`` does not
unlock a directory. A lock guards the directory, not its name: if the directory is deleted or moved
while its process runs (and perhaps a new run started under its name), that process's saves are
refused (:func:`check_held`). ``overwrite`` moves the old directory aside to a unique hidden name of hdt's own
with one rename before anything new is written, so the new run never shares the directory with a
file of the old one, and a sibling hdt did not create is never touched. A claim that fails before
anything was saved removes what it created.
"""

from __future__ import annotations

import contextlib
import datetime
import errno
import fcntl
import json
import os
import socket
import tempfile
import uuid
from pathlib import Path
from typing import Iterator, Mapping

from hdt import atomic
from hdt.transfer import names
from hdt.version import __version__

MARKER = ".hdt-run"
LOCK = ".hdt-lock"
REPLACED = ".hdt-replaced"  # inside a run that an overwrite moved aside: what it replaced
CONTAINERS = ("sweep", "quickstart", "experiment")  # kinds of directory that hold runs of their own
# Writing a run under these would touch the operating system's own files.
SYSTEM_DIRS = tuple(Path(p) for p in ("/bin", "/boot", "/dev", "/etc", "/lib", "/lib64", "/proc", "/sbin",
                                      "/sys", "/usr", "/var/lib", "/var/log"))

LAST_CLAIMED: list[Path] = []  # directories claimed by this process, latest last (for the Ctrl-C message)
_HELD: dict[Path, int] = {}  # directories this process holds locked -> an open descriptor of each


class RunDirError(ValueError):
  """A directory hdt may not write into, or one another process is writing."""


def _what_is_there(path: Path, limit: int = 4) -> str:
  names = sorted(p.name + ("/" if p.is_dir() else "") for p in path.iterdir())
  return ", ".join(names[:limit]) + (f" and {len(names) - limit} more" if len(names) > limit else "")


def _json_object(path: Path) -> dict | None:
  try:
    obj = json.loads(path.read_text())
  except (OSError, ValueError):
    return None
  return obj if isinstance(obj, dict) else None


def _legacy_run(path: Path) -> bool:
  """A run written before the marker: all of hdt's files, or a resumable state of hdt's format."""
  seeds = [p for p in path.glob("seed_*") if p.name.removesuffix(".old")[5:].isdigit()]
  complete = ((path / "config.json").is_file() and _json_object(path / "meta.json") is not None
              and any(_json_object(p / "meta.json") is not None for p in seeds))
  state = any((_json_object(path / d / "state.json") or {}).get("kind") == "train_state"
              for d in ("state", "state.old"))
  return complete or state


def owner_kind(path) -> str | None:
  """The kind of hdt directory ``path`` is ("run", "sweep", "eval", ...), None if hdt did not write it."""
  path = Path(path)
  if not path.is_dir():
    return None
  kind = (_json_object(path / MARKER) or {}).get("kind")
  if isinstance(kind, str):
    return kind
  return "run" if _legacy_run(path) else None


def _marker(kind: str) -> dict:
  return dict(kind=kind, id=uuid.uuid4().hex, created=datetime.datetime.now().isoformat(timespec="seconds"),
              host=socket.gethostname(), pid=os.getpid(), hdt_version=__version__)


def check_out(out, what: str = "out") -> Path:
  """``out`` as a Path, refused (RunDirError, nothing written) if it is empty, not a path, a symbolic
  link, an existing file, under a file or a system directory, or in a directory this process cannot
  write."""
  if not (out is None or isinstance(out, (str, os.PathLike))):
    raise RunDirError(f"{what}={out!r}: give the run directory as a path (str or pathlib.Path), e.g. runs/my-run")
  if out is None or not str(out).strip():
    raise RunDirError(f"{what} is empty, which would write into the current directory; give a directory "
                      f"name, e.g. runs/my-run")
  path = Path(out).expanduser()
  full = Path(os.path.abspath(path))
  if any(full == s or s in full.parents for s in SYSTEM_DIRS) or full == Path("/"):
    raise RunDirError(f"{what}={out} is a system directory; pick a directory of your own, e.g. runs/my-run")
  if path.is_symlink():
    raise RunDirError(f"{what}={out} is a symbolic link (to {os.readlink(path)}); hdt does not write through "
                      f"links: pass the directory itself, or a new directory")
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
  """No entries at all, or hdt's marker and nothing but its bookkeeping (lock, a killed save's hidden
  temporaries): a directory without the marker that holds anything is not hdt's to take."""
  names = [p.name for p in path.iterdir()]
  return not names or (MARKER in names and all(n in (MARKER, LOCK) or atomic.is_temp(n) for n in names))


def _real(path) -> Path:
  return Path(os.path.realpath(os.path.expanduser(str(path))))


def _inputs(reads) -> list[tuple[str, Path]]:
  """(label, resolved directory) of each run a command reads; ``reads``: {label: path} or paths."""
  items = reads.items() if isinstance(reads, Mapping) else [("", r) for r in reads or ()]
  out = []
  for label, r in items:
    if r is None:
      continue
    try:
      out.append((label, _real(names.resolve(r))))
    except names.ZooError:
      continue  # an unknown zoo name is reported where it is read
  return out


def refuse_zoo(path, what: str = "out", instead: str = "a directory outside it, e.g. runs/my-run") -> None:
  """Refuses ``path`` in the model zoo, which only ``hdt zoo export`` writes."""
  real, zoo_dir = _real(path), _real(names.ZOO_DIR)
  if real == zoo_dir or zoo_dir in real.parents:
    raise RunDirError(f"{what}={path} lies in the model zoo ({zoo_dir}), which only `hdt zoo export` writes; "
                      f"pass {instead}")


def check_place(path, what: str = "out", reads=(), zoo_ok: bool = False) -> None:
  """Refuses ``path`` in the model zoo (unless ``zoo_ok``), inside another hdt run, or where it is,
  holds or lies inside a run the command reads (``reads``: see :func:`_inputs`)."""
  real = _real(path)
  if not zoo_ok:
    refuse_zoo(path, what)
  for parent in real.parents:
    kind = owner_kind(parent) or ("zoo entry" if (parent / "zoo.json").is_file() else None)
    if kind is not None and kind not in CONTAINERS:
      raise RunDirError(f"{what}={path} lies inside the hdt {kind} directory {parent}, and writing there would "
                        f"change it; pass a directory outside it")
  for label, r in _inputs(reads):
    name = f"the {label} run {r}" if label else f"the run {r}"
    if r == real:
      where = f"is {name} this command reads"
    elif r in real.parents:
      where = f"lies inside {name} this command reads"
    elif real in r.parents:
      where = f"holds {name} this command reads"
    else:
      continue
    raise RunDirError(f"{what}={path} {where}; writing there would destroy that input: pass another {what}")


def check_claimable(out, kind: str = "run", resume: bool = False, overwrite: bool = False,
                    reuse: bool = False, what: str = "out", reads=(), zoo_ok: bool = False,
                    legacy=None) -> Path:
  """Read-only checks of :func:`claim`: ``out`` must be a place hdt may write (:func:`check_out`,
  :func:`check_place`), and new, empty, or an hdt directory of ``kind`` that ``resume`` /
  ``overwrite`` / ``reuse`` (add to it) allows writing. ``legacy(path)``: whether an unmarked
  directory is one hdt wrote as ``kind`` before the marker existed (runs are recognised here)."""
  path = check_out(out, what)
  check_place(path, what, reads, zoo_ok)
  if not path.exists() or is_empty(path):
    return path
  found = owner_kind(path) or (kind if legacy is not None and legacy(path) else None)
  if found is None:
    raise RunDirError(f"{what}={out} is not an hdt directory and not empty (it holds {_what_is_there(path)}); "
                      f"hdt writes only into new or empty directories or its own runs: pass another {what}")
  if found != kind:
    raise RunDirError(f"{what}={out} holds an hdt {found} directory where this command writes "
                      f"{'an' if kind[0] in 'aeiou' else 'a'} {kind} directory; pass another {what}")
  if not (resume or overwrite or reuse):
    raise RunDirError(f"{out} already holds a {kind}: pass --resume (resume=True) to continue it, --overwrite "
                      f"(overwrite=True) to replace it, or another {what}")
  return path


def _holder(lock_path: Path) -> str:
  try:
    return f"PID {int(lock_path.read_text().split()[0])}"
  except (OSError, ValueError, IndexError):
    return "another process"


def _flock(fd: int, path: Path) -> bool:
  """Locks ``fd`` (False where the file system cannot lock it); RunDirError if another process has."""
  try:
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    return True
  except OSError as e:
    if e.errno in (errno.EAGAIN, errno.EACCES):
      raise RunDirError(f"{path} is in use by {_holder(path / LOCK)}, which is writing to it; wait for it to "
                        f"finish (or stop it), or pass another --out") from None
    if e.errno in (errno.EINVAL, errno.ENOLCK, errno.EOPNOTSUPP, errno.EBADF):
      return False
    raise


@contextlib.contextmanager
def _locked(path: Path, kind: str, mark: bool = True) -> Iterator[None]:
  """Holds the locks of ``path`` (creating it, and with ``mark`` its marker) until the block ends."""
  atomic.make_dirs(path)
  fds, dir_locked, key = [], False, Path(path).resolve()
  try:
    fds.append(os.open(path, os.O_RDONLY | os.O_DIRECTORY))
    dir_locked = _flock(fds[0], path)
    fds.append(os.open(path / LOCK, os.O_RDWR | os.O_CREAT, atomic.file_mode()))
    if not (_flock(fds[1], path) or dir_locked):
      raise RunDirError(f"cannot lock {path} (its file system does not support locks); pass an --out on a "
                        f"local disk")
    if not _is_at(fds[0], path):  # replaced while we waited: start over
      raise RunDirError(f"{path} was replaced by another process while this one claimed it; run the command again")
    os.ftruncate(fds[1], 0)
    os.write(fds[1], f"{os.getpid()}\n".encode())
    if mark and not (path / MARKER).exists():
      atomic.write_json(path / MARKER, _marker(kind))
    _HELD[key] = fds[0]
    yield
  finally:
    _HELD.pop(key, None)
    if dir_locked:  # the directory's own lock guards the PID file: no other process holds it now
      with contextlib.suppress(OSError):
        os.unlink(LOCK, dir_fd=fds[0])  # in the locked directory, wherever it was moved
    for fd in fds:
      os.close(fd)  # releases the locks


def _is_at(fd: int, path: Path) -> bool:
  """Whether the open directory ``fd`` is the one at ``path`` now (FileNotFoundError if none is)."""
  now, ours = os.stat(path), os.fstat(fd)
  return (now.st_ino, now.st_dev) == (ours.st_ino, ours.st_dev)


def check_held(path) -> None:
  """Refuses (RunDirError) to write at ``path`` if the directory this process locked around it was
  deleted or replaced meanwhile (a lock guards a directory, not its name): whatever holds that name
  now, e.g. a new run started in its place, is not this process's to write."""
  path = Path(path).resolve()
  for held, fd in list(_HELD.items()):
    if path == held or held in path.parents:
      try:
        same = _is_at(fd, held)
      except FileNotFoundError:
        same = False
      if not same:
        raise RunDirError(f"{held} was deleted or replaced while this process wrote it, so nothing more is saved "
                          f"there (what holds that name now is left as it is); run the command again")


def _aside_pattern(path: Path) -> str:
  return f".{path.name}.hdt-replaced-*"


def _clear_asides(path: Path) -> None:
  """Deletes what a killed overwrite of ``path`` left: hidden siblings of hdt's own naming that carry
  its tag for ``path`` (and empty ones it had just created); nothing else."""
  for d in path.parent.glob(_aside_pattern(path)):
    if (_json_object(d / REPLACED) or {}).get("from") == path.name:
      atomic.remove(d)
    else:
      with contextlib.suppress(OSError):
        d.rmdir()  # only if empty


def _move_aside(path: Path, kind: str, legacy=None) -> Path:
  """Moves the hdt directory ``path`` (locked, checked again to be hdt's ``kind``) to a unique
  hidden sibling of hdt's naming, tagged as such; returns it."""
  if owner_kind(path) != kind and not (legacy is not None and legacy(path)):
    raise RunDirError(f"{path} changed while this command started (it is no longer an hdt {kind}); "
                      f"it was left as it is: pass another --out")
  atomic.write_json(path / REPLACED, {"from": path.name, "pid": os.getpid()})
  aside = Path(tempfile.mkdtemp(dir=path.parent, prefix=_aside_pattern(path)[:-1]))
  os.replace(path, aside)  # onto the empty directory just made: one rename
  return aside


@contextlib.contextmanager
def claim(out, kind: str = "run", resume: bool = False, overwrite: bool = False,
          reuse: bool = False, reads=(), zoo_ok: bool = False, legacy=None) -> Iterator[Path]:
  """Checks ``out`` (:func:`check_claimable`), locks it, and yields it as a Path. With ``overwrite``
  an existing directory is first locked (so nobody is writing it), moved aside in one rename and
  deleted; the block then writes a fresh directory. If the block fails while the directory holds
  nothing but hdt's bookkeeping, what this claim created is removed again.

  One of several processes (``jax.distributed``): every process calls it at the same point, process 0
  alone claims (and writes), the others yield the path without touching it; all fail together if
  process 0's claim fails."""
  from hdt.agents import sharding  # here: rundir itself stays free of JAX
  kw = dict(kind=kind, resume=resume, overwrite=overwrite, reuse=reuse, reads=reads, zoo_ok=zoo_ok, legacy=legacy)
  if not sharding.several_processes():
    with _claim(out, **kw) as path:
      yield path
    return
  # Every process has checked ``out`` (read only) before it comes here; process 0 claims only once all
  # have, so that none finds process 0's fresh claim in its way and refuses.
  sharding.stop_together(None, f"checking {out}")
  with contextlib.ExitStack() as held:
    path = sharding.on_writer(lambda: held.enter_context(_claim(out, **kw)), f"claiming {out}")
    yield Path(out).expanduser() if path is None else path


@contextlib.contextmanager
def _claim(out, kind: str = "run", resume: bool = False, overwrite: bool = False,
           reuse: bool = False, reads=(), zoo_ok: bool = False, legacy=None) -> Iterator[Path]:
  path = check_claimable(out, kind, resume, overwrite, reuse, reads=reads, zoo_ok=zoo_ok, legacy=legacy)
  _clear_asides(path)
  before = {p.name for p in path.iterdir()} if path.is_dir() else None
  if overwrite and not resume and path.exists() and not is_empty(path):
    with _locked(path, kind, mark=False):
      aside = _move_aside(path, kind, legacy)
    atomic.remove(aside)
    before = None
  with _locked(path, kind):
    LAST_CLAIMED.append(path)
    try:
      yield path
    except BaseException:
      if path.is_dir() and is_empty(path):  # nothing was saved: leave no trace of this claim
        if before is None:
          atomic.remove(path)
        else:
          for p in path.iterdir():
            if p.name not in before:
              atomic.remove(p)
      raise


def install(tmp, out, kind: str = "run", overwrite: bool = False, reads=(), zoo_ok: bool = False,
            what: str = "out") -> Path:
  """Moves the complete directory ``tmp`` (written elsewhere, e.g. a hidden sibling) to ``out`` in one
  rename, marked as hdt's ``kind``; an hdt directory already at ``out`` is replaced only with
  ``overwrite`` (moved aside under its lock first). Refused as :func:`claim` refuses."""
  tmp = Path(tmp)
  path = check_claimable(out, kind, overwrite=overwrite, reads=reads, zoo_ok=zoo_ok, what=what)
  _clear_asides(path)
  if not (tmp / MARKER).exists():
    atomic.write_json(tmp / MARKER, _marker(kind))
  atomic.make_dirs(path.parent)
  if not path.exists():
    os.replace(tmp, path)
    return path
  with _locked(path, kind, mark=False):
    aside = _move_aside(path, kind) if not is_empty(path) else None
    if aside is None:
      atomic.remove(path)  # nothing of anyone's in it
    os.replace(tmp, path)
  if aside is not None:
    atomic.remove(aside)
  return path


def holds_only_runs(path: Path, own_files=lambda name: False) -> bool:
  """Whether ``path`` holds hdt runs and otherwise only files ``own_files(name)`` says a container of
  them writes (how sweeps and experiments written before the marker are recognised)."""
  entries = [p for p in path.iterdir() if not atomic.is_temp(p.name) and p.name not in (MARKER, LOCK)]
  runs = [p for p in entries if owner_kind(p) is not None]
  return bool(runs) and all(p in runs or own_files(p.name) for p in entries)


def discard(out, kind: str = "run") -> None:
  """Deletes the hdt directory ``out`` of ``kind`` (refused as :func:`claim` refuses), e.g. a run to
  be retrained; a directory of anything else is never deleted."""
  with claim(out, kind, overwrite=True):
    pass

