"""SAC end to end on the toy point-goal env: it learns, seeds vmap exactly, the replay wraps."""

import dataclasses
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hdt.agents import replay
from hdt.agents.plugins import Plugin
from hdt.agents.sac import SACConfig
from hdt.agents.train import NONFINITE, eval_key, make_train, run, seed_indices, seed_keys, vmapped
from toy_env import PointGoal

ENV = PointGoal()
CFG = SACConfig(
    total_env_steps=5_000, steps_per_chunk=500, learning_starts=300, buffer_size=10_000,
    num_eval_episodes=32,
)
TRAINER = make_train(ENV, CFG)
# compiled once, shared by the tests below (compiling is most of their cost on a 2-core CPU)
INIT = jax.jit(TRAINER.init)
CHUNK = jax.jit(TRAINER.run_chunk, donate_argnums=0)  # donated: the replay is updated in place
EVAL = jax.jit(TRAINER.evaluate)


@pytest.mark.parametrize("seed", [0, 1])
def test_sac_learns_to_reach_goals(seed):
  """Deterministic-eval final distance to goal drops >= 10x within 5k env steps."""
  calls = []
  result = run(ENV, CFG, seeds=[seed], progress_fn=lambda step, m: calls.append(step),
               trainer=TRAINER)
  h = {k: v[0] for k, v in result.history.items()}  # the only seed
  assert calls == list(range(500, 5001, 500))
  np.testing.assert_array_equal(h["env_steps"], calls)
  np.testing.assert_array_equal(h["eval/env_steps"], [0] + calls)  # evaluated before training too
  untrained, trained = h["eval/goal_dist_final"][0], h["eval/goal_dist_final"][-1]
  print(f"seed {seed}: final goal distance untrained {untrained:.3f} -> trained {trained:.3f}")
  assert untrained > 0.5  # sanity: the untrained policy does not reach goals
  assert trained * 10.0 <= untrained, (untrained, trained)
  assert h["eval/return"][-1] > h["eval/return"][0]
  assert np.all(h["eval/length"] == ENV.horizon)  # eval episodes run to the time limit
  assert h["alpha"][-1] < 0.9  # the learned temperature went down from 1
  assert np.all(np.isfinite(h["critic_loss"])) and np.all(h["train_episodes"] == 10)
  # one update per env step once learning_starts env steps were taken
  assert int(result.state.env_steps[0]) == 5_000
  assert int(result.state.agent.update_steps[0]) == 5_000 - 300 + 1


def test_sb2_value_net_sac_learns_to_reach_goals():
  """SB2's SAC (the authors': V with a target V', the actor on Q_1) learns the same toy task."""
  cfg = dataclasses.replace(CFG, value_net=True)
  result = run(ENV, cfg, seeds=[0])
  dist = result.history["eval/goal_dist_final"][0]
  print(f"value_net: final goal distance untrained {dist[0]:.3f} -> trained {dist[-1]:.3f}")
  assert dist[-1] * 10.0 <= dist[0], dist
  agent = result.state.agent
  assert set(agent.q_params) == {"q", "v"} and set(agent.target_q_params) == {"v"}
  assert np.all(np.isfinite(result.history["v"]))


