"""Checkpoints: orbax for the parameter pytree, JSON for the metadata that makes a hand-off safe.

A run directory holds ``config.json``, ``meta.json``, ``metrics.csv`` and one sub-directory per seed
(``seed_0``, ``seed_1``, ...), each with ``params/`` (orbax, the final parameters), ``best/params/``
(those of the best periodic evaluation; ``meta["best"]`` says which env step and return; a zoo LL
keeps only these) and its own ``meta.json``, and
``state/``: the resumable training state (``arrays/`` orbax, ``state.json``). A normalised run's
observation statistics are saved beside the parameters (``params["obs_norm"]`` next to "policy" and
"q"); checkpoints written when they lived inside the policy and critics are split on load. Each of these
directories is written under a temporary name and renamed into place, so a save killed at any point
(tested with SIGKILL) leaves the previous version loadable. A zoo entry keeps each parameter set
packed into one file (``params.msgpack``: :func:`pack`) instead of orbax's directory of a dozen small
files, which is what a git checkout holds. Metadata carries ``format_version``;
another version, damaged files, or a checkpoint of the wrong kind raise :class:`CheckpointError`
saying what to do.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import re
import threading
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np
import orbax.checkpoint as ocp
from flax import serialization

from hdt import atomic
from hdt.agents import normalizer, sharding
from hdt.transfer import names, rundir
from hdt.transfer.names import (SEED_HASHES, CheckpointError, content_hash, current, existing_seed_dir, list_seeds,
                               seed_dir)
from hdt.transfer.names import resolve as zoo_path  # zoo:NAME wherever a run is read
from hdt.version import __version__

FORMAT_VERSION = 1
CURVES_CSV = "curves.csv"  # a zoo entry's learning curves: the evaluation rows of its run's metrics.csv


def write_json_atomic(path: Path, obj: Any) -> None:
  atomic.write_json(path, obj, default=jsonable)


def jsonable(x):
  """json.dumps(default=jsonable): numpy values as numbers and lists, tuples as lists."""
  if isinstance(x, (np.generic, np.ndarray)):
    return x.tolist()
  if isinstance(x, tuple):
    return list(x)
  raise TypeError(f"not JSON serialisable: {type(x)}")


def _replace_in_run(run_dir: Path, final: Path, write) -> Path:
  """:func:`atomic.replace_dir` of ``final`` in ``run_dir``, refused if the run directory this process
  locked is no longer at that name (:func:`rundir.check_held`): before anything is made, and again
  just before the swap, since the write takes seconds."""
  rundir.check_held(run_dir)

  def checked(tmp: Path):
    write(tmp)
    rundir.check_held(run_dir)

  return atomic.replace_dir(final, checked)


@contextlib.contextmanager
def _quiet_orbax():
  """Orbax logs each failure of its writer threads with a traceback (absl, ERROR) before raising
  it in the caller: the caller's one-line error says it."""
  logger = logging.getLogger("absl")
  level = logger.level
  logger.setLevel(logging.CRITICAL)
  try:
    yield
  finally:
    logger.setLevel(level)


_OS_ERROR = re.compile(r"os_error_code='?(\d+)")


def _checkpointer():
  """orbax's pytree checkpointer. With several processes (``jax.distributed``) orbax would wait for
  every process to save together; hdt's checkpoints are host arrays that process 0 writes alone and
  any process reads, so each process's checkpointer runs on that process only."""
  if not sharding.several_processes():
    return ocp.PyTreeCheckpointer()
  alone = ocp.options.MultiprocessingOptions(primary_host=jax.process_index(),
                                             active_processes={jax.process_index()})
  return ocp.Checkpointer(ocp.PyTreeCheckpointHandler(multiprocessing_options=alone), multiprocessing_options=alone)


def orbax_save(path: Path, tree) -> None:
  """``tree`` saved by orbax at ``path``, its commit marker path-free (:func:`names.scrub_marker`); a
  file-system failure (a full disk, a read-only mount) is raised as the OSError it is, naming ``path``."""
  before = set(threading.enumerate())
  try:
    with _quiet_orbax():
      _checkpointer().save(path, tree)
    names.scrub_marker(path)
  except Exception as e:  # orbax wraps OS errors in ValueError and others
    for t in set(threading.enumerate()) - before:  # its other writers: done before the caller cleans up
      t.join(timeout=30)
    code = _OS_ERROR.search(str(e))
    if code is None:
      raise
    n = int(code.group(1))
    raise OSError(n, os.strerror(n), str(path)) from None


