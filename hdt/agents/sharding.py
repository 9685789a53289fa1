"""The seed axis of a vmapped run, sharded across devices (and hosts).

Seeds are independent: the vmapped training functions run under ``shard_map`` on a 1-D mesh named
"seeds", so every TrainState leaf (replay, env states, params) is split along its leading axis and
each device runs its own seeds with no communication. Across
hosts, call :func:`initialize_distributed` first (``jax.distributed.initialize``); every process
builds the same keys and the mesh spans all processes' devices.
"""

from __future__ import annotations

import os

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec


def initialize_distributed() -> None:
  """``jax.distributed.initialize()`` when launched as one of several processes (coordinator
  address and process id from the environment, as on SLURM / Cloud TPU, or HDT_DISTRIBUTED=1)."""
  if os.environ.get("HDT_DISTRIBUTED") == "1" and not jax.distributed.is_initialized():
    jax.distributed.initialize()


def seed_mesh(num_seeds: int) -> Mesh | None:
  """A 1-D "seeds" mesh over all devices, or None with one device or when the seeds do not split
  evenly (then everything stays on the default device)."""
  devices = jax.devices()
  if len(devices) == 1 or num_seeds % len(devices):
    return None
  return Mesh(np.asarray(devices), ("seeds",))


def over_seeds(fn, mesh: Mesh | None, num_args: int = 1):
  """``fn`` (already vmapped over seeds) run per device on its own seeds with ``shard_map``, so
  host callbacks inside (the native physics backend) also run per shard, on local data."""
  if mesh is None:
    return fn
  spec = PartitionSpec("seeds")
  return jax.shard_map(fn, mesh=mesh, in_specs=(spec,) * num_args, out_specs=spec, check_vma=False)


def seed_sharding(num_seeds: int) -> NamedSharding | None:
  """The leading (seed) axis split over :func:`seed_mesh`."""
  mesh = seed_mesh(num_seeds)
  return None if mesh is None else NamedSharding(mesh, PartitionSpec("seeds"))


def shard(tree, sharding: NamedSharding | None):
  return tree if sharding is None else jax.device_put(tree, sharding)


def to_host(tree):
  """numpy copies of (possibly multi-host) sharded arrays, gathered onto every process."""
  def get(x):
    if isinstance(x, jax.Array) and not x.is_fully_addressable:
      return np.asarray(multihost_utils.process_allgather(x, tiled=True))
    return np.asarray(jax.device_get(x))
  return jax.tree.map(get, tree)
