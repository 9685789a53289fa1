"""The high level as an environment: a task plus a frozen low level (DESIGN: "HL env").

One HL action is a relative sub-goal z in [-1, 1]^2, scaled to the agent's goal box (``delta_max``):
``g = skill(obs_hi) + delta_max * z``. One HL step is the authors' ``Hierarchical.high_level_step``
(bot_transfer/envs/hierarchical.py): the frozen LL acts deterministically for at most k steps (a
``while_loop``) and stops once the goal-space point is within epsilon of g (``early_stop``) or the robot fell;
the HL reward is the task's reward at the end of the step (``Task.hl_reward``) minus
``skill_penalty * |delta_max * z|``, and the task is judged solved on the state at the end of the step.
The LL parameters live in the state, so every seed of a vmapped sweep can drive its own LL.

The HL policy observes ``task.hl_features(obs_hi)`` (``state.obs`` / ``next_obs``), while ``obs_hi``
keeps the raw global observation the sub-goals are built from. Waypoint's HL sees the waypoint relative
to the agent (a departure from the authors, who feed both absolute positions; SPEC.md, Departures).
"""

from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp

from hdt.envs.core import State
from hdt.envs.env import AgentTaskEnv

LowPolicy = Callable[[Any, jax.Array], jax.Array]  # (params, Task.ll_observation) -> action


def _reduce(how: str, values: jax.Array, active: jax.Array, last: jax.Array) -> jax.Array:
  """One HL step's value of a per-LL-step metric, as the task's ``step_reduce`` says."""
  if how == "last":
    return values[last]
  if how == "max":
    return jnp.max(values)
  if how == "sum":
    return jnp.sum(values)
  if how == "mean":  # over the LL steps taken
    return jnp.sum(values * active) / jnp.maximum(active.sum(), 1)
  raise ValueError(f"unknown HL-step reduction {how!r}; use mean, last, max or sum (Task.step_reduce)")


def skill(obs_hi: jax.Array) -> jax.Array:
  """Goal-space point of a global observation (torso / end-effector / peg-tip xy)."""
  return obs_hi[..., :2]