def test_vmap_over_seeds_matches_separate_runs():
  """run() (jit(vmap) over 4 seeds) == 4 separate unbatched runs, for one chunk."""
  seeds = [0, 1, 2, 3]
  calls = []
  one_chunk = dataclasses.replace(CFG, total_env_steps=CFG.env_steps_per_chunk)
  result = run(ENV, one_chunk, seeds, progress_fn=lambda step, m: calls.append((step, m)),
               trainer=TRAINER)
  h = result.history
  assert [c[0] for c in calls] == [500] and "eval/return" in calls[0][1]
  assert h["critic_loss"].shape == (4, 1) and h["eval/return"].shape == (4, 2)
  np.testing.assert_array_equal(h["eval/env_steps"], [[0, 500]] * 4)
  keys = seed_keys(seeds)
  for i in range(4):
    ts0 = INIT(keys[i])
    ev0 = EVAL(ts0.agent.policy_params, eval_key(keys[i], 0))
    ts, m = CHUNK(ts0)
    ev1 = EVAL(ts.agent.policy_params, eval_key(keys[i], 1))
    pick = lambda t: jax.tree_util.tree_map(lambda x: x[i], t)
    # Batched and unbatched XLA programs are not bit-identical (1-ulp differences inside the
    # fused Adam step); after 200 updates they agree to ~1e-7. A seed mix-up would be O(1).
    for a, b in zip(jax.tree_util.tree_leaves(pick(result.state.agent)),
                    jax.tree_util.tree_leaves(ts.agent)):
      np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)
    # the first 300 transitions come from uniform-random actions, before any update: exact
    np.testing.assert_array_equal(pick(result.state.replay.data.obs)[:300], ts.replay.data.obs[:300])
    for k in m:
      if k.startswith(NONFINITE):  # NaN-guard flags: checked by run(), not kept in the history
        assert m[k] == -1, k
        continue
      np.testing.assert_allclose(h[k][i, 0], m[k], rtol=1e-4, atol=1e-5, equal_nan=True, err_msg=k)
    for k in ev0:
      np.testing.assert_allclose(h["eval/" + k][i, 0], ev0[k], rtol=1e-5, err_msg=k)
      np.testing.assert_allclose(h["eval/" + k][i, 1], ev1[k], rtol=1e-4, atol=1e-5, err_msg=k)
  # the seeds are really different runs
  assert len(set(np.round(h["eval/return"][:, 1], 3))) == 4
  np.testing.assert_array_equal(h["update_steps"][:, 0], 500 - 300 + 1)
  assert result.state.env_steps.tolist() == [500] * 4
  jax.tree_util.tree_map(lambda x: np.testing.assert_equal(x.shape[0], 4), result.params)


@pytest.mark.parametrize("fields, values", [(("actor_lr", "critic_lr"), [1e-4, 3e-4]),
                                            (("target_entropy",), [None, 2.0])])
def test_vmapped_grid_matches_separate_runs(fields, values):
  """run(hyper=...) trains a 2-point grid (learning rates; target entropies) x 2 seeds as one vmapped
  program; each point equals its own separate run with the same seeds (float rounding apart)."""
  # (at lr 1e-3 the rounding differences grow chaotically: ~1e-7 after 100 updates, ~1e-3 in some
  # parameters after 200; at these rates they stay ~1e-7)
  seeds = [0, 1]
  one_chunk = dataclasses.replace(CFG, total_env_steps=CFG.env_steps_per_chunk)
  grid = run(ENV, one_chunk, seeds, trainer=TRAINER, hyper={f: values for f in fields})
  assert grid.history["critic_loss"].shape == (4, 1) and grid.history["eval/return"].shape == (4, 2)
  for p, v in enumerate(values):
    cfg = dataclasses.replace(one_chunk, **{f: v for f in fields})
    alone = run(ENV, cfg, seeds, trainer=TRAINER if cfg == one_chunk else None)
    rows = slice(p * len(seeds), (p + 1) * len(seeds))
    for k, v in alone.history.items():
      if k != "walltime":
        np.testing.assert_allclose(grid.history[k][rows], v, rtol=1e-4, atol=1e-5, equal_nan=True, err_msg=k)
    for a, b in zip(jax.tree_util.tree_leaves(jax.tree_util.tree_map(lambda x: x[rows], grid.state.agent)),
                    jax.tree_util.tree_leaves(alone.state.agent)):
      np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)
  # the two points really trained differently (a mix-up of the values would fail above)
  differs = "alpha" if fields == ("target_entropy",) else "critic_loss"
  assert not np.allclose(grid.history[differs][:2], grid.history[differs][2:], rtol=1e-2)


def test_hyper_grid_rejects_shape_changing_fields():
  with pytest.raises(ValueError, match="cannot be vmapped"):
    run(ENV, CFG, [0], trainer=TRAINER, hyper={"batch_size": [32, 64]})
  with pytest.raises(ValueError, match="same number"):
    run(ENV, CFG, [0], trainer=TRAINER, hyper={"actor_lr": [1e-3, 3e-4], "tau": [0.01]})


def _buffer_copies(compiled_text):
  return [l.strip()[:160] for l in compiled_text.splitlines()
          if "copy(" in l and re.search(rf"\b{CFG.buffer_size}\b", l)]


