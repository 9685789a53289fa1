"""The environment interface every hdt environment implements.

An environment is a frozen object with two pure functions, ``reset(key) -> State`` and
``step(state, action) -> State``, both jit-able and vmappable. Episodes are handled inside ``step``
(auto-reset), so a training loop never calls ``reset`` after the first time: the transition for a
replay buffer is ``(state.obs, action, next.reward, next.next_obs, next.discount)``.
"""

from __future__ import annotations

from typing import Any, Protocol

import jax
from flax import struct


@struct.dataclass
class State:
  physics: Any  # backend-specific physics pytree (mjx.Data or native state vector + sensors)
  obs: jax.Array  # flat observation the policy of this environment sees
  obs_hi: jax.Array  # global, morphology-independent observation; obs_hi[:2] is the goal-space point
  obs_lo: jax.Array  # proprioceptive observation of the agent
  next_obs: jax.Array  # obs at the end of this step, before any auto-reset (for replay)
  next_obs_hi: jax.Array  # obs_hi at the end of this step, before any auto-reset
  reward: jax.Array
  done: jax.Array  # 1.0 when this step ended an episode (terminal or time limit)
  discount: jax.Array  # 0.0 on a true terminal (fall, task solved), else 1.0 (time limits bootstrap)
  task: Any  # task-specific state (goal, step counter, cached initial physics, ...)
  metrics: dict[str, jax.Array]
  key: jax.Array  # the environment's own RNG, so that step stays a function of (state, action)


class Env(Protocol):
  """What a training loop may rely on."""

  observation_size: int
  action_size: int
  horizon: int  # steps per episode (time limit)

  def reset(self, key: jax.Array) -> State: ...

  def step(self, state: State, action: jax.Array) -> State: ...
