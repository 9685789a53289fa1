"""The plug-in protocol of make_train: a list of Plugin objects folded over, per-seed plug-in state in
TrainState.aux, and plug-ins that combine (a discriminator reward and a KL term in one run)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hdt.agents import discriminator as disc_lib
from hdt.agents import train as sac_train
from hdt.agents.discriminator import DiscConfig
from hdt.agents.kl import KL_REFERENCE, kl_plugin
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
  # both plug-ins' states are in TrainState.aux, per seed
  aux = res.state.aux
  assert {"params", "buf", KL_REFERENCE} <= set(aux)
  assert all(x.shape[0] == 2 for x in jax.tree.leaves(aux[KL_REFERENCE]))


def test_the_kl_reference_is_per_seed_state():
  """Each seed regularises towards the reference in its own TrainState: give seed 1 its own policy
  as reference and its KL term is 0 at the start, while seed 0's is not."""
  networks = sac_train.make_networks(ENV, CFG)
  trainer = sac_train.make_train(ENV, CFG, networks=networks,
                                 plugins=[kl_plugin(networks.policy_apply, _reference(networks), 1.0, 1e6)])
  ts = sac_train.vmapped(trainer).init(sac_train.seed_keys([0, 1]))
  own = jax.tree.map(lambda r, p: r.at[1].set(p[1]), ts.aux[KL_REFERENCE], ts.agent.policy_params)
  ts = ts.replace(aux=dict(ts.aux, **{KL_REFERENCE: own}))
  ts, m = sac_train.vmapped(trainer).run_chunk(ts)  # learning starts within the first chunk
  reg = np.asarray(m["kl"])
  assert reg[0] > 1e-3 and reg[1] < 0.1 * reg[0], reg  # seed 1 starts at its reference


def test_plugins_that_cannot_combine_are_refused():
  reg = lambda state, params, obs: jnp.zeros(())
  with pytest.raises(ValueError, match="each define regularizer; at most one plug-in may"):
    sac_train.make_train(ENV, CFG, plugins=[Plugin("a", regularizer=reg), Plugin("b", regularizer=reg)])
  init = lambda key, agent: (agent, {"x": jnp.zeros(())})
  with pytest.raises(ValueError, match=r"plug-in 'b' uses TrainState.aux keys \['x'\] that another plug-in owns"):
    sac_train.make_train(ENV, CFG, plugins=[Plugin("a", init=init), Plugin("b", init=init)])
  with pytest.raises(ValueError, match="each plug-in needs its own name"):
    sac_train.make_train(ENV, CFG, plugins=[Plugin("a"), Plugin("a")])
  with pytest.raises(TypeError, match="initial state must be a dict"):
    sac_train.make_train(ENV, CFG, plugins=[Plugin("a", init=lambda key, agent: (agent, jnp.zeros(())))])