@pytest.mark.parametrize("seeds", [None, 1, 4])  # unbatched; vmapped over 1 and over 4 seeds
def test_replay_is_updated_in_place(seeds):
  """No copy of a replay-sized array in the compiled chunk (an O(capacity) copy per env step
  crept in while writing this; see replay._take_rows). The shapes match the tests above, so
  the compiled programs come from the cache when the whole file runs."""
  if seeds is None:
    chunk, ts = CHUNK, jax.eval_shape(TRAINER.init, jax.random.PRNGKey(0))
  else:
    fns = vmapped(TRAINER)
    chunk, ts = fns.run_chunk, jax.eval_shape(fns.init, seed_keys(range(seeds)), seed_indices(seeds))
  assert _buffer_copies(chunk.lower(ts).compile().as_text()) == []


@pytest.mark.parametrize("n", [2, 4])  # 2 divides the capacity (dynamic_update_slice), 4 does not (scatter)
def test_replay_wraps_around_and_samples_filled_rows(n):
  cap = 6
  spec = replay.make_transition_spec(observation_size=1, action_size=1)
  rows = lambda ids: replay.Transition(
      obs=ids[:, None], action=-ids[:, None], reward=ids, next_obs=ids[:, None] + 0.5,
      discount=jnp.ones_like(ids),
  )
  insert = jax.jit(replay.insert)
  sample = jax.jit(replay.sample, static_argnums=2)

  state = replay.init(cap, spec)
  assert int(state.size) == 0 and state.data.obs.shape == (cap, 1)
  state = insert(state, rows(jnp.arange(1.0, 1.0 + n)))  # ids 1..n
  assert int(state.size) == n and int(state.position) == n % cap
  s = sample(state, jax.random.PRNGKey(0), 500)
  assert set(np.asarray(s.reward).tolist()) == set(range(1, n + 1))  # only filled rows, all of them
  np.testing.assert_array_equal(s.action[:, 0], -s.reward)  # rows stay aligned across fields

  next_id = 1 + n
  for _ in range(5):  # keep inserting well past the capacity
    state = insert(state, rows(jnp.arange(next_id, next_id + n, dtype=jnp.float32)))
    next_id += n
  total = next_id - 1
  assert int(state.size) == cap and int(state.position) == total % cap
  # circular layout: id t lives in row (t - 1) % cap, and only the newest `cap` ids remain
  expect = np.zeros(cap)
  for t in range(total - cap + 1, total + 1):
    expect[(t - 1) % cap] = t
  np.testing.assert_array_equal(state.data.reward, expect)
  np.testing.assert_array_equal(state.data.next_obs[:, 0], expect + 0.5)
  s = sample(state, jax.random.PRNGKey(1), 2000)
  counts = np.bincount(np.asarray(s.reward, int) - (total - cap + 1), minlength=cap)
  assert counts.sum() == 2000 and len(counts) == cap and counts.min() > 250  # uniform over 6 rows

  # under vmap (a seed axis) the two paths give the same answer
  batched = jax.vmap(replay.insert)(
      jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), state),
      jax.tree_util.tree_map(lambda x: jnp.stack([x, x + 100]), rows(jnp.arange(1.0, 1.0 + n))),
  )
  single = replay.insert(state, rows(jnp.arange(1.0, 1.0 + n)))
  np.testing.assert_array_equal(batched.data.reward[0], single.data.reward)
  np.testing.assert_array_equal(batched.data.reward[1] - single.data.reward,
                                np.where(np.isin(np.arange(cap), (state.position + np.arange(n)) % cap), 100, 0))


def test_replay_rejects_oversized_insert():
  state = replay.init(3, replay.make_transition_spec(1, 1))
  big = jax.tree_util.tree_map(lambda x: jnp.zeros((4,) + x.shape), replay.make_transition_spec(1, 1))
  with pytest.raises(ValueError, match="capacity 3"):
    replay.insert(state, big)