def _orbax_restore(path: Path):
  with _quiet_orbax():
    return _checkpointer().restore(path)


PACKED = ".msgpack"


def packed(path: Path) -> Path:
  """The one-file form of the orbax parameter directory ``path`` (``params`` -> ``params.msgpack``)."""
  return Path(path).with_name(Path(path).name + PACKED)


def has_params(path: Path) -> bool:
  """Whether the parameter set ``path`` (``seed_i/params`` or ``seed_i/best/params``) exists, in either form."""
  return Path(path).is_dir() or packed(path).is_file()


def pack(path: Path, tree=None) -> Path:
  """Writes the parameter set ``path`` as one flax-msgpack file (``tree``; default, what ``path`` holds
  now), checked to restore to the same arrays (names, dtypes, values), then removes its orbax
  directory if it had one; returns the file."""
  tree = restore_params(path) if tree is None else tree
  data = serialization.msgpack_serialize(tree)
  back = serialization.msgpack_restore(data)
  same = jax.tree.structure(tree) == jax.tree.structure(back) and all(
      np.asarray(a).dtype == np.asarray(b).dtype and np.array_equal(a, b, equal_nan=True)
      for a, b in zip(jax.tree.leaves(tree), jax.tree.leaves(back)))
  if not same:
    raise CheckpointError(f"{path} does not survive packing into one file unchanged; keep it as it is")
  out = atomic.write_bytes(packed(path), data)
  atomic.remove(Path(path))
  return out


def restore_params(path: Path):
  """The parameter set ``path``: its packed file if there is one, else its orbax directory."""
  f = packed(path)
  if f.is_file():
    return jax.tree.map(np.array, serialization.msgpack_restore(f.read_bytes()))
  return _orbax_restore(Path(path).resolve())


WHICH = ("final", "best")


def save(run_dir: str | Path, seed_index: int, params: Any, meta: dict,
         best: tuple[Any, dict] | None = None) -> Path:
  """Atomically write one seed's parameters and metadata into ``run_dir/seed_<i>``; ``best`` =
  (params, info) of the best periodic evaluation goes to ``best/params`` and ``meta["best"]``."""
  run_dir = Path(run_dir).resolve()  # orbax wants absolute paths
  params = jax.tree.map(np.asarray, jax.device_get(params))
  meta = dict(meta, format_version=FORMAT_VERSION, hdt_version=__version__, seed_index=seed_index)
  if best is not None:
    meta["best"] = best[1]

  def write(tmp: Path):
    orbax_save(tmp / "params", params)
    if best is not None:
      orbax_save(tmp / "best" / "params", jax.tree.map(np.asarray, best[0]))
    write_json_atomic(tmp / "meta.json", meta)

  return _replace_in_run(run_dir, seed_dir(run_dir, seed_index), write)


def check_unchanged(run_dir: str | Path, seed_index: int) -> None:
  """Refuses (CheckpointError) seed ``seed_index`` of ``run_dir`` if its files are not those its zoo
  entry's zoo.json or its run's meta.json recorded (replaced by another run's, edited or damaged);
  runs and entries that record no hash are not checked."""
  run_dir = Path(zoo_path(run_dir))
  info = names.info_of(run_dir)
  if info is not None:
    want, where = names.recorded_hash(info, seed_index), run_dir / "zoo.json"
    try:
      rel = f"zoo/{run_dir.resolve().relative_to(names.ZOO_DIR.resolve())}"
    except ValueError:
      rel = str(run_dir)
    fix = f"restore the entry (e.g. git checkout -- {rel})"
  else:
    try:
      hashes = json.loads((run_dir / "meta.json").read_text()).get(SEED_HASHES)
    except (OSError, ValueError, AttributeError):
      hashes = None
    ok = isinstance(hashes, list) and 0 <= seed_index < len(hashes) and isinstance(hashes[seed_index], str)
    want, where, fix = (hashes[seed_index] if ok else None), run_dir / "meta.json", "restore it from a backup, or re-train the run"
  if want is not None and content_hash(run_dir, seed_index) != want:
    raise CheckpointError(f"the checkpoint {existing_seed_dir(run_dir, seed_index)} is not the one {where} records "
                          f"(its content hash differs: its files were replaced, edited or damaged); {fix}")


def record_seed_hashes(run_dir: str | Path) -> dict:
  """Rewrites the run's meta.json with the content hashes of its seeds as they are now (after a
  deliberate change of a checkpoint, e.g. slimming a zoo copy); returns it."""
  path = Path(run_dir) / "meta.json"
  meta = json.loads(path.read_text())
  meta[SEED_HASHES] = [content_hash(run_dir, s) for s in list_seeds(run_dir)]
  write_json_atomic(path, meta)
  return meta


