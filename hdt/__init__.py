"""hdt: hierarchically decoupled morphological transfer in pure JAX."""

import importlib

from hdt.version import __version__  # noqa: F401 (a leaf: imports nothing)

# Imported on first use: ``import hdt`` (and the ``hdt`` command, which handles Ctrl-C before JAX is
# imported) costs nothing until a name below is used.
_EXPORTS = {
    "envs": "hdt.envs",
    "use_cpu_cores": "hdt.agents.sharding",
    "train_low": "hdt.transfer.pipeline", "train_high": "hdt.transfer.pipeline", "train_full": "hdt.transfer.pipeline",
    "finetune_high": "hdt.transfer.finetune",
    "RunOptions": "hdt.transfer.runner", "LowRef": "hdt.transfer.card", "AlignSpec": "hdt.transfer.align",
    "FinetuneSpec": "hdt.transfer.finetune",
    "compose": "hdt.transfer.evaluate", "evaluate": "hdt.transfer.evaluate",
    "random_actions": "hdt.transfer.evaluate", "zero_shot_matrix": "hdt.transfer.evaluate",
    "trajectory": "hdt.transfer.evaluate",
}

__all__ = list(_EXPORTS)


def __getattr__(name):
  if name not in _EXPORTS:
    raise AttributeError(f"module 'hdt' has no attribute {name!r}")
  module = importlib.import_module(_EXPORTS[name])
  value = module if name == "envs" else getattr(module, name)
  globals()[name] = value
  return value


def __dir__():
  return sorted(list(globals()) + __all__)
