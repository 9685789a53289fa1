"""The plug-in protocol of make_train: a list of Plugin objects folded over, per-seed plug-in state in
TrainState.aux, and plug-ins that combine (a discriminator reward and a KL term in one run)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hdt.agents import discriminator as disc_lib
from hdt.agents import train as sac_train
from hdt.agents.discriminator import DiscConfig, DiscState
from hdt.agents.kl import KLState, kl_plugin
from hdt.agents.plugins import Plugin
from hdt.agents.sac import SACConfig
from toy_env import PointGoal

ENV = PointGoal()
CFG = SACConfig(hidden_sizes=(16, 16), batch_size=16, buffer_size=500, num_envs=4, steps_per_chunk=25,
                total_env_steps=400, learning_starts=40, num_eval_episodes=4)


def _disc():
  return disc_lib.make_alignment(
      DiscConfig(batch_size=8, hidden_sizes=(8,), buffer_size=256, include_z=False, data="fixed"),  # toy env: no z
      np.random.default_rng(0).normal(size=(256, disc_lib.TAU_SIZE)).astype(np.float32),
      CFG.total_env_steps, CFG.num_envs)


def _reference(networks, seed=99):
  return networks.policy_init(jax.random.PRNGKey(seed))


def test_discriminator_and_kl_train_together_and_both_terms_are_logged():
  networks = sac_train.make_networks(ENV, CFG)
  kl = kl_plugin(networks.policy_apply, _reference(networks), kl_weight=2.0, anneal_steps=CFG.total_env_steps)
  res = sac_train.run(ENV, CFG, seeds=[0, 1], networks=networks, plugins=[_disc().plugin, kl])
  h = res.history
  learned = h["update_steps"][:, -1] > 0
  assert learned.all()
  for term in ("disc/loss", "disc/acc", "kl", "kl_weight", "critic_loss", "actor_loss"):
    assert term in h and np.all(np.isfinite(h[term])), term
  chunks = h["env_steps"][0] > CFG.learning_starts
  assert np.all(h["kl"][:, chunks] > 0)  # the KL to another network is never 0
  assert np.all(h["disc/loss"].max(axis=1) > 0)  # it trains (until DiscConfig.stop of the run)
  w = h["kl_weight"][0]
  assert w[chunks][0] > w[-1] > 0  # annealed from 2 towards 0
  # each plug-in's state is in TrainState.aux under its name, of its own type, per seed
  aux = res.state.aux
  assert set(aux) == {"discriminator", "kl"}
  assert isinstance(aux["discriminator"], DiscState) and isinstance(aux["kl"], KLState)
  assert all(x.shape[0] == 2 for x in jax.tree.leaves(aux["kl"].reference))


def test_the_kl_reference_is_per_seed_state():
  """Each seed regularises towards the reference in its own TrainState: give seed 1 its own policy
  as reference and its KL term is 0 at the start, while seed 0's is not."""
  networks = sac_train.make_networks(ENV, CFG)
  trainer = sac_train.make_train(ENV, CFG, networks=networks,
                                 plugins=[kl_plugin(networks.policy_apply, _reference(networks), 1.0, 1e6)])
  ts = sac_train.vmapped(trainer).init(sac_train.seed_keys([0, 1]), sac_train.seed_indices(2))
  own = jax.tree.map(lambda r, p: r.at[1].set(p[1]), ts.aux["kl"].reference, ts.agent.policy_params)
  ts = ts.replace(aux=dict(ts.aux, kl=ts.aux["kl"].replace(reference=own)))
  ts, m = sac_train.vmapped(trainer).run_chunk(ts)  # learning starts within the first chunk
  reg = np.asarray(m["kl"])
  assert reg[0] > 1e-3 and reg[1] < 0.1 * reg[0], reg  # seed 1 starts at its reference


def test_regularizers_compose_each_with_its_schedule_and_name():
  """Two regularising plug-ins and two with transition extras in one run: each term is weighted by its
  own schedule and logged under its plug-in's name; each plug-in gets back its own extras."""
  seen = {}

  def extras(name, value):
    def update(state, transitions, env_steps, key):
      seen[name] = transitions.extras  # traced: the shapes are what matter
      return state, {}
    return dict(transition_extras=lambda s, n: {"v": jnp.full((), value)}, update=update)

  a = Plugin("a", regularizer=lambda state, params, obs: jnp.float32(1.0), schedule=lambda t: jnp.float32(0.5),
             **extras("a", 1.0))
  b = Plugin("b", regularizer=lambda state, params, obs: jnp.float32(3.0), **extras("b", 2.0))
  trainer = sac_train.make_train(ENV, CFG, plugins=[a, b])
  ts, m = sac_train.vmapped(trainer).run_chunk(
      sac_train.vmapped(trainer).init(sac_train.seed_keys([0]), sac_train.seed_indices(1)))
  assert (float(m["a"][0]), float(m["a_weight"][0]), float(m["b"][0]), float(m["b_weight"][0])) == (1, 0.5, 3, 1)
  assert set(ts.replay.data.extras) == {"a", "b"} and set(seen["a"]) == set(seen["b"]) == {"v"}
  assert float(ts.replay.data.extras["b"]["v"][0, 0]) == 2.0
  with pytest.raises(ValueError, match="'c' has a schedule but no regularizer"):
    sac_train.make_train(ENV, CFG, plugins=[Plugin("c", schedule=lambda t: 1.0)])


def test_plugins_see_their_seed_index():
  """init gets each seed's place in the run's seeds (the same in every grid point)."""
  plugin = Plugin("i", init=lambda key, agent, seed_index: (agent, jnp.asarray(seed_index)))
  trainer = sac_train.make_train(ENV, CFG, plugins=[plugin])
  ts = sac_train.vmapped(trainer).init(sac_train.seed_keys([5, 9, 5, 9]), sac_train.seed_indices(2, 2))
  assert np.asarray(ts.aux["i"]).tolist() == [0, 1, 0, 1]


def test_each_plugin_keeps_its_own_state():
  """Two plug-ins whose states have the same shape and field names do not collide: each state is kept
  under its plug-in's name, and each update sees its own."""
  init = lambda v: lambda key, agent, seed_index: (agent, {"x": jnp.float32(v)})
  update = lambda state, transitions, env_steps, key: ({"x": state["x"] + 1.0}, {})
  trainer = sac_train.make_train(ENV, CFG, plugins=[Plugin("a", init=init(0.0), update=update),
                                                     Plugin("b", init=init(100.0), update=update)])
  ts, _ = trainer.run_chunk(trainer.init(jax.random.PRNGKey(0)))
  steps = CFG.steps_per_chunk
  assert (float(ts.aux["a"]["x"]), float(ts.aux["b"]["x"])) == (steps, 100.0 + steps)


def test_plugins_that_cannot_combine_are_refused():
  with pytest.raises(ValueError, match="each plug-in needs its own name"):
    sac_train.make_train(ENV, CFG, plugins=[Plugin("a"), Plugin("a")])
