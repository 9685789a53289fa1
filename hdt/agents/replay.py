"""A device-resident circular replay buffer as pure functions over a pytree state.

Why not ``brax.training.replay_buffers.UniformSamplingQueue``: when it is full its ``insert`` does
``jnp.roll`` of the whole buffer (O(capacity) per insert). Here an insert writes ``n`` rows at a
moving pointer with ``lax.dynamic_update_slice`` (or a modular scatter when ``n`` does not divide the
capacity), so it costs O(n) and, with the state donated to a jitted function, updates in place.

Everything is a pure function of :class:`ReplayState`, so it works under ``jit``, ``lax.scan`` and
``vmap`` over seeds (sampling has a custom vmap rule, see ``_take_rows``; it is not
differentiable, which a replay never needs).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct


@struct.dataclass
class Transition:
  obs: jax.Array
  action: jax.Array
  reward: jax.Array
  next_obs: jax.Array
  discount: jax.Array
  extras: Any = None  # optional per-transition data of a plug-in (make_train's transition_extras)
  done: Any = None  # 1 where the episode ended (time limits too); stored only for n-step returns


@struct.dataclass
class ReplayState:
  data: Any  # pytree (usually a Transition) of arrays with leading axis `capacity`
  position: jax.Array  # int32, next row to write
  size: jax.Array  # int32, number of filled rows (<= capacity)


def capacity(state: ReplayState) -> int:
  return jax.tree_util.tree_leaves(state.data)[0].shape[0]


def make_transition_spec(observation_size: int, action_size: int, with_done: bool = False) -> Transition:
  """One float32 transition of zeros (the row layout of the buffer; numpy: no device op to compile).
  ``with_done``: also the episode-end flag that n-step sampling needs."""
  z = lambda *s: np.zeros(s, np.float32)
  return Transition(
      obs=z(observation_size),
      action=z(action_size),
      reward=z(),
      next_obs=z(observation_size),
      discount=z(),
      done=z() if with_done else None,
  )


def init(buffer_size: int, example: Any) -> ReplayState:
  """An empty buffer of ``buffer_size`` rows shaped like the single (unbatched) ``example``."""
  if buffer_size <= 0:
    raise ValueError(f"buffer_size must be positive, got {buffer_size}")
  data = jax.tree_util.tree_map(
      lambda x: jnp.zeros((buffer_size,) + jnp.shape(x), jnp.asarray(x).dtype), example
  )
  return ReplayState(data=data, position=jnp.zeros((), jnp.int32), size=jnp.zeros((), jnp.int32))


def insert(state: ReplayState, batch: Any) -> ReplayState:
  """Writes the ``n`` rows of ``batch`` (leading axis n) at the pointer, wrapping around."""
  cap = capacity(state)
  n = jax.tree_util.tree_leaves(batch)[0].shape[0]
  if n > cap:
    raise ValueError(f"cannot insert {n} rows into a replay buffer of capacity {cap}")
  pos = state.position
  if cap % n == 0:
    # pos is always a multiple of n, so the slice never crosses the end.
    def write(buf, x):
      return jax.lax.dynamic_update_slice_in_dim(buf, x.astype(buf.dtype), pos, axis=0)
  else:
    idx = (pos + jnp.arange(n, dtype=jnp.int32)) % cap

    def write(buf, x):
      return buf.at[idx].set(x.astype(buf.dtype), unique_indices=True)

  data = jax.tree_util.tree_map(write, state.data, batch)
  return ReplayState(
      data=data,
      position=((pos + n) % cap).astype(jnp.int32),
      size=jnp.minimum(state.size + n, cap).astype(jnp.int32),
  )


def sample(state: ReplayState, key: jax.Array, batch_size: int) -> Any:
  """``batch_size`` rows drawn uniformly (with replacement) from the filled rows.

  On an empty buffer this returns row 0 (zeros); callers should not learn before anything is in.
  """
  return sample_from_bits(state, jax.random.bits(key, (batch_size,), jnp.uint32))


def sample_from_bits(state: ReplayState, bits: jax.Array) -> Any:
  """Rows ``bits % size`` for uniformly random uint32 ``bits`` (one row per entry).

  The modulo bias is at most ``capacity / 2**32`` (2e-4 relative for a 1M buffer).
  """
  size = jnp.maximum(state.size, 1).astype(jnp.uint32)
  idx = (bits.astype(jnp.uint32) % size).astype(jnp.int32)
  return jax.tree_util.tree_map(lambda buf: _take_rows(buf, idx), state.data)


def sample_n_step_from_bits(state: ReplayState, bits: jax.Array, n: int, stride: int, gamma: float) -> Transition:
  """n-step transitions starting at uniformly drawn rows, folded so that the one-step target
  ``reward + gamma * discount * V(next_obs)`` is the n-step one.

  The buffer must hold ``Transition`` rows with ``done`` that were inserted ``stride`` at a time (one
  row per parallel env), so the same env's next step sits ``stride`` rows later. A start is drawn
  among the rows that have ``n - 1`` successors. The sum stops at the first episode end (a time
  limit included); the fold is ``reward = sum_j gamma^j r_j`` over the ``m`` steps kept,
  ``discount = gamma^(m-1) * discount_(m-1)`` and ``next_obs`` that of step ``m - 1``.
  """
  cap = capacity(state)
  oldest = (state.position - state.size) % cap
  starts = jnp.maximum(state.size - (n - 1) * stride, 1).astype(jnp.uint32)
  offset = (bits.astype(jnp.uint32) % starts).astype(jnp.int32)
  rows = (oldest + offset[:, None] + stride * jnp.arange(n, dtype=jnp.int32)) % cap  # (B, n)
  data = state.data
  reward, discount, done = (_take_rows(x, rows) for x in (data.reward, data.discount, data.done))
  # alive[:, j]: step j belongs to the start's episode (no end among steps 0..j-1)
  alive = jnp.cumprod(jnp.concatenate([jnp.ones_like(done[:, :1]), 1.0 - done[:, :-1]], axis=1), axis=1)
  powers = jnp.asarray(gamma, jnp.float32) ** jnp.arange(n, dtype=jnp.float32)
  last = jnp.sum(alive, axis=1).astype(jnp.int32) - 1  # the last step kept, 0..n-1
  at_last = lambda x: jnp.take_along_axis(x, last[:, None], axis=1)[:, 0]
  first = rows[:, 0]
  return Transition(
      obs=_take_rows(data.obs, first),
      action=_take_rows(data.action, first),
      reward=jnp.sum(alive * powers * reward, axis=1),
      next_obs=_take_rows(data.next_obs, at_last(rows)),
      discount=powers[last] * at_last(discount),
      extras=None if data.extras is None else jax.tree_util.tree_map(lambda x: _take_rows(x, first), data.extras),
      done=at_last(done),
  )


@jax.custom_batching.custom_vmap
def _take_rows(buf, idx):
  return jnp.take(buf, idx, axis=0, mode="clip")


@_take_rows.def_vmap
def _take_rows_vmap(axis_size, in_batched, buf, idx):
  # Under vmap (seeds), jnp.take becomes one batched gather, and XLA on CPU fused that gather
  # with the preceding insert (dynamic_update_slice), which forced a copy of the whole buffer on
  # every training step (2.5x slower at 200k rows, worse for bigger buffers). One plain gather
  # per batch member keeps the insert in place.
  buf_b, idx_b = in_batched
  outs = [_take_rows(buf[i] if buf_b else buf, idx[i] if idx_b else idx) for i in range(axis_size)]
  return jnp.stack(outs), True
