"""Where hdt keeps files between runs: the compiled physics custom call, JAX's compile cache and
ahead-of-time compiled training programs."""

from __future__ import annotations

import concurrent.futures
import contextlib
import functools
import hashlib
import os
import pickle
from pathlib import Path
from typing import Callable, Sequence

import jax
import jaxlib
import mujoco
from jax.experimental import serialize_executable
from jax.experimental.compilation_cache import compilation_cache as cc

from hdt import atomic


def cache_dir() -> Path:
  return Path(os.environ.get("HDT_CACHE_DIR", Path.home() / ".cache" / "hdt"))


def enable_compile_cache(path: str | os.PathLike | None = None) -> Path:
  """Turns on JAX's persistent compilation cache (``cache_dir()/jax`` unless ``path`` or
  ``JAX_COMPILATION_CACHE_DIR`` says otherwise): a second run of the same configuration loads its
  programs instead of compiling them. Returns the directory in use."""
  path = path or os.environ.get("JAX_COMPILATION_CACHE_DIR") or cache_dir() / "jax"
  jax.config.update("jax_compilation_cache_dir", str(path))
  return Path(path)


@functools.cache
def code_version() -> str:
  """A hash of hdt's source files, the jax/jaxlib/mujoco versions, the devices and XLA flags: a
  compiled program saved by other code or for another machine setup is never loaded."""
  root = Path(__file__).parent
  h = hashlib.sha256(f"{jax.__version__} {jaxlib.__version__} {mujoco.__version__} {jax.devices()} "
                     f"{os.environ.get('XLA_FLAGS', '')} {jax.config.jax_enable_x64}".encode())
  for path in sorted(root.rglob("*")):
    if path.suffix in (".py", ".cc") and "__pycache__" not in path.parts:
      h.update(str(path.relative_to(root)).encode() + path.read_bytes())
  return h.hexdigest()


def compiled_all(programs: Sequence[tuple[Callable, str, Callable[[], tuple]]]) -> list:
  """Each ``(jitted, key, abstract_args)`` (a ``jax.jit`` function) compiled ahead of time, loaded
  from ``cache_dir()/aot`` when a program was saved under ``key`` (which must name everything the
  program depends on besides hdt's code) by this code version; otherwise lowered for
  ``abstract_args()`` (ShapeDtypeStructs), compiled and saved. A loaded program pays no tracing,
  lowering or compiling. Programs with host callbacks (``jax.pure_callback``) are not saved: their
  callbacks live in one process only. Only while the persistent compile cache is on
  (:func:`enable_compile_cache`, as the CLI does); else returns the ``jitted`` themselves.

  XLA releases the GIL while it compiles, so each program compiles on a thread while the next one is
  lowered: a cold start costs about the largest compile, not their sum.

  Opt-in (``HDT_AOT_CACHE=1``): programs are keyed by :func:`code_version`, so after any edit of hdt's
  sources every saved program is compiled afresh, past the persistent compile cache (see
  :func:`_persistent_cache_off`), which keys by the lowered program and would have skipped most of them."""
  if not jax.config.jax_compilation_cache_dir or os.environ.get("HDT_AOT_CACHE") != "1":
    return [jitted for jitted, _, _ in programs]
  paths = [cache_dir() / "aot" / f"{hashlib.sha256((key + code_version()).encode()).hexdigest()[:32]}.pkl"
           for _, key, _ in programs]
  out = [_load(path) for path in paths]
  todo = [i for i, program in enumerate(out) if program is None]
  if not todo:
    return out
  with _persistent_cache_off(), concurrent.futures.ThreadPoolExecutor(len(todo)) as pool:
    futures = {}
    for i in todo:  # lowering holds the GIL; the compiles submitted before it run meanwhile
      jitted, _, abstract_args = programs[i]
      lowered = jitted.lower(*abstract_args())
      futures[i] = (pool.submit(lowered.compile), "callback" not in lowered.as_text())
    for i, (future, savable) in futures.items():
      out[i] = future.result()
      if savable:
        _save(paths[i], out[i])
  return out


def _load(path: Path):
  if not path.exists():
    return None
  try:
    with open(path, "rb") as f:
      program, device_ids = pickle.load(f)
    by_id = {d.id: d for d in jax.devices()}
    # on the devices it was compiled for: by default it would expect one shard per device
    return serialize_executable.deserialize_and_load(*program, execution_devices=[by_id[i] for i in device_ids])
  except Exception:  # noqa: BLE001 - damaged or stale file: compile afresh and replace it
    return None


def _save(path: Path, program) -> None:
  path.parent.mkdir(parents=True, exist_ok=True)
  with atomic.open_atomic(path, "wb") as f:  # a concurrent run never reads half a file
    devices = {d.id for sh in jax.tree.leaves(program.input_shardings) for d in sh.device_set}
    pickle.dump((serialize_executable.serialize(program), sorted(devices)), f)


@contextlib.contextmanager
def _persistent_cache_off():
  """Programs compiled inside are compiled by XLA, never taken from the persistent compile cache:
  XLA:CPU re-serialises an executable it loaded from that cache without its kernels, so a program
  saved from a cache hit failed at run time in the next process ("Function wrapped_slice not found")."""
  enabled = jax.config.jax_enable_compilation_cache
  jax.config.update("jax_enable_compilation_cache", False)
  cc.reset_cache()  # the cache memoises whether it is on
  try:
    yield
  finally:
    jax.config.update("jax_enable_compilation_cache", enabled)
    cc.reset_cache()