def require(meta: dict, fields: dict[str, type | tuple], where: str | Path) -> dict:
  """``meta`` if each of ``fields`` is present with the given type(s), else a one-line CheckpointError."""
  for key, types in fields.items():
    if key not in meta:
      problem = f"has no {key!r}"
    elif not isinstance(meta[key], types) or (isinstance(meta[key], bool) and
                                              bool not in (types if isinstance(types, tuple) else (types,))):
      problem = f"has {key}={meta[key]!r} ({type(meta[key]).__name__})"
    else:
      continue
    raise CheckpointError(f"checkpoint metadata in {where} {problem}: the file was edited or damaged; "
                          f"re-run training, or restore it from a backup")
  return meta


def has_state(run_dir: str | Path) -> bool:
  """Whether ``run_dir`` holds a complete resumable state (``state/``, or ``state.old`` after a kill
  between the two renames of a save)."""
  return current(state_dir(run_dir)) is not None


def settle_state(run_dir: str | Path) -> None:
  """Completes a save killed between its two renames (``state.old`` but no ``state/``); call it
  only while holding the run directory's lock."""
  d = state_dir(run_dir)
  if not d.exists() and current(d) is not None:
    os.replace(current(d), d)


def load_meta(run_dir: str | Path, seed_index: int = 0) -> dict:
  run_dir = zoo_path(run_dir)
  run_dir = Path(run_dir)
  if not run_dir.exists():
    raise CheckpointError(f"checkpoint directory {run_dir} does not exist; pass the RUN directory a "
                          f"training command printed (it holds seed_0/, seed_1/, ...)")
  d = existing_seed_dir(run_dir, seed_index)
  return _read_meta(d / "meta.json")


def _read_meta(path: Path) -> dict:
  """A checkpoint's JSON metadata, checked to be readable and of this hdt's format version."""
  try:
    meta = json.loads(path.read_text())
    if not isinstance(meta, dict):
      raise ValueError(f"expected a JSON object, found {type(meta).__name__}")
  except (OSError, ValueError) as e:  # JSONDecodeError is a ValueError
    raise CheckpointError(f"corrupt checkpoint metadata {path}: {e}; the file is truncated or damaged: "
                          f"re-run training, or restore the file from a backup") from e
  fv = meta.get("format_version")
  if fv != FORMAT_VERSION:
    d = path.parent
    if isinstance(fv, int) and fv > FORMAT_VERSION:
      fix = f"upgrade hdt (this is {__version__}) to read it"
    else:
      fix = (f"re-train it, or load it with the hdt that wrote it "
             f"({meta.get('hdt_version', 'unknown version')})")
    raise CheckpointError(f"checkpoint {d} has format version {fv!r} but this hdt ({__version__}) "
                          f"reads version {FORMAT_VERSION}: {fix}")
  return meta


def check_which(which: str, what: str = "which") -> str:
  if which not in WHICH:
    raise ValueError(f"{what}={which!r}: load the 'final' parameters or the 'best' (those of the best "
                     f"periodic evaluation)")
  return which


def load(run_dir: str | Path, seed_index: int = 0, which: str = "final") -> tuple[Any, dict]:
  """Returns (params, meta) of one seed: its final parameters, or with ``which="best"`` those of
  its best periodic evaluation. As the authors' loader, "best" falls back to the final parameters
  of a checkpoint that has none; a zoo entry keeps one of the two (zoo.py), which either name then
  loads; an HL entry exported policy-only keeps its final ones. ``meta["params"]`` says which were
  loaded and ``meta["params_env_steps"]`` after how many env steps."""
  run_dir = zoo_path(run_dir)
  check_which(which)
  meta = load_meta(run_dir, seed_index)
  check_unchanged(run_dir, seed_index)
  d = existing_seed_dir(Path(run_dir).resolve(), seed_index)
  has_best = isinstance(meta.get("best"), dict)
  use = "best" if which == "best" and has_best else "final"
  where = {"final": d / "params", "best": d / "best" / "params"}
  if not has_params(where[use]) and (Path(run_dir) / "zoo.json").is_file():
    use = {"final": "best", "best": "final"}[use]  # a zoo entry keeps the set its numbers are of
  path = where[use]
  try:
    params = restore_params(path)
  except Exception as e:  # orbax raises several types for damaged files
    raise CheckpointError(f"corrupt checkpoint parameters in {path} ({type(e).__name__}: "
                          f"{e}); re-run training, or restore the directory from a backup") from e
  steps = meta["best"].get("env_steps") if use == "best" else (meta.get("sac") or {}).get("total_env_steps")
  return split_obs_norm(params), dict(meta, params=use, params_env_steps=steps)


