"""Build, load and register the native physics custom call (``native_ffi.cc``).

The C++ handler is compiled on first use with the system's C++ compiler against the installed
mujoco and jaxlib headers, and cached under ``$HDT_CACHE_DIR`` (default ``~/.cache/hdt``) keyed by
the source and both versions, so an upgrade rebuilds it. Without a compiler (or with
``HDT_NATIVE_FFI=0``) ``available()`` is False and the native backend falls back to
``jax.pure_callback``: same results, more per-step overhead, and no persistent compile cache.
"""

from __future__ import annotations

import ctypes
import functools
import glob
import hashlib
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import jax
import jaxlib
import mujoco
import numpy as np

from hdt import atomic
from hdt.cache import cache_dir

SOURCE = Path(__file__).with_name("native_ffi.cc")
STEP_TARGET, FORWARD_TARGET = "hdt_physics_step", "hdt_physics_forward"
_models: dict[int, mujoco.MjModel] = {}  # registered models stay alive for the process


def _mujoco_lib() -> Path:
  libs = sorted(glob.glob(os.path.join(os.path.dirname(mujoco.__file__), "libmujoco.so*")))
  if not libs:
    raise FileNotFoundError("libmujoco.so not found next to the mujoco package")
  return Path(libs[0])


def _build(out: Path) -> None:
  cxx = os.environ.get("CXX") or shutil.which("g++") or shutil.which("c++") or shutil.which("clang++")
  if cxx is None:
    raise FileNotFoundError("no C++ compiler (g++, c++ or clang++) on PATH")
  lib = _mujoco_lib()
  out.parent.mkdir(parents=True, exist_ok=True)
  with atomic.temp_path(out) as tmp:  # a concurrent or killed build never leaves half a library
    cmd = [cxx, "-O2", "-std=c++17", "-shared", "-fPIC", "-pthread", str(SOURCE), "-o", tmp,
           f"-I{jax.ffi.include_dir()}", f"-I{lib.parent / 'include'}", str(lib),
           f"-Wl,-rpath,{lib.parent}"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
      errors = [l for l in proc.stderr.splitlines() if "error" in l][:5] or proc.stderr.splitlines()[-5:]
      raise RuntimeError(f"{' '.join(cmd)} failed:\n" + "\n".join(errors))


@functools.cache
def _library() -> ctypes.CDLL | None:
  if os.environ.get("HDT_NATIVE_FFI", "1") == "0":
    return None
  key = hashlib.sha256(SOURCE.read_bytes() + f"{mujoco.__version__} {jaxlib.__version__} "
                       f"{sys.platform}".encode()).hexdigest()[:16]
  path = cache_dir() / f"native_ffi-{key}.so"
  try:
    if not path.exists():
      _build(path)
    lib = ctypes.CDLL(str(path))
  except (OSError, RuntimeError, FileNotFoundError) as e:
    warnings.warn(f"hdt: native physics custom call unavailable, using jax.pure_callback "
                  f"(slower, and not in JAX's persistent compile cache): {e}", stacklevel=3)
    return None
  lib.HdtRegisterModel.argtypes = [ctypes.c_int64, ctypes.c_void_p]
  lib.HdtRegisterModel.restype = ctypes.c_int
  jax.ffi.register_ffi_target(STEP_TARGET, jax.ffi.pycapsule(lib.HdtPhysicsStep), platform="cpu")
  jax.ffi.register_ffi_target(FORWARD_TARGET, jax.ffi.pycapsule(lib.HdtPhysicsForward),
                              platform="cpu")
  return lib


def available() -> bool:
  return _library() is not None


def model_id(model: mujoco.MjModel) -> int:
  """A content hash of the compiled model (its MJB bytes): stable across processes."""
  buf = np.empty(mujoco.mj_sizeModel(model), np.uint8)
  mujoco.mj_saveModel(model, None, buf)
  return int.from_bytes(hashlib.blake2b(buf.tobytes(), digest_size=8).digest(), "little") >> 1


def register(model: mujoco.MjModel) -> int:
  """Registers ``model`` with the custom call and returns the id the call is given."""
  lib = _library()
  if lib is None:
    raise RuntimeError("the native physics custom call is not available")
  mid = model_id(model)
  if mid not in _models:
    _models[mid] = model
    lib.HdtRegisterModel(mid, model._address)
  return mid
