"""Checkpoints: orbax for the parameter pytree, JSON for the metadata that makes a hand-off safe.

A run directory holds ``config.json``, ``meta.json``, ``metrics.csv`` and one sub-directory per seed
(``seed_0``, ``seed_1``, ...), each with ``params/`` (orbax) and its own ``meta.json``. A seed
directory is written under a temporary name and renamed into place, so a killed save leaves the
previous checkpoint loadable.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp

import hdt

FORMAT_VERSION = 1


class CheckpointError(ValueError):
  """A checkpoint is missing, corrupt, or does not fit where it is used."""


def write_json_atomic(path: Path, obj: Any) -> None:
  path = Path(path)
  fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
  with os.fdopen(fd, "w") as f:
    json.dump(obj, f, indent=1, sort_keys=True, default=_jsonable)
  os.replace(tmp, path)


def _jsonable(x):
  if isinstance(x, (np.generic, np.ndarray)):
    return x.tolist()
  if isinstance(x, tuple):
    return list(x)
  raise TypeError(f"not JSON serialisable: {type(x)}")


def seed_dir(run_dir: Path, seed_index: int) -> Path:
  return Path(run_dir) / f"seed_{seed_index}"


def save(run_dir: str | Path, seed_index: int, params: Any, meta: dict) -> Path:
  """Atomically write one seed's parameters and metadata into ``run_dir/seed_<i>``."""
  run_dir = Path(run_dir).resolve()  # orbax wants absolute paths
  run_dir.mkdir(parents=True, exist_ok=True)
  final = seed_dir(run_dir, seed_index)
  tmp = Path(tempfile.mkdtemp(dir=run_dir, prefix=f".{final.name}.", suffix=".tmp"))
  try:
    params = jax.tree.map(np.asarray, jax.device_get(params))
    ocp.PyTreeCheckpointer().save(tmp / "params", params)
    meta = dict(meta, format_version=FORMAT_VERSION, hdt_version=hdt.__version__, seed_index=seed_index)
    write_json_atomic(tmp / "meta.json", meta)
    old = final.with_name(final.name + ".old")
    if final.exists():
      if old.exists():
        shutil.rmtree(old)
      os.replace(final, old)
    os.replace(tmp, final)
    if old.exists():
      shutil.rmtree(old)
  except BaseException:
    shutil.rmtree(tmp, ignore_errors=True)
    raise
  return final


def _resolve_seed_dir(run_dir: Path, seed_index: int) -> Path:
  d = seed_dir(run_dir, seed_index)
  if d.exists():
    return d
  old = d.with_name(d.name + ".old")  # a save was killed between its two renames
  if old.exists():
    return old
  raise CheckpointError(f"no checkpoint for seed {seed_index} in {run_dir} (expected {d}); "
                        f"seeds present: {list_seeds(run_dir) or 'none'}")


def list_seeds(run_dir: str | Path) -> list[int]:
  run_dir = Path(run_dir)
  if not run_dir.is_dir():
    return []
  out = set()
  for p in run_dir.iterdir():
    name = p.name.removesuffix(".old")
    if name.startswith("seed_") and name[5:].isdigit() and (p / "meta.json").exists():
      out.add(int(name[5:]))
  return sorted(out)


def load_meta(run_dir: str | Path, seed_index: int = 0) -> dict:
  run_dir = Path(run_dir)
  if not run_dir.exists():
    raise CheckpointError(f"checkpoint directory {run_dir} does not exist; pass the RUN directory a "
                          f"training command printed (it holds seed_0/, seed_1/, ...)")
  d = _resolve_seed_dir(run_dir, seed_index)
  try:
    meta = json.loads((d / "meta.json").read_text())
  except (OSError, json.JSONDecodeError) as e:
    raise CheckpointError(f"corrupt checkpoint metadata {d / 'meta.json'}: {e}; re-run training or "
                          f"restore the file") from e
  fv = meta.get("format_version")
  if fv != FORMAT_VERSION:
    raise CheckpointError(f"checkpoint {d} has format version {fv}, this hdt ({hdt.__version__}) reads "
                          f"version {FORMAT_VERSION}: re-train it or load it with hdt "
                          f"{meta.get('hdt_version', '?')}")
  return meta


def load(run_dir: str | Path, seed_index: int = 0) -> tuple[Any, dict]:
  """Returns (params, meta) of one seed."""
  meta = load_meta(run_dir, seed_index)
  d = _resolve_seed_dir(Path(run_dir).resolve(), seed_index)
  try:
    params = ocp.PyTreeCheckpointer().restore(d / "params")
  except Exception as e:  # orbax raises several types for damaged files
    raise CheckpointError(f"corrupt checkpoint parameters in {d / 'params'}: {e}") from e
  return params, meta


def load_all(run_dir: str | Path) -> tuple[Any, list[dict]]:
  """All seeds of a run, parameters stacked on a leading seed axis."""
  seeds = list_seeds(run_dir)
  if not seeds:
    raise CheckpointError(f"no seed checkpoints (seed_0/, ...) in {run_dir}")
  loaded = [load(run_dir, s) for s in seeds]
  params = jax.tree.map(lambda *x: np.stack(x), *[p for p, _ in loaded])
  return params, [m for _, m in loaded]