NORM = normalizer.KEY  # the observation statistics, beside "policy" and "q"


def split_obs_norm(params: dict) -> dict:
  """``params`` with the observation statistics beside the networks: checkpoints written before they
  were (``params["policy"]["obs_norm"]``, copies in the critics) are converted; others are unchanged."""
  if not (isinstance(params, dict) and isinstance(params.get("policy"), dict) and NORM in params["policy"]):
    return params
  strip = lambda v: {k: x for k, x in v.items() if k != NORM} if isinstance(v, dict) else v
  return dict({k: strip(v) for k, v in params.items()}, **{NORM: params["policy"][NORM]})


def params_label(metas: list[dict]) -> str:
  """Which parameters a list of per-seed metas (from :func:`load`) holds: "final", "best", or
  "mixed: ..." per seed when some seeds had no best."""
  used = [m.get("params", "final") for m in metas]
  return used[0] if len(set(used)) == 1 else "mixed: " + ", ".join(used)


def load_all(run_dir: str | Path, which: str = "final") -> tuple[Any, list[dict]]:
  """All seeds of a run, parameters stacked on a leading seed axis (``which``: as in :func:`load`)."""
  run_dir = zoo_path(run_dir)
  seeds = list_seeds(run_dir)
  if not seeds:
    raise CheckpointError(f"no seed checkpoints (seed_0/, ...) in {run_dir}")
  try:  # a run's meta.json lists its seeds: a checkpoint beyond them is left over from another run
    declared = json.loads((Path(run_dir) / "meta.json").read_text()).get("seeds")
  except (OSError, ValueError, AttributeError):
    declared = None
  if isinstance(declared, list) and seeds != list(range(len(declared))):
    raise CheckpointError(f"{run_dir} holds checkpoints seed_{', seed_'.join(map(str, seeds))} but its meta.json "
                          f"lists {len(declared)} seed(s): it mixes two runs; re-train it with --overwrite")
  loaded = [load(run_dir, s, which) for s in seeds]
  params = jax.tree.map(lambda *x: np.stack(x), *[p for p, _ in loaded])
  return params, [m for _, m in loaded]


# ------------------------------------------------------------------------------------------------
# Resumable training state: ``run_dir/state/`` holds the whole vmapped TrainState (parameters,
# targets, optimiser states, temperature, plug-in state, replay buffer, env states, RNG keys,
# counters) and the history so far, so that a resumed run continues bit for bit.

STATE = "state"


def state_dir(run_dir: str | Path) -> Path:
  return Path(run_dir) / STATE


def _leaf_specs(named) -> list[list]:
  """[name, shape, dtype] of (name, array or ShapeDtypeStruct) pairs, as stored in state.json."""
  return [[name, list(x.shape), str(np.dtype(x.dtype))] for name, x in named]


def _named_leaves(tree) -> list[tuple[str, np.ndarray]]:
  flat, _ = jax.tree_util.tree_flatten_with_path(jax.device_get(tree))
  return [(jax.tree_util.keystr(path), np.asarray(x)) for path, x in flat]


def save_state(run_dir: str | Path, tree: Any, history: dict[str, np.ndarray], info: dict,
               best: Any = None) -> Path:
  """Atomically write ``tree`` (any pytree of arrays, e.g. a TrainState), ``history`` (name ->
  array), the best-evaluation record ``best`` (a pytree, or None) and the JSON ``info`` (config,
  run metadata, ...) into ``run_dir/state``. The previous state stays loadable until the new one
  is complete."""
  run_dir = Path(run_dir).resolve()
  leaves = _named_leaves(tree)
  hist = [(k, np.asarray(v)) for k, v in history.items()]
  best_leaves = [] if best is None else _named_leaves(best)
  # orbax keys must be plain names: index them, and keep the real names in state.json
  index = lambda named: {f"{i:05d}": x for i, (_, x) in enumerate(named)}
  arrays = {"state": index(leaves), "history": index(hist), "best": index(best_leaves)}
  info = dict(info, format_version=FORMAT_VERSION, hdt_version=__version__, kind="train_state",
              leaves=_leaf_specs(leaves), history=_leaf_specs(hist))
  if best is not None:
    info["best_leaves"] = _leaf_specs(best_leaves)

  def write(tmp: Path):
    orbax_save(tmp / "arrays", {k: v for k, v in arrays.items() if v})
    write_json_atomic(tmp / "state.json", info)

  return _replace_in_run(run_dir, state_dir(run_dir), write)


