"""Evaluation rollouts (``hdt.agents.acting.evaluate``) against a plain Python loop."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from toy_env import PointGoal

from hdt.agents import acting


@dataclasses.dataclass(frozen=True)
class EndsEarly(PointGoal):
  """Episodes end after 2 to 6 steps (set by the goal), far inside the horizon; counts its steps."""
  horizon: int = 200
  calls: list = dataclasses.field(default_factory=list, compare=False, hash=False)

  def step(self, state, action):
    jax.debug.callback(lambda: self.calls.append(1))
    s = super().step(state, action)
    end = 2 + jnp.floor((state.task["goal"][0] + 1) * 2.499).astype(jnp.int32)
    return s.replace(done=jnp.maximum(s.done, (state.task["t"] + 1 >= end).astype(jnp.float32)))


def policy(params, obs):
  return jnp.tanh(obs[..., 2:] * params)


def test_evaluation_stops_when_every_episode_is_done_and_counts_as_a_python_loop():
  env, n, key = EndsEarly(), 6, jax.random.PRNGKey(3)
  out = jax.jit(lambda k: acting.evaluate(env, policy, 2.0, k, n))(key)
  # the reference: each episode stepped alone up to and including its first done
  rets, lengths, dists = [], [], []
  for k in jax.random.split(key, n):
    s, ret, t, dist = env.reset(k), 0.0, 0, []
    while True:
      s = env.step(s, policy(2.0, s.obs))
      ret, t = ret + float(s.reward), t + 1
      dist.append(float(s.metrics["goal_dist"]))
      if s.done or t == env.horizon:
        break
    rets.append(ret), lengths.append(t), dists.append(dist)
  np.testing.assert_allclose(out["return"], np.mean(rets), rtol=1e-5)
  np.testing.assert_allclose(out["return_std"], np.std(rets), rtol=1e-4)
  np.testing.assert_allclose(out["length"], np.mean(lengths))
  np.testing.assert_allclose(out["goal_dist"], np.mean([np.mean(d) for d in dists]), rtol=1e-5)
  np.testing.assert_allclose(out["goal_dist_final"], np.mean([d[-1] for d in dists]), rtol=1e-5)
  np.testing.assert_allclose(out["goal_dist_max"], np.mean([max(d) for d in dists]), rtol=1e-5)
  assert max(lengths) < 7 < env.horizon
  env.calls.clear()
  jax.block_until_ready(acting.evaluate(env, policy, 2.0, key, n))
  assert 0 < len(env.calls) <= n * max(lengths)  # stopped with the longest episode, not at the horizon
