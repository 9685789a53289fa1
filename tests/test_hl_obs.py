"""HL observation features (Task.hl_features) and the running observation normaliser."""

import jax
import jax.numpy as jnp
import numpy as np

from hdt.agents import networks as nets
from hdt.agents import normalizer
from hdt.envs.tasks import TASKS


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


def test_normalised_networks_apply_both_layouts_and_stop_gradients():
  n = nets.make_sac_networks(3, 2, (8,), normalize_observations=True)
  p = n.policy_init(jax.random.PRNGKey(0))
  assert normalizer.KEY in p and normalizer.KEY in n.q_init(jax.random.PRNGKey(1))
  obs = jnp.ones((5, 3))
  stats = normalizer.update(normalizer.init(3), jax.random.normal(jax.random.PRNGKey(2), (50, 3)) * 4 + 1)
  p = normalizer.with_stats(p, stats)
  plain, _ = normalizer.split(p)
  loc, _ = n.policy_apply(p, obs)
  loc_ref, _ = n.policy_apply(plain, normalizer.normalize(stats, obs))  # parameters without a normaliser
  np.testing.assert_allclose(loc, loc_ref, rtol=1e-6)
  g = jax.grad(lambda p: jnp.sum(n.policy_apply(p, obs)[0]))(p)
  assert all(float(jnp.max(jnp.abs(x))) == 0.0 for x in jax.tree.leaves(g[normalizer.KEY]))


def test_waypoint_hl_sees_the_waypoint_relative_to_the_agent():
  wp = TASKS["waypoint"]()
  obs_hi = jnp.array([1.0, 2.0, 4.0, -1.0])
  np.testing.assert_allclose(wp.hl_features(obs_hi), [3.0, -3.0])
  np.testing.assert_allclose(TASKS["waypoint"](hl_relative=(), hl_absolute=True).hl_features(obs_hi), obs_hi)
  push = TASKS["push1"](hl_relative=(2,))
  obs = jnp.array([0.1, 0.2, 0.3, 0.5, 7.0, 8.0])
  np.testing.assert_allclose(push.hl_features(obs), [0.1, 0.2, 0.2, 0.3, 7.0, 8.0], rtol=1e-6)
  np.testing.assert_allclose(TASKS["maze"]().hl_features(obs_hi), obs_hi)
