"""SAC's sample-efficiency options: n-step critic targets (SACConfig.n_step; the replay's n-step sample
against a brute-force reference), the delayed actor (SACConfig.policy_delay) and the policy's moving
average (SACConfig.policy_ema); SAC learns with each."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hdt.agents import replay
from hdt.agents.plugins import Plugin
from hdt.agents.sac import SACConfig, make_update
from hdt.agents.train import delayed_actor_group, make_train, run, saved_params
from toy_env import PointGoal


def _reference(r, d, e, next_obs, t, env, n, gamma):
  """Walk env ``env``'s steps from ``t`` until n steps or an episode end."""
  ret = 0.0
  for j in range(n):
    ret += gamma ** j * r[t + j, env]
    if e[t + j, env] or j == n - 1:
      return ret, gamma ** j * d[t + j, env], next_obs[t + j, env]


@pytest.mark.parametrize("cap", [48, 50])  # a multiple of the envs (slice writes) and not (scatter)
@pytest.mark.parametrize("steps", [5, 20])  # buffer not full; wrapped around twice
def test_n_step_sample_matches_a_walk_through_each_envs_steps(cap, steps):
  n_envs, n, gamma = 4, 3, 0.9
  rng = np.random.default_rng(cap + steps)
  r = rng.normal(size=(steps, n_envs)).astype(np.float32)
  e = (rng.random((steps, n_envs)) < 0.25).astype(np.float32)  # episode ends
  d = np.where(e > 0, (rng.random((steps, n_envs)) < 0.5), 1.0).astype(np.float32)  # time limits keep 1
  next_obs = rng.normal(size=(steps, n_envs, 2)).astype(np.float32)
  state = replay.init(cap, replay.make_transition_spec(2, 1, with_done=True))
  for t in range(steps):
    state = replay.insert(state, replay.Transition(
        obs=jnp.full((n_envs, 2), t, jnp.float32) + jnp.arange(n_envs)[:, None] / 10,
        action=jnp.zeros((n_envs, 1)), reward=r[t], next_obs=next_obs[t], discount=d[t], done=e[t]))
  total, size = steps * n_envs, int(state.size)
  starts = size - (n - 1) * n_envs
  s = jax.jit(replay.sample_n_step_from_bits, static_argnums=(2, 3, 4))(
      state, jnp.arange(starts, dtype=jnp.uint32), n, n_envs, gamma)
  for k in range(starts):
    g = total - size + k  # the k-th oldest row's global index
    t, env = divmod(g, n_envs)
    np.testing.assert_allclose(s.obs[k], [t + env / 10] * 2, rtol=1e-6)
    ret, disc, nxt = _reference(r, d, e, next_obs, t, env, n, gamma)
    np.testing.assert_allclose(s.reward[k], ret, rtol=1e-5, atol=1e-6, err_msg=f"start {t}, env {env}")
    np.testing.assert_allclose(s.discount[k], disc, rtol=1e-6, err_msg=f"start {t}, env {env}")
    np.testing.assert_array_equal(s.next_obs[k], nxt)
  # a start is never drawn among the newest (n - 1) steps, which lack successors
  drawn = replay.sample_n_step_from_bits(state, jax.random.bits(jax.random.PRNGKey(0), (4000,), jnp.uint32),
                                         n, n_envs, gamma)
  t_drawn = np.floor(np.asarray(drawn.obs[:, 0]))
  assert t_drawn.max() == steps - n and t_drawn.min() == (total - size) // n_envs


def _learns(total: int, **option):
  """(config, result) of a toy run with ``option``, checked to cut the final goal distance >= 10x."""
  cfg = SACConfig(total_env_steps=total, steps_per_chunk=500, learning_starts=300, buffer_size=10_000,
                  num_eval_episodes=32, num_envs=2, **option)
  result = run(PointGoal(), cfg, seeds=[0])
  dist = result.history["eval/goal_dist_final"][0]
  assert dist[-1] * 10.0 <= dist[0], dist
  return cfg, result


def test_n_step_sac_learns_and_one_step_stores_no_done():
  cfg, result = _learns(5_000, updates_per_step=2, n_step=3)
  assert result.state.replay.data.done.shape == (1, 10_000)
  one_step = jax.eval_shape(make_train(PointGoal(), dataclasses.replace(cfg, n_step=1)).init, jax.random.PRNGKey(0))
  assert one_step.replay.data.done is None  # the authors' one-step SAC keeps its replay layout


