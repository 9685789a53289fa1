"""Where hdt keeps files between runs: the compiled physics custom call, JAX's compile cache and
ahead-of-time compiled training programs."""

from __future__ import annotations

import concurrent.futures
import functools
import hashlib
import os
import pickle
from pathlib import Path
from typing import Callable

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


def compiled(jitted, key: str, abstract_args: Callable[[], tuple]):
  """``jitted`` (a ``jax.jit`` function) compiled ahead of time, loaded from ``cache_dir()/aot``
  when a program was saved under ``key`` (which must name everything the program depends on besides
  hdt's code) by this code version; otherwise lowered for ``abstract_args()`` (ShapeDtypeStructs),
  compiled and saved. A loaded program pays no tracing, lowering or compiling. Programs with host
  callbacks (``jax.pure_callback``) are not saved: their callbacks live in one process only. Only
  while the persistent compile cache is on (:func:`enable_compile_cache`, as the CLI does); else
  returns ``jitted`` itself.

  Opt-in (``HDT_AOT_CACHE=1``): programs are keyed by :func:`code_version`, so after any edit of hdt's
  sources every saved program is compiled afresh, past the persistent compile cache (see
  :func:`_compile_fresh`), which keys by the lowered program and would have skipped most of them."""
  return compiled_many([(jitted, key, abstract_args)])[0]


def compiled_many(specs: list[tuple]) -> list:
  """:func:`compiled` of each ``(jitted, key, abstract_args)``: the saved ones loaded, the others
  lowered one by one and compiled side by side in threads (XLA compiles without the GIL, so a cold
  start on several cores overlaps the training chunk's compile with the others')."""
  if not jax.config.jax_compilation_cache_dir or os.environ.get("HDT_AOT_CACHE") != "1":
    return [jitted for jitted, _, _ in specs]
  paths = [cache_dir() / "aot" / f"{hashlib.sha256((key + code_version()).encode()).hexdigest()[:32]}.pkl"
           for _, key, _ in specs]
  out = [_load(path) for path in paths]
  todo = [i for i, program in enumerate(out) if program is None]
  lowered = {i: specs[i][0].lower(*specs[i][2]()) for i in todo}
  plain = [i for i in todo if "callback" in lowered[i].as_text()]  # not saved: compiled as usual
  fresh = [i for i in todo if i not in plain]
  for i in plain:
    out[i] = lowered[i].compile()
  for i, program in zip(fresh, _compile_fresh([lowered[i] for i in fresh])):
    out[i] = program
    paths[i].parent.mkdir(parents=True, exist_ok=True)
    with atomic.open_atomic(paths[i], "wb") as f:  # a concurrent run never reads half a file
      devices = {d.id for sh in jax.tree.leaves(program.input_shardings) for d in sh.device_set}
      pickle.dump((serialize_executable.serialize(program), sorted(devices)), f)
  return out


def _load(path: Path):
  """The program saved at ``path``, or None (none, or damaged or stale: compiled afresh and replaced)."""
  if not path.exists():
    return None
  try:
    with open(path, "rb") as f:
      program, device_ids = pickle.load(f)
    by_id = {d.id: d for d in jax.devices()}
    # on the devices it was compiled for: by default it would expect one shard per device
    return serialize_executable.deserialize_and_load(*program, execution_devices=[by_id[i] for i in device_ids])
  except Exception:  # noqa: BLE001
    return None


def _compile_fresh(lowered: list) -> list:
  """The ``lowered`` programs compiled by XLA side by side, never taken from the persistent compile
  cache: XLA:CPU re-serialises an executable it loaded from that cache without its kernels, so a
  program saved from a cache hit failed at run time in the next process ("Function wrapped_slice not
  found"). The cache is switched off once around all of them (not per thread)."""
  if not lowered:
    return []
  enabled = jax.config.jax_enable_compilation_cache
  jax.config.update("jax_enable_compilation_cache", False)
  cc.reset_cache()  # the cache memoises whether it is on
  try:
    with concurrent.futures.ThreadPoolExecutor(max_workers=len(lowered)) as pool:
      return list(pool.map(lambda low: low.compile(), lowered))
  finally:
    jax.config.update("jax_enable_compilation_cache", enabled)
    cc.reset_cache()
