"""Memory estimates, checked before anything is compiled: a request that would not fit is refused in one
line naming what to lower, instead of an allocation failure minutes later."""

from __future__ import annotations

import jax
import numpy as np
import psutil

from hdt.agents.sac import SACConfig


def _available_bytes() -> int:
  """Memory a new allocation can get without swapping (psutil: MemAvailable on Linux, its equivalent
  elsewhere)."""
  return int(psutil.virtual_memory().available)


def _tree_bytes(tree) -> int:
  return sum(int(np.prod(x.shape)) * np.dtype(x.dtype).itemsize for x in jax.tree.leaves(tree))


def state_bytes(env) -> int:
  """Bytes of one env state (from its shapes, nothing allocated)."""
  return _tree_bytes(jax.eval_shape(env.reset, jax.ShapeDtypeStruct((2,), np.uint32)))


def check_memory(need: int, what: str, fix: str) -> None:
  """Refuses (one line) a request whose estimated size ``need`` exceeds 90% of available memory."""
  avail = _available_bytes()
  if need > 0.9 * avail:
    raise ValueError(f"{what} needs about {need / 2**30:.3g} GiB but {avail / 2**30:.3g} GiB of memory are "
                     f"available: {fix}")


def _mlp_params(sizes, n_in: int, n_out: int) -> int:
  dims = [n_in, *sizes, n_out]
  return sum(a * b + b for a, b in zip(dims[:-1], dims[1:]))


def network_bytes(obs_size: int, action_size: int, config: SACConfig) -> int:
  """Float32 bytes of one seed's SAC networks as training keeps them: the actor with its gradient and
  two Adam moments (4 copies), the twin critics (and V) also with their targets (5 copies), and a
  batch of activations."""
  actor = _mlp_params(config.hidden_sizes, obs_size, 2 * action_size)
  critics = 2 * _mlp_params(config.critic_sizes, obs_size + action_size, 1)
  if getattr(config, "value_net", False):
    critics += _mlp_params(config.critic_sizes, obs_size, 1)
  widest = max([*config.hidden_sizes, *config.critic_sizes])
  return 4 * (4 * actor + 5 * critics + 8 * config.batch_size * widest * len(config.critic_sizes))


def check_train_memory(env, config: SACConfig, seeds, points: int = 1) -> None:
  """Estimate, per seed (and grid point): the networks (:func:`network_bytes`), the replay buffer (obs,
  next obs, action, reward, discount, and done for n-step returns, in float32), the training env states (~2 copies) and the
  evaluation episodes' env states (~4 copies, as hdt.transfer.evaluate counts them)."""
  n = seeds if isinstance(seeds, (int, np.integer)) and not isinstance(seeds, bool) else \
      (len(seeds) if hasattr(seeds, "__len__") else 1)
  if n <= 0:
    return  # seed_list explains
  n *= points
  transition = 4 * (2 * env.observation_size + env.action_size + 2 + (getattr(config, "n_step", 1) > 1))
  per_seed = (config.buffer_size * transition + network_bytes(env.observation_size, env.action_size, config)
              + (2 * config.num_envs + 4 * config.num_eval_episodes) * state_bytes(env))
  check_memory(n * per_seed, f"training {n} seeds (networks {list(config.hidden_sizes)}, replay buffer of "
               f"{config.buffer_size}, {config.num_envs} env(s) and {config.num_eval_episodes} evaluation "
               f"episodes per seed)",
               "lower the number of seeds, hidden_sizes, buffer_size, num_envs or num_eval_episodes")