def test_n_step_needs_enough_stored_steps_and_no_reward_plugin():
  with pytest.raises(ValueError, match=r"n_step=3 needs learning_starts >= n_step \* num_envs = 24"):
    SACConfig(n_step=3, num_envs=8, learning_starts=20)
  with pytest.raises(ValueError, match="n_step=0: must be a positive integer"):
    SACConfig(n_step=0)
  reward = Plugin(name="disc", reward=lambda aux, batch: batch.reward)
  with pytest.raises(ValueError, match="cannot be combined with the reward of plug-in 'disc'"):
    make_train(PointGoal(), SACConfig(n_step=2), plugins=[reward])


def _adam_counts(opt_state) -> set:
  return {int(x) for x in jax.tree_util.tree_leaves(opt_state) if getattr(x, "dtype", None) == jnp.int32}


def test_policy_delay_steps_the_actor_and_temperature_once_every_d_updates():
  _, result = _learns(4_000, updates_per_step=4, policy_delay=2)
  agent = jax.tree_util.tree_map(lambda x: x[0], result.state.agent)
  updates = int(agent.update_steps)
  assert updates == 4 * ((4_000 - 300) // 2 + 1)  # 4 per training step from learning_starts on
  assert _adam_counts(agent.q_opt_state) == {updates}
  assert _adam_counts(agent.policy_opt_state) == _adam_counts(agent.alpha_opt_state) == {updates // 2}


def test_policy_delay_must_divide_the_updates_of_a_training_step():
  with pytest.raises(ValueError, match="policy_delay=3 must divide updates_per_step=8"):
    SACConfig(policy_delay=3, updates_per_step=8)


def test_a_delayed_actor_group_runs_the_critic_alone_first_and_logs_the_critic_over_all_its_updates():
  def update(agent, x, actor=True):  # agent: the order of calls; a metric per step kind
    m = {"critic_loss": x}
    return agent + [(float(x), actor)], (dict(m, actor_loss=10 * x) if actor else m)
  agent, m = delayed_actor_group(update, 3)([], jnp.array([1.0, 2.0, 6.0]))
  assert agent == [(1.0, False), (2.0, False), (6.0, True)]
  assert float(m["critic_loss"]) == 3.0 and float(m["actor_loss"]) == 60.0


def test_the_policys_moving_average_is_what_evaluations_and_checkpoints_use_and_training_is_unchanged():
  cfg = SACConfig(total_env_steps=1_500, steps_per_chunk=250, learning_starts=300, buffer_size=2_000,
                  num_eval_episodes=8, num_envs=2, updates_per_step=4, policy_delay=2)
  plain = run(PointGoal(), cfg, seeds=[0])
  ema = run(PointGoal(), dataclasses.replace(cfg, policy_ema=0.01), seeds=[0])
  train = lambda r: {k: v for k, v in r.history.items() if not k.startswith("eval/") and k != "walltime"}
  jax.tree_util.tree_map(np.testing.assert_array_equal, train(ema), train(plain))  # acting, updates: the same
  jax.tree_util.tree_map(np.testing.assert_array_equal, ema.state.agent.policy_params, plain.state.agent.policy_params)
  agent = jax.tree_util.tree_map(lambda x: x[0], ema.state.agent)
  assert not all(np.array_equal(a, b) for a, b in zip(jax.tree_util.tree_leaves(agent.policy_ema_params),
                                                      jax.tree_util.tree_leaves(agent.policy_params)))
  jax.tree_util.tree_map(np.testing.assert_array_equal, saved_params(ema.state.agent)["policy"],
                         ema.state.agent.policy_ema_params)
  assert not np.array_equal(ema.history["eval/return"], plain.history["eval/return"])
  assert jax.eval_shape(make_train(PointGoal(), cfg).init, jax.random.PRNGKey(0)).agent.policy_ema_params is None
  # one actor step moves the average by the rate toward the new policy
  trainer = make_train(PointGoal(), dataclasses.replace(cfg, policy_ema=0.01))
  update = make_update(trainer.networks, trainer.config, PointGoal().action_size)
  batch = jax.tree_util.tree_map(lambda x: x[0, :cfg.batch_size], ema.state.replay.data)
  new, _ = update(agent, batch, jnp.zeros((2, cfg.batch_size, PointGoal().action_size)))
  jax.tree_util.tree_map(lambda e, old, p: np.testing.assert_allclose(e, 0.99 * old + 0.01 * p, rtol=1e-6, atol=1e-7),
                         new.policy_ema_params, agent.policy_ema_params, new.policy_params)


def test_policy_ema_must_be_a_rate_below_one():
  with pytest.raises(ValueError, match=r"policy_ema=1.0: must be in \[0, 1\)"):
    SACConfig(policy_ema=1.0)
