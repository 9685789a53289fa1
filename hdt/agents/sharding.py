"""The seed axis of a vmapped run, sharded across devices (and hosts).

Seeds are independent: the vmapped training functions run under ``shard_map`` on a 1-D mesh named
"seeds", so every TrainState leaf (replay, env states, params) is split along its leading axis and
each device runs its own seeds with no communication. Across
processes (hosts), call :func:`initialize_distributed` first (``jax.distributed.initialize``); every
process builds the same keys, the mesh spans the same number of devices of every process, so each
process trains its own consecutive share of the seeds, and only between chunks are the per-seed
results gathered (metrics, evaluations, saved states) onto every process. Process 0 alone writes
files (:func:`writes`, :func:`on_writer`).

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


DISTRIBUTED_VARS = ("JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES", "JAX_PROCESS_ID")


class OtherProcessFailed(RuntimeError):
  """Another process of a multi-process run failed; this one stops with it (its own output says why)."""


def _env_int(name: str) -> int | None:
  text = os.environ.get(name)
  if text is None or not text.strip():
    return None
  try:
    return int(text)
  except ValueError:
    raise ValueError(f"{name}={text!r}: give a whole number (e.g. {name}=0)") from None


def initialize_distributed() -> bool:
  """With ``HDT_DISTRIBUTED=1``, ``jax.distributed.initialize()`` as one of several processes: the
  coordinator address, number of processes and this process's id from ``JAX_COORDINATOR_ADDRESS``,
  ``JAX_NUM_PROCESSES`` and ``JAX_PROCESS_ID`` where set, the rest detected by JAX from the cluster
  (SLURM, Open MPI, Kubernetes, Cloud TPU). Returns whether it initialised (False: not asked, or
  already done). Call it before any JAX operation."""
  if os.environ.get("HDT_DISTRIBUTED") != "1" or jax.distributed.is_initialized():
    return False
  num, pid = _env_int("JAX_NUM_PROCESSES"), _env_int("JAX_PROCESS_ID")
  # Cross-process collectives on CPU go over TCP with gloo (the default of this JAX, which older
  # versions did not have); on GPUs and TPUs the backend's own collectives are used.
  if not os.environ.get("JAX_CPU_COLLECTIVES_IMPLEMENTATION"):
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
  try:
    jax.distributed.initialize(coordinator_address=os.environ.get("JAX_COORDINATOR_ADDRESS") or None,
                               num_processes=num, process_id=pid)
  except ValueError as e:  # JAX found no cluster to read what is missing from
    unset = [v for v in DISTRIBUTED_VARS if not os.environ.get(v)]
    what = str(e).rstrip(".")
    raise ValueError(f"HDT_DISTRIBUTED=1 but {what[:1].lower() + what[1:]} (JAX found no cluster such as SLURM "
                     f"to read it from): "
                     f"set {', '.join(unset) or ', '.join(DISTRIBUTED_VARS)} on every process, e.g. "
                     f"JAX_COORDINATOR_ADDRESS=host0:1234 JAX_NUM_PROCESSES=2 JAX_PROCESS_ID=0 "
                     f"(1 on the other)") from None
  return True


def several_processes() -> bool:
  """Whether this process is one of several (``jax.distributed`` initialised with more than one)."""
  return jax.distributed.is_initialized() and jax.process_count() > 1


def writes() -> bool:
  """Whether this process writes files: the only process, or process 0 of several."""
  return jax.process_index() == 0


def agree(ok: bool) -> bool:
  """Whether ``ok`` holds on every process (one small collective that every process must reach at the
  same point; True at once with a single process)."""
  if jax.process_count() == 1:
    return bool(ok)
  return bool(np.all(multihost_utils.process_allgather(np.asarray([bool(ok)]))))


def stop_together(error: BaseException | None, what: str) -> None:
  """Every process raises if any failed at this point (``error``: this process's failure, or None):
  its own error, or :class:`OtherProcessFailed`; so that no process waits for the others in the next
  collective. ``what`` names the step in the message."""
  if not agree(error is None):
    if error is not None:
      raise error
    raise OtherProcessFailed(f"another process of this run failed while {what}, so this one stops too; "
                             f"that process's output says why")


def on_writer(fn, what: str):
  """``fn()`` on the process that writes files (:func:`writes`), its result there (None on the others);
  with several processes, all learn whether it succeeded and fail together (:func:`stop_together`)."""
  if jax.process_count() == 1:
    return fn()
  result, error = None, None
  if writes():
    try:
      result = fn()
    except BaseException as e:  # noqa: BLE001 - re-raised below, after the others know
      error = e
  stop_together(error, what)
  return result


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
  """A 1-D "seeds" mesh over the most devices that split the seeds evenly, or None when that is one
  device (then everything stays on the default device). With several processes, the mesh takes the
  same number of devices from each, process by process, so that each trains its own consecutive share
  of the seeds; None when the seeds do not split over the processes (then every process trains every
  seed on its own, the same, and process 0 writes them)."""
  devices = mesh_devices(jax.devices(), num_seeds, jax.process_count())
  return None if len(devices) <= 1 else Mesh(np.asarray(devices), ("seeds",))


def mesh_devices(devices: list, num_seeds: int, processes: int = 1) -> list:
  """The devices of :func:`seed_mesh` (in mesh order) among ``devices`` (each with a ``process_index``)."""
  if processes > 1:
    per_process = [[d for d in devices if d.process_index == p] for p in range(processes)]
    local = min(len(ds) for ds in per_process)
    n = max((k for k in range(1, local + 1) if num_seeds % (k * processes) == 0), default=0)
    return [d for ds in per_process for d in ds[:n]]
  n = max(d for d in range(1, min(len(devices), num_seeds) + 1) if num_seeds % d == 0)
  return list(devices[:n])


def seed_devices(num_seeds: int) -> int:
  """How many devices :func:`seed_mesh` splits ``num_seeds`` over (1 when it does not split them)."""
  mesh = seed_mesh(num_seeds)
  return 1 if mesh is None else mesh.size


def local_runs(num_seeds: int) -> list[int]:
  """The indices of the runs (seeds) that this process trains: its devices' consecutive shares of
  :func:`seed_mesh`, or all of them when the mesh does not split them."""
  mesh = seed_mesh(num_seeds)
  if mesh is None:
    return list(range(num_seeds))
  per = num_seeds // mesh.size
  here = jax.process_index()
  return [i * per + j for i, d in enumerate(mesh.devices.flat) if d.process_index == here for j in range(per)]


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


def gathered(tree):
  """``tree`` with every array that spans several processes gathered onto this one (numpy, as
  :func:`to_host`); every process must call it at the same point. Other leaves stay as they are."""
  def get(x):
    if isinstance(x, jax.Array) and not x.is_fully_addressable:
      return np.asarray(multihost_utils.process_allgather(x, tiled=True))
    return x
  return jax.tree.map(get, tree)


def to_host(tree):
  """numpy copies of (possibly multi-host) sharded arrays, gathered onto every process."""
  def get(x):
    if isinstance(x, jax.Array) and not x.is_fully_addressable:
      return np.asarray(multihost_utils.process_allgather(x, tiled=True))
    return np.asarray(jax.device_get(x))
  return jax.tree.map(get, tree)