def load_state_info(run_dir: str | Path) -> dict:
  """``state.json`` of the resumable state in ``run_dir`` (checked readable and of this format)."""
  d = current(state_dir(run_dir))
  if d is None:
    what = "does not exist" if not Path(run_dir).exists() else f"has no saved training state ({STATE}/)"
    raise CheckpointError(f"cannot resume: {run_dir} {what}; start the run without resume (or pass the "
                          f"out= directory of the interrupted run)")
  info = _read_meta(d / "state.json")
  if info.get("kind") != "train_state":
    raise CheckpointError(f"{d} is not a training state (kind={info.get('kind')!r}); re-run training")
  return require(info, {"leaves": list, "history": list}, d / "state.json")


class SavedState(NamedTuple):
  tree: Any  # structured as the template
  history: dict[str, np.ndarray]
  info: dict  # state.json
  best: Any  # structured as best_template; None when not asked for or not saved


def _check_fits(d: Path, got: list, want: list, written_by: str | None) -> None:
  """Refuses a saved state whose leaf specs ``got`` are not the specs ``want`` this run needs."""
  if got != want:
    fmt = lambda spec: f"{spec[0]} {spec[2]}{spec[1]}" if spec else "nothing"
    saved, needed = next(((g, w) for g, w in zip(got, want) if g != w),
                         (got[len(want)] if len(got) > len(want) else None,
                          want[len(got)] if len(want) > len(got) else None))
    by = (f"{f'hdt {written_by}' if written_by else 'an older hdt'} wrote it, and this is hdt {__version__}"
          if written_by != __version__ else "it was written by another configuration")
    raise CheckpointError(f"the training state in {d} does not fit this run (saved {fmt(saved)} where "
                          f"this run needs {fmt(needed)}): {by}; start a new run in another out= directory")


# Where a state saved when the statistics lived inside the networks kept them (keystr prefixes, old ->
# new); their other copies (critics, target critics, Adam moments) are dropped on load.
_LEGACY_NORM = ((".agent.policy_params['obs_norm']", ".agent.obs_norm"),
                ("['policy']['obs_norm']", "['obs_norm']"))
# TrainState leaves added since states were saved (keystr -> the value an older state means):
# hdt.agents.train.TrainState.diverged_at, -1 for a seed that never diverged.
_ADDED_LEAVES = {".diverged_at": -1}
# Leaves renamed since (new keystr -> old): the best record's score was saved as its "return", also
# when SACConfig.best_by picked another metric (hdt.agents.train.empty_best).
_RENAMED_LEAVES = {"['score']": "['return']"}


def _legacy_sources(got: list, want: list) -> list[list[int]] | None:
  """For a state saved by an older hdt (leaf specs ``got``), the saved indices that make each leaf of
  ``want`` (one leaf, or several raveled and concatenated); None if ``got`` is not such a state or the
  conversions below do not make it fit. Four conversions: leaves added since (:data:`_ADDED_LEAVES`,
  no saved index), leaves renamed since (:data:`_RENAMED_LEAVES`), the observation statistics that lived inside
  the networks (:data:`_LEGACY_NORM`; their other copies are dropped), and the Adam moments kept per
  layer before the optimisers raveled each small network's parameters (``hdt.agents.sac.make_optimizers``):
  ``...mu['params']...`` leaves become one ``...mu`` vector, in pytree order (as ``optax.flatten``)."""
  legacy_norm = any(f"['{NORM}']" in g[0] for g in got)
  want_names = {w[0] for w in want}
  renamed = {old: new for new, old in _RENAMED_LEAVES.items() if new in want_names and old not in want_names}
  index = {}
  for i, (name, shape, dtype) in enumerate(got):
    name = renamed.get(name, name)
    new = next((n + name[len(o):] for o, n in _LEGACY_NORM if name.startswith(o)), None) if legacy_norm else None
    if new is not None or f"['{NORM}']" not in name:
      index[new or name] = (i, [new or name, shape, dtype])
  sources = []
  for name, shape, dtype in want:
    if index.get(name, (None, None))[1] == [name, shape, dtype]:
      sources.append([index[name][0]])
      continue
    if name in _ADDED_LEAVES and name not in index:
      sources.append([])  # filled with its value for an older state (pick)
      continue
    # leading axes (seeds, grid points) kept; the rest of every part raveled into the last axis
    lead = shape[:-1]
    parts = [(i, spec) for n, (i, spec) in index.items() if n == name or n.startswith(name + "[")]
    if not (shape and parts and all(spec[2] == dtype and spec[1][:len(lead)] == lead for _, spec in parts)
            and sum(math.prod(spec[1][len(lead):]) for _, spec in parts) == shape[-1]):
      return None
    sources.append(sorted(i for i, _ in parts))
  identity = (all(src == [i] for i, src in enumerate(sources)) and len(sources) == len(got)
              and not any(g[0] in renamed for g in got))
  return None if identity else sources