def test_plugins_are_wired_into_the_training_step():
  """A plug-in's init and update carry its state, its reward sees it, its regulariser is scheduled."""
  cfg = SACConfig(hidden_sizes=(8,), batch_size=4, buffer_size=64, total_env_steps=20,
                  steps_per_chunk=10, learning_starts=4)
  seen_steps = []

  def aux_update(aux, transitions, env_steps, key):
    seen_steps.append(env_steps)  # traced once
    aux = {"count": aux["count"] + 1, "reward_sum": aux["reward_sum"] + transitions.reward.sum()}
    return aux, {"aux_count": aux["count"].astype(jnp.float32)}

  trainer = make_train(ENV, cfg, plugins=[Plugin(
      "custom",
      init=lambda key, agent, seed_index: (agent, {"count": jnp.zeros((), jnp.int32), "reward_sum": jnp.zeros(())}),
      update=aux_update,
      reward=lambda aux, batch: jnp.full_like(batch.reward, 3.0) + 0.0 * aux["reward_sum"],
      regularizer=lambda aux, params, obs: jnp.float32(2.0),
      schedule=lambda env_steps: 0.5 * jnp.ones(()),
  )])
  ts, m = jax.jit(trainer.run_chunk)(jax.jit(trainer.init)(jax.random.PRNGKey(0)))
  assert int(ts.aux["custom"]["count"]) == 10 and len(seen_steps) == 1
  np.testing.assert_allclose(float(ts.aux["custom"]["reward_sum"]), float(jnp.sum(ts.replay.data.reward)), rtol=1e-5)
  assert float(m["aux_count"]) == pytest.approx(5.5)  # mean of 1..10 over the chunk
  assert float(m["batch_reward"]) == pytest.approx(3.0)  # rewards recomputed at sample time
  assert float(m["custom"]) == pytest.approx(2.0)  # logged under the plug-in's name
  assert float(m["custom_weight"]) == pytest.approx(0.5)
  assert int(ts.agent.update_steps) == 10 - 4 + 1


_CACHE_SCRIPT = """
import dataclasses, sys
import jax, numpy as np
sys.path.insert(0, {tests!r})
import hdt.cache
from hdt.agents.sac import SACConfig
from hdt.agents.train import make_train, run
from toy_env import PointGoal
traces, compiles = [], []
jax.monitoring.register_event_duration_secs_listener(
    lambda name, secs, **kw: compiles.append(1) if name == "/jax/core/compile/backend_compile_duration" else None)
class Counted(PointGoal):
  def step(self, state, action):
    traces.append(1)  # Python runs only while tracing
    return super().step(state, action)
hdt.cache.enable_compile_cache({jax_dir!r})
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)  # the toy programs compile fast
env = Counted()
cfg = SACConfig(hidden_sizes=(32, 32), batch_size=32, buffer_size=2000, num_envs=2, learning_starts=50,
                total_env_steps=1000, steps_per_chunk=250, num_eval_episodes=2)
for key in {keys!r}:  # groups of programs in one process
  n, c = len(traces), len(compiles)
  res = run(env, cfg, [0], cache_key=key, trainer=make_train(env, cfg))
  print(key, "traced" if len(traces) > n else "loaded", "compiled" if len(compiles) > c else "no compile", flush=True)
  print("HISTORY", {{k: np.asarray(v).tolist() for k, v in res.history.items() if k != "walltime"}}, flush=True)
"""


def test_cached_programs_load_without_tracing(tmp_path):
  """With the compile cache on and a cache_key, run() saves its compiled programs; a later process
  with the same key loads them (the env is not traced again, nothing is compiled) and trains
  identically, for two groups of programs in one process. The programs are saved after a first process filled the persistent
  compile cache: one re-serialised from a cache hit lacked its kernels on XLA:CPU and failed at run
  time ("Function wrapped_slice not found"), so saved programs are compiled afresh."""
  import os
  import subprocess
  import sys
  both = ("toy point goal", "another env")

  def proc(aot, keys=both):
    script = _CACHE_SCRIPT.format(tests=os.path.dirname(__file__), jax_dir=str(tmp_path / "jax"), keys=keys)
    # two CPU devices, as the CLI makes on two cores: a loaded 1-device program must not expect two shards
    env = dict(os.environ, HDT_CACHE_DIR=str(tmp_path), HDT_AOT_CACHE=aot, JAX_NUM_CPU_DEVICES="2")
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    lines = out.stdout.splitlines()
    return [ln for ln in lines if ln.startswith(keys)], [ln for ln in lines if ln.startswith("HISTORY")]

  # fills the persistent compile cache; one group does, as both groups lower to the same programs
  plain, h_plain = proc("0", both[:1])
  assert plain == ["toy point goal traced compiled"] and not (tmp_path / "aot").exists()
  cold, h_cold = proc("1")
  assert cold == ["toy point goal traced compiled", "another env traced compiled"]
  assert len(list((tmp_path / "aot").glob("*.pkl"))) == 8  # init, run_chunk, evaluate, eval_keys per key
  warm, h_warm = proc("1")
  # a warm start neither traces nor compiles anything, eager ops included (seed and evaluation keys)
  assert warm == ["toy point goal loaded no compile", "another env loaded no compile"]
  assert h_warm == h_cold and h_cold[0] == h_plain[0]  # loaded programs train identically
