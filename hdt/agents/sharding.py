"""The seed axis of a vmapped run, sharded across devices (and hosts).

Seeds are independent: the vmapped training functions run under ``shard_map`` on a 1-D mesh named
"seeds", so every TrainState leaf (replay, env states, params) is split along its leading axis and
each device runs its own seeds with no communication. Across
hosts, call :func:`initialize_distributed` first (``jax.distributed.initialize``); every process
builds the same keys and the mesh spans all processes' devices.

On a CPU, :func:`use_cpu_cores` (the CLI calls it) splits the machine into several JAX devices: XLA:CPU
runs the small matmuls of one device's program on about one core, so seeds on separate devices use
the others.
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


CPU_DEVICES_FLAG = "xla_force_host_platform_device_count"


def cpu_cores() -> int:
  """The cores this process may run on (its affinity mask, e.g. under taskset or a container)."""
  return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def use_cpu_cores(num_devices: int | None = None) -> int | None:
  """Makes JAX's CPU backend ``num_devices`` devices (default: one per core). Returns the number set, or
  None when JAX already ran an operation (too late to change) or the user chose (``JAX_NUM_CPU_DEVICES``,
  or the XLA flag in ``XLA_FLAGS``). More devices than cores helps matmul-bound runs (3 LL seeds on 3
  devices on 2 cores) but slows physics-bound ones (HLs), so the default does not oversubscribe."""
  if os.environ.get("JAX_NUM_CPU_DEVICES") or CPU_DEVICES_FLAG in os.environ.get("XLA_FLAGS", ""):
    return None
  n = num_devices or cpu_cores()
  try:
    jax.config.update("jax_num_cpu_devices", n)
  except RuntimeError:  # backends already initialised
    return None
  return n


def seed_mesh(num_seeds: int) -> Mesh | None:
  """A 1-D "seeds" mesh over the most devices (of one process) that split the seeds evenly, or None
  when that is one device (then everything stays on the default device). Across processes the mesh
  spans all devices, or is None when the seeds do not split over all of them."""
  devices = jax.devices()
  if jax.process_count() > 1:
    n = len(devices) if num_seeds % len(devices) == 0 else 1
  else:
    n = max(d for d in range(1, min(len(devices), num_seeds) + 1) if num_seeds % d == 0)
  return None if n <= 1 else Mesh(np.asarray(devices[:n]), ("seeds",))


def seed_devices(num_seeds: int) -> int:
  """How many devices :func:`seed_mesh` splits ``num_seeds`` over (1 when it does not split them)."""
  mesh = seed_mesh(num_seeds)
  return 1 if mesh is None else mesh.size


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