def load_state(run_dir: str | Path, template: Any, best_template: Any = None) -> SavedState:
  """(tree, history, info, best) saved by :func:`save_state`; ``tree`` has the structure of
  ``template`` (e.g. ``jax.eval_shape`` of the trainer's init), whose leaf names, shapes and dtypes
  must match; so must ``best_template``'s, if given and a best record was saved (else best=None)."""
  info = load_state_info(run_dir)
  d = current(state_dir(Path(run_dir).resolve()))

  def fits(got, tree):  # (treedef, saved indices per leaf of tree, (name, shape, dtype) per leaf of tree)
    flat, treedef = jax.tree_util.tree_flatten_with_path(tree)
    want = _leaf_specs([(jax.tree_util.keystr(p), x) for p, x in flat])
    sources = _legacy_sources(got, want)
    if sources is None:
      _check_fits(d, got, want, info.get("hdt_version"))
      sources = [[i] for i in range(len(want))]
    return treedef, sources, [(spec[0], tuple(spec[1]), spec[2]) for spec in want]

  saved = info.get("leaves", [])
  treedef, state_idx, specs = fits(saved, template)
  with_best = best_template is not None and "best_leaves" in info
  best_saved = info["best_leaves"] if with_best else []
  best_def, best_idx, best_specs = fits(best_saved, best_template) if with_best else (None, [], [])
  try:
    arrays = _orbax_restore(d / "arrays")
    group = lambda name, n: [np.asarray(arrays[name][f"{i:05d}"]) for i in range(n)]
    state, best = group("state", len(saved)), group("best", len(best_saved))
    hist = dict(zip([h[0] for h in info.get("history", [])], group("history", len(info.get("history", [])))))
  except Exception as e:  # orbax raises several types for damaged files
    raise CheckpointError(f"corrupt training state in {d / 'arrays'} ({type(e).__name__}: {e}); "
                          f"delete {d} to start over, or restore it from a backup") from e
  for (name, shape, dtype), x in zip(saved + info.get("history", []) + best_saved,
                                     state + list(hist.values()) + best):
    if list(x.shape) != shape or str(x.dtype) != dtype:
      raise CheckpointError(f"corrupt training state in {d}: {name} has shape {x.shape} {x.dtype}, "
                            f"state.json says {shape} {dtype}; delete {d} to start over")

  def pick(xs, idx, specs):  # one saved leaf per leaf, or (legacy states) several raveled into one, or none
    return [np.full(shape, _ADDED_LEAVES[name], dtype) if not i else
            xs[i[0]] if len(i) == 1 and xs[i[0]].shape == shape else
            np.concatenate([xs[j].reshape(shape[:-1] + (-1,)) for j in i], axis=-1)
            for i, (name, shape, dtype) in zip(idx, specs)]
  return SavedState(jax.tree_util.tree_unflatten(treedef, pick(state, state_idx, specs)), hist, info,
                    jax.tree_util.tree_unflatten(best_def, pick(best, best_idx, best_specs)) if with_best else None)


def differences(saved: Any, requested: Any, path: str = "") -> list[str]:
  """Human-readable differences ``path: saved X, requested Y`` between two JSON-like values
  (compared after a JSON round trip, so tuples equal lists)."""
  norm = lambda x: json.loads(json.dumps(x, sort_keys=True, default=jsonable))
  saved, requested = norm(saved), norm(requested)
  if isinstance(saved, dict) and isinstance(requested, dict):
    out = []
    for k in sorted(set(saved) | set(requested)):
      out += differences(saved.get(k, "<unset>"), requested.get(k, "<unset>"), f"{path}.{k}".lstrip("."))
    return out
  return [] if saved == requested else [f"{path or 'value'}: saved {saved!r}, requested {requested!r}"]