class HighLevelEnv:
  """Wraps an agent-task environment whose LL acts on sub-goals. Owns the HL time limit."""

  def __init__(self, env: AgentTaskEnv, low_policy: LowPolicy, low_params: Any, k: int | None = None,
               hl_horizon: int | None = None, early_stop: bool = True, record: bool = False,
               delta_max: float | None = None, eps: float | None = None):
    self.env = env
    self.low_policy = low_policy
    self.low_params = low_params
    # None means the agent's / task's default; 0 is an error, not a default.
    self.k = int(env.agent.k if k is None else k)
    if self.k <= 0:
      raise ValueError(f"k (LL steps per HL action) must be positive, got {self.k}; e.g. the agent's "
                       f"default k={env.agent.k}")
    self.horizon = int(env.task.hl_horizon if hl_horizon is None else hl_horizon)
    if self.horizon <= 0:
      raise ValueError(f"hl_horizon (HL steps per episode) must be positive, got {self.horizon}; e.g. "
                       f"the task's default {env.task.hl_horizon}")
    self.delta_max = float(env.agent.delta_max if delta_max is None else delta_max)
    if not self.delta_max > 0:
      raise ValueError(f"delta_max (half-width of the sub-goal box) must be positive, got "
                       f"{self.delta_max}; e.g. the agent's default {env.agent.delta_max}")
    self.early_stop = early_stop
    # epsilon_low of the authors' env: the task's (Insert 0.015) or the agent's (manip 0.01, nav 0.27)
    self.eps = float(eps if eps is not None else env.task.hl_eps if env.task.hl_eps is not None
                     else env.agent.reach_eps)
    self.record = record
    self.action_size = 2
    self.features = env.task.hl_features  # obs_hi -> what the HL policy observes
    self.observation_size = int(self.features(jnp.zeros((env.obs_hi_size,))).shape[-1])
    self.obs_hi_size, self.obs_lo_size = env.obs_hi_size, env.obs_lo_size

  def _wrap(self, inner: State, low_params, **kw) -> State:
    next_hi = kw.get("next_obs", inner.obs_hi)
    return State(physics=inner, obs=self.features(inner.obs_hi), obs_hi=inner.obs_hi, obs_lo=inner.obs_lo,
                 next_obs=self.features(next_hi), next_obs_hi=next_hi,
                 reward=kw.get("reward", jnp.float32(0.0)), done=kw.get("done", jnp.float32(0.0)),
                 discount=kw.get("discount", jnp.float32(1.0)),
                 task={"low": low_params, "steps": kw.get("steps", jnp.int32(0))},
                 metrics=kw.get("metrics", {}), key=kw.get("key", inner.key))

  def reset(self, key: jax.Array, low_params: Any = None) -> State:
    inner = self.env.reset(key)
    state = self._wrap(inner, self.low_params if low_params is None else low_params)
    _, metrics = self._metrics_template(state)
    return state.replace(metrics=metrics)

  def _metrics_template(self, state):
    m = {k: jnp.zeros((), jnp.float32) for k in state.physics.metrics}
    m |= {"ll_steps": jnp.float32(0.0), "sub_goal_dist": jnp.float32(0.0)}
    if self.record:
      m |= {"xy": jnp.zeros((self.k, 2)), "block": jnp.zeros((self.k, 2)),
            "active": jnp.zeros((self.k,)), "goal": jnp.zeros(2),
            "qpos": jnp.zeros((self.k,) + state.physics.physics.qpos.shape)}
    return None, m

  def step(self, state: State, action: jax.Array) -> State:
    inner0 = state.physics
    low = state.task["low"]
    task = self.env.task
    z = self.delta_max * jnp.clip(action, -1.0, 1.0)
    goal = skill(inner0.obs_hi) + z

    def ll_step(inner, running):
      a = self.low_policy(low, task.ll_observation(inner.obs_lo, inner.obs_hi, goal))
      nxt = self.env.step(inner, a, auto_reset=False, active=running)
      out = dict(nxt.metrics, reward=nxt.reward)
      if self.record:
        out["xy"] = skill(nxt.obs_hi)
        out["block"] = nxt.obs_hi[2:4] if nxt.obs_hi.shape[-1] >= 4 else jnp.zeros(2)
        out["qpos"] = nxt.physics.qpos  # every LL step's pose, for videos (hdt.render)
      still = nxt.done == 0  # the inner env's done flags a fall only
      if self.early_stop:
        still = still & ~(jnp.linalg.norm(skill(nxt.obs_hi) - goal) < self.eps)
      return nxt, still, out

    # A while loop, not a scan of k steps: it ends when the LL stops (under vmap, when every env's
    # LL has), and the physics skips the envs that stopped earlier. Steps not taken record zeros.
    template = jax.eval_shape(ll_step, inner0, jnp.bool_(True))[2]
    per0 = {k: jnp.zeros((self.k,) + v.shape, v.dtype) for k, v in template.items()}

    def body(c):
      i, inner, running, per = c
      nxt, still, out = ll_step(inner, running)
      per = {k: v.at[i].set(out[k]) for k, v in per.items()}
      return i + 1, nxt, still, per

    c0 = (jnp.int32(0), inner0, jnp.bool_(True), per0)
    taken, inner, _, per = jax.lax.while_loop(lambda c: c[2] & (c[0] < self.k), body, c0)
    last = taken - 1  # the loop always takes a first step
    per["active"] = (jnp.arange(self.k) < taken).astype(jnp.float32)

    reward = task.hl_reward(per["reward"], per, last) - task.skill_penalty * jnp.linalg.norm(z)
    # A fall ends the HL step but not the HL episode (high_level_is_done ignores it, e.g. ant.py Ant):
    # each later HL step then lasts one LL step and pays the task reward of the fallen robot.
    terminal = inner.task["solved"]
    steps = state.task["steps"] + 1
    done = terminal | (steps >= self.horizon)
    key, k_reset = jax.random.split(state.key)
    next_hi = inner.obs_hi
    inner = jax.tree.map(lambda n, o: jnp.where(done, n, o), self.env.reset(k_reset), inner)
    active = per["active"]
    metrics = {k: _reduce(task.reduction(k), v, active, last)
               for k, v in per.items() if k not in ("active", "xy", "block", "qpos", "reward")}
    metrics["ll_steps"] = active.sum()
    metrics["sub_goal_dist"] = jnp.linalg.norm(skill(next_hi) - goal)
    if self.record:
      metrics |= {"xy": per["xy"], "block": per["block"], "active": active, "goal": goal, "qpos": per["qpos"]}
    return self._wrap(inner, low, next_obs=next_hi, reward=reward, done=done.astype(jnp.float32),
                      discount=1.0 - terminal.astype(jnp.float32), steps=jnp.where(done, 0, steps),
                      metrics=metrics, key=key)
