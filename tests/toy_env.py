"""A pure-JAX 2-D point that must reach a random goal: a fast learning sanity check for SAC.

obs = [pos, goal - pos]; action in [-1, 1]^2 is a velocity scaled by 0.1 per step; reward =
-||goal - pos'||; episodes last ``horizon`` = 50 steps (time limit only, so discount is always 1)
and auto-reset inside ``step`` following ``hdt.envs.core``: the returned state carries the
pre-reset ``next_obs``, ``reward``, ``done`` and ``metrics`` of the step just taken, and the
post-reset ``obs`` the policy acts on next.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from hdt.envs.core import State


@dataclasses.dataclass(frozen=True)
class PointGoal:
  observation_size: int = 4
  action_size: int = 2
  horizon: int = 50
  speed: float = 0.1
  arena: float = 1.0  # start and goal uniform in [-arena, arena]^2

  def _obs(self, pos, goal):
    return jnp.concatenate([pos, goal - pos])

  def reset(self, key: jax.Array) -> State:
    k_draw, k_next = jax.random.split(key)
    pos, goal = jax.random.uniform(k_draw, (2, 2), jnp.float32, -self.arena, self.arena)
    obs = self._obs(pos, goal)
    zero = jnp.zeros((), jnp.float32)
    return State(
        physics=pos,
        obs=obs,
        obs_hi=pos,
        obs_lo=pos,
        next_obs=obs,
        next_obs_hi=pos,
        reward=zero,
        done=zero,
        discount=jnp.ones((), jnp.float32),
        task={"goal": goal, "t": jnp.zeros((), jnp.int32)},
        metrics={"goal_dist": jnp.linalg.norm(goal - pos)},
        key=k_next,
    )

  def step(self, state: State, action: jax.Array) -> State:
    goal, t = state.task["goal"], state.task["t"] + 1
    pos = state.physics + self.speed * jnp.clip(action, -1.0, 1.0)
    dist = jnp.linalg.norm(goal - pos)
    next_obs = self._obs(pos, goal)
    done = (t >= self.horizon).astype(jnp.float32)
    k_reset, k_next = jax.random.split(state.key)
    fresh = self.reset(k_reset)
    stepped = state.replace(
        physics=pos, obs=next_obs, obs_hi=pos, obs_lo=pos, task={"goal": goal, "t": t}
    )
    nxt = jax.tree_util.tree_map(lambda r, s: jnp.where(done > 0, r, s), fresh, stepped)
    return nxt.replace(
        next_obs=next_obs,
        next_obs_hi=pos,
        reward=-dist,
        done=done,
        discount=jnp.ones((), jnp.float32),
        metrics={"goal_dist": dist},
        key=k_next,
    )
