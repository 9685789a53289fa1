"""Where hdt keeps files between runs: the compiled physics custom call and JAX's compile cache."""

from __future__ import annotations

import os
from pathlib import Path

import jax


def cache_dir() -> Path:
  return Path(os.environ.get("HDT_CACHE_DIR", Path.home() / ".cache" / "hdt"))


def enable_compile_cache(path: str | os.PathLike | None = None) -> Path:
  """Turns on JAX's persistent compilation cache (``cache_dir()/jax`` unless ``path`` or
  ``JAX_COMPILATION_CACHE_DIR`` says otherwise): a second run of the same configuration loads its
  programs instead of compiling them. Returns the directory in use."""
  path = path or os.environ.get("JAX_COMPILATION_CACHE_DIR") or cache_dir() / "jax"
  jax.config.update("jax_compilation_cache_dir", str(path))
  return Path(path)
