"""HL observation features (Task.hl_features) and the running observation normaliser."""

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from hdt.agents import networks as nets
from hdt.agents import normalizer
from hdt.agents import train as sac_train
from hdt.agents.sac import SACConfig, init_sac_state
from hdt.envs.tasks import TASKS
from hdt.transfer import checkpoint as ckpt
from toy_env import PointGoal


def test_normalizer_matches_numpy_over_batches():
  rng = np.random.default_rng(0)
  xs = [rng.normal(3.0, 2.0, (n, 4)).astype(np.float32) for n in (1, 7, 8, 33)]
  s = normalizer.init(4)
  for x in xs:
    s = normalizer.update(s, x)
  allx = np.concatenate(xs)
  np.testing.assert_allclose(s["count"], len(allx))
  np.testing.assert_allclose(s["mean"], allx.mean(0), rtol=1e-5)
  np.testing.assert_allclose(normalizer.std(s), allx.std(0), rtol=1e-4)
  z = normalizer.normalize(s, jnp.asarray(allx))
  np.testing.assert_allclose(np.asarray(z).mean(0), 0.0, atol=1e-4)
  assert float(jnp.max(jnp.abs(normalizer.normalize(s, jnp.full((4,), 1e6))))) == normalizer.CLIP


def test_normalised_networks_take_the_statistics_explicitly_and_stop_gradients():
  n = nets.make_sac_networks(3, 2, (8,))
  agent = init_sac_state(n, SACConfig(normalize_observations=True), jax.random.PRNGKey(0))
  p = agent.policy_params
  # the statistics live in their own field; the networks are plain flax variables
  assert float(agent.obs_norm["count"]) == 0.0 and agent.obs_norm["mean"].shape == (3,)
  assert all(normalizer.KEY not in t for t in (p, agent.q_params, agent.target_q_params))
  assert init_sac_state(n, SACConfig(), jax.random.PRNGKey(0)).obs_norm is None
  obs, act = jnp.ones((5, 3)), jnp.zeros((5, 2))
  stats = normalizer.update(normalizer.init(3), jax.random.normal(jax.random.PRNGKey(2), (50, 3)) * 4 + 1)
  loc, _ = n.policy_apply(p, obs, stats)
  loc_ref, _ = n.policy_apply(p, normalizer.normalize(stats, obs))  # applied without a normaliser
  np.testing.assert_allclose(loc, loc_ref, rtol=1e-6)
  np.testing.assert_allclose(n.q_apply(agent.q_params, obs, act, stats),
                             n.q_apply(agent.q_params, normalizer.normalize(stats, obs), act), rtol=1e-6)
  g = jax.grad(lambda s: jnp.sum(n.policy_apply(p, obs, s)[0]))(stats)
  assert all(float(jnp.max(jnp.abs(x))) == 0.0 for x in jax.tree.leaves(g))


def test_training_updates_the_statistics_apart_from_the_networks_over_seeds():
  """Vmapped over two seeds: the statistics count every collected observation (the soft update of
  the target critics, which have none, cannot average them) and are saved beside the parameters."""
  cfg = SACConfig(hidden_sizes=(8,), batch_size=8, buffer_size=100, num_envs=2, steps_per_chunk=10,
                  total_env_steps=40, learning_starts=4, num_eval_episodes=2, normalize_observations=True)
  trainer = sac_train.make_train(PointGoal(), cfg)
  fns = sac_train.vmapped(trainer, 2)
  ts = fns.init(sac_train.seed_keys([0, 1]), sac_train.seed_indices(2))
  ts, _ = fns.run_chunk(ts)
  np.testing.assert_array_equal(ts.agent.obs_norm["count"], ts.env_steps.astype(np.float32))
  assert ts.agent.obs_norm["mean"].shape == (2, 4)
  assert all(normalizer.KEY not in t for t in (ts.agent.policy_params, ts.agent.q_params,
                                                 ts.agent.target_q_params))
  assert set(sac_train.saved_params(ts.agent)) == {"policy", "q", normalizer.KEY}
  ev = fns.evaluate(ts.agent.policy_params, sac_train.seed_keys([5, 6]), ts.agent.obs_norm)
  assert np.all(np.isfinite(ev["return"]))


def test_checkpoints_with_the_statistics_inside_the_networks_are_split_on_load(tmp_path):
  stats = normalizer.update(normalizer.init(3), np.arange(6, dtype=np.float32).reshape(2, 3))
  pol, q = {"params": {"w": np.ones((3, 2), np.float32)}}, {"params": {"v": np.zeros((4,), np.float32)}}
  legacy = {"policy": dict(pol, obs_norm=stats), "q": dict(q, obs_norm=stats),
            "target_q": dict(q, obs_norm=stats), "log_alpha": np.float32(0.5)}
  ckpt.save(tmp_path, 0, legacy, {"level": "low"}, best=(legacy, {"env_steps": 1}))
  for which in ckpt.WHICH:
    got, _ = ckpt.load(tmp_path, 0, which)
    assert set(got) == {"policy", "q", "target_q", "log_alpha", normalizer.KEY}
    for name, want in (("policy", pol), ("q", q), ("target_q", q), (normalizer.KEY, stats)):
      assert jax.tree.structure(got[name]) == jax.tree.structure(want)
      assert all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(got[name]), jax.tree.leaves(want)))

  # a resumable state: the policy's statistics become the agent's, their other copies are dropped
  @struct.dataclass
  class Agent:
    policy_params: Any
    policy_opt_state: Any
    obs_norm: Any = None

  @struct.dataclass
  class TS:
    agent: Any

  old = TS(Agent(dict(pol, obs_norm=stats), {"mu": dict(pol, obs_norm=stats)}))
  old_best = {"policy": dict(pol, obs_norm=stats), "q": dict(q, obs_norm=stats), "return": np.float32(1)}
  ckpt.save_state(tmp_path / "run", old, {}, {}, best=old_best)
  new = TS(Agent(pol, {"mu": pol}, stats))
  new_best = {"policy": pol, "q": q, normalizer.KEY: stats, "return": np.float32(1)}
  saved = ckpt.load_state(tmp_path / "run", new, new_best)
  for a, b in ((saved.tree, new), (saved.best, new_best)):
    assert jax.tree.structure(a) == jax.tree.structure(b)
    assert all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))


def test_waypoint_hl_sees_the_waypoint_relative_to_the_agent():
  wp = TASKS["waypoint"]()
  obs_hi = jnp.array([1.0, 2.0, 4.0, -1.0])
  np.testing.assert_allclose(wp.hl_features(obs_hi), [3.0, -3.0])
  np.testing.assert_allclose(TASKS["waypoint"](hl_relative=(), hl_absolute=True).hl_features(obs_hi), obs_hi)
  push = TASKS["push1"](hl_relative=(2,))
  obs = jnp.array([0.1, 0.2, 0.3, 0.5, 7.0, 8.0])
  np.testing.assert_allclose(push.hl_features(obs), [0.1, 0.2, 0.2, 0.3, 7.0, 8.0], rtol=1e-6)
  np.testing.assert_allclose(TASKS["maze"]().hl_features(obs_hi), obs_hi)
