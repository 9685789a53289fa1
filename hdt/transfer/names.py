"""What names a checkpoint: ``zoo:NAME`` resolved to an entry's directory, a run's seed directories,
and the content hashes that identify a seed's files.

Whoever depends on a checkpoint records its content hash (an HL its LL's, an aligned LL the imitated
one's, a run its own seeds', a zoo entry in ``zoo.json``), and every load checks it. A slim zoo copy
of a run keeps the hashes of what it was copied from (:func:`hash_aliases`): slimming an entry is not
retraining it. Standard library only (and :mod:`hdt.atomic`): the zoo, checkpoints, run directories,
the runner and evaluation all read names through here.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from pathlib import Path

from hdt import atomic

ZOO_DIR = Path(__file__).resolve().parents[2] / "zoo"
PREFIX = "zoo:"
NAME = re.compile(r"[a-z0-9_]+(/[a-z0-9_]+)?")


class CheckpointError(ValueError):
  """A checkpoint is missing, corrupt, or does not fit where it is used."""


class ZooError(ValueError):
  """A zoo name that is not a name, or names no entry."""


def check_name(name) -> str:
  """``name`` if it is an entry name (one or two parts of ``[a-z0-9_]``, e.g. ``point/low``), else a
  one-line ZooError: a name is never a path."""
  if not isinstance(name, str) or not NAME.fullmatch(name):
    raise ZooError(f"zoo name {name!r}: a name is one or two parts of lowercase letters, digits and '_' "
                   f"joined by '/', e.g. point/low (see `hdt zoo`)")
  return name


def entry_names() -> list[str]:
  """The names of the zoo's entries, sorted."""
  found = (str(p.parent.relative_to(ZOO_DIR)) for p in ZOO_DIR.glob("**/zoo.json"))
  return sorted(n for n in found if NAME.fullmatch(n))


def resolve(path):
  """``zoo:NAME`` -> the entry's directory (inside ``zoo/``, never through a link out of it); any
  other path is returned unchanged."""
  if isinstance(path, (str, Path)) and str(path).startswith(PREFIX):  # argparse may give a Path
    name = check_name(str(path)[len(PREFIX):])
    d = ZOO_DIR / name
    root = os.path.realpath(ZOO_DIR)
    if not os.path.realpath(d).startswith(root + os.sep):
      raise ZooError(f"zoo entry {name!r} points outside {ZOO_DIR}; restore it (git checkout -- zoo/{name})")
    if not (d / "zoo.json").is_file():
      raise ZooError(f"no zoo entry {name!r}; entries: {', '.join(entry_names()) or '(none)'} (see `hdt zoo`)")
    return d
  return path


def info_of(run) -> dict | None:
  """The zoo.json of the entry ``run`` (a zoo name or an entry's directory), None for other runs."""
  try:
    info = json.loads((Path(resolve(run)) / "zoo.json").read_text())
  except (OSError, ValueError):
    return None
  return info if isinstance(info, dict) else None


# --- a run's seed directories -------------------------------------------------------------------

def seed_dir(run_dir, seed_index: int) -> Path:
  return Path(run_dir) / f"seed_{seed_index}"


def current(d: Path) -> Path | None:
  """``d``, or its previous version when a write was killed between its two renames
  (:func:`hdt.atomic.replace_dir`), or None."""
  if d.exists():
    return d
  old = atomic.old(d)
  return old if old.exists() else None


def list_seeds(run_dir) -> list[int]:
  """The seed indices of ``run_dir`` (or ``zoo:NAME``) that hold a checkpoint."""
  run_dir = Path(resolve(run_dir))
  if not run_dir.is_dir():
    return []
  out = set()
  for p in run_dir.iterdir():
    name = p.name.removesuffix(".old")
    if name.startswith("seed_") and name[5:].isdigit() and (p / "meta.json").exists():
      out.add(int(name[5:]))
  return sorted(out)


def existing_seed_dir(run_dir, seed_index: int) -> Path:
  """The directory of seed ``seed_index``'s checkpoint (:func:`current`), or a one-line CheckpointError."""
  d = current(seed_dir(run_dir, seed_index))
  if d is None:
    raise CheckpointError(f"no checkpoint for seed {seed_index} in {run_dir} (expected "
                          f"{seed_dir(run_dir, seed_index)}); seeds present: "
                          f"{list_seeds(run_dir) or 'none'}")
  return d


# --- content hashes -----------------------------------------------------------------------------

SEED_HASHES = "seed_sha256"  # a run's meta.json: the content hash of each seed's checkpoint


def content_hash(run_dir, seed_index: int | None = None) -> str:
  """sha256 over the files (relative names and bytes) of one seed's checkpoint, or of every seed's:
  recorded by runs that depend on a checkpoint, so resuming or evaluating them after it changed
  (e.g. the LL was retrained) is refused."""
  run_dir = Path(resolve(run_dir))
  dirs = ([existing_seed_dir(run_dir, seed_index)] if seed_index is not None
          else [existing_seed_dir(run_dir, s) for s in list_seeds(run_dir)])
  h = hashlib.sha256()
  for d in dirs:
    for f in sorted(p for p in d.rglob("*") if p.is_file()):
      h.update(str(f.relative_to(d)).encode() + b"\0")
      h.update(f.read_bytes())
  return h.hexdigest()


def recorded_hash(info: dict, seed: int) -> str | None:
  """The content hash a zoo.json ``info`` records for seed ``seed`` of its entry (None if it records none)."""
  for s in info.get("slim") or []:
    if isinstance(s, dict) and s.get("seed") == seed and isinstance(s.get("sha256"), str):
      return s["sha256"]
  hashes = info.get("seed_sha256")
  return hashes[seed] if isinstance(hashes, list) and 0 <= seed < len(hashes) and isinstance(hashes[seed], str) else None


def recorded_low_hash(high) -> str | None:
  """The content hash of the LL seed that the HL entry ``high`` composes with, as its zoo.json records."""
  h = (info_of(high) or {}).get("low_sha256")
  return h if isinstance(h, str) else None


def hash_aliases(low, seed: int | None) -> set[str]:
  """Content hashes that name seed ``seed`` of ``low`` (every seed: None) as it is now: its own, plus,
  for a zoo entry whose files are unchanged since it was last slimmed and packed, that
  of the full run it was exported from and of its earlier zoo copies (``hdt.transfer.zoo.reslim``)."""
  now = content_hash(low, seed)
  info = (info_of(low) or {}) if str(low).startswith(PREFIX) else {}
  if seed is None:
    return {now} | (set(info.get("earlier_entry_sha256") or []) if info.get("entry_sha256") == now else set())
  return {now} | {h for s in info.get("slim") or [] if s["seed"] == seed and s["sha256"] == now
                  for h in [s["source_sha256"], *s.get("earlier_sha256", [])]}


ORBAX_MARKER = "commit_success.txt"
MARKER_TEXT = "Checkpoint commit was successful\n"  # orbax's own text ends with the absolute save path


def scrub_marker(path) -> bool:
  """Rewrites the commit marker orbax leaves in the checkpoint ``path`` without the path it was saved
  to, so that a checkpoint's bytes (and content hash) do not depend on the machine or directory that
  wrote it; True if it changed."""
  f = Path(path) / ORBAX_MARKER
  if not f.is_file() or f.read_text() == MARKER_TEXT:
    return False
  atomic.write_text(f, MARKER_TEXT)
  return True
