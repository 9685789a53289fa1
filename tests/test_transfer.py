"""Hierarchy and hand-off: LL/HL training, checkpoints, composition and zero-shot matrices."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hdt.transfer import checkpoint as ckpt
from hdt.transfer import configs
from hdt.transfer.evaluate import compose, evaluate, load_policy, random_actions, trajectory, zero_shot_matrix
from hdt.transfer.pipeline import high_env, low_policy_fn, train_low
from hdt.transfer.runner import RunOptions


# point_low, point_high: trained once per session (conftest.py)


def test_point_low_level_learns_goal_reaching(point_low):
  dist = point_low.history["eval/goal_dist"][0]  # mean distance to goal over evaluation episodes
  assert dist[-1] < dist[0] / 5, dist  # measured: 4.1 -> 0.4 after 4k steps


def test_checkpoint_round_trip(point_low):
  params, meta = ckpt.load(point_low.run_dir, 0)
  assert meta["level"] == "low" and meta["agent"] == "point" and meta["delta_max"] == 4.0
  obs = jax.random.normal(jax.random.PRNGKey(0), (32, meta["obs_size"]))
  act = low_policy_fn(meta["hidden_sizes"], meta["obs_size"], meta["action_size"])
  saved = act(params["policy"], obs)
  live = act(jax.tree.map(lambda x: x[0], point_low.params["policy"]), obs)
  np.testing.assert_array_equal(np.asarray(saved), np.asarray(live))
  for f in ("config.json", "meta.json", "metrics.csv"):
    assert (point_low.run_dir / f).exists()


def test_missing_and_corrupt_checkpoints_are_clear(point_low, tmp_path):
  with pytest.raises(ckpt.CheckpointError, match="does not exist"):
    ckpt.load(tmp_path / "nope")
  bad = tmp_path / "bad"
  (bad / "seed_0").mkdir(parents=True)
  (bad / "seed_0" / "meta.json").write_text("{not json")
  with pytest.raises(ckpt.CheckpointError, match="corrupt checkpoint metadata"):
    ckpt.load(bad)


def test_high_level_beats_random_high_level(point_low, point_high):
  trained = evaluate(compose(point_high.run_dir, point_low.run_dir), "waypoint", episodes=16)
  # A random HL: uniform sub-goals in the box, same LL, same episodes.
  env = high_env("waypoint", point_low.run_dir)

  def episode(key):
    s = env.reset(key)

    def f(c, k):
      s, ret, alive = c
      s = env.step(s, jax.random.uniform(k, (2,), minval=-1, maxval=1))
      return (s, ret + alive * s.reward, alive * (1 - s.done)), None
    return jax.lax.scan(f, (s, 0.0, 1.0), jax.random.split(key, env.horizon))[0][1]

  random_return = float(jnp.mean(jax.jit(jax.vmap(episode))(jax.random.split(jax.random.PRNGKey(5), 16))))
  assert trained["return_mean"] > random_return + 300, (trained["return_mean"], random_return)


def test_zero_shot_matrix_matches_direct_evaluation(point_low, point_high):
  m = zero_shot_matrix({"PM": point_high.run_dir}, {"PM": point_low.run_dir}, "waypoint", episodes=4)
  assert m["rows"] == ["PM"] and m["cols"] == ["PM"] and len(m["cells"]) == 1
  direct = evaluate(compose(point_high.run_dir, point_low.run_dir), "waypoint", episodes=4)
  mean, std, metric = m["cells"][("PM", "PM")]
  assert metric == "return" and mean == pytest.approx(direct["return_mean"]) and std == pytest.approx(direct["return_std"])


def test_trajectory_records_top_down_path(point_low, point_high):
  tr = trajectory(compose(point_high.run_dir, point_low.run_dir), "waypoint")
  assert tr["xy"].ndim == 2 and tr["xy"].shape[1] == 2 and len(tr["xy"]) > 50
  assert np.all(np.isfinite(tr["xy"]))


def test_composing_incompatible_levels_fails_clearly(point_low, point_high, tmp_path):
  cfg = configs.low_config("arm3", total_env_steps=200, num_envs=2, steps_per_chunk=100, batch_size=16,
                           buffer_size=1000, hidden_sizes=(16, 16), num_eval_episodes=2)
  arm = train_low("arm3", cfg, options=RunOptions(seeds=1, out=tmp_path / "arm_low", quiet=True))
  with pytest.raises(ValueError, match="goal spaces do not match"):
    compose(point_high.run_dir, arm.run_dir)
  with pytest.raises(ckpt.CheckpointError, match="compose needs an HL"):
    compose(point_low.run_dir, point_low.run_dir)


def test_save_to_relative_dir_and_killed_save_leaves_previous(tmp_path, monkeypatch):
  monkeypatch.chdir(tmp_path)
  tree = {"w": np.arange(6, dtype=np.float32).reshape(2, 3)}
  ckpt.save("rel_run", 0, tree, {"level": "low"})
  params, meta = ckpt.load("rel_run", 0)
  np.testing.assert_array_equal(params["w"], tree["w"])
  assert meta["level"] == "low"
  # A save interrupted between its two renames leaves seed_0.old: still loadable.
  (tmp_path / "rel_run" / "seed_0").rename(tmp_path / "rel_run" / "seed_0.old")
  params, _ = ckpt.load("rel_run", 0)
  np.testing.assert_array_equal(params["w"], tree["w"])


def test_uniform_actions_ignore_the_policy_and_draw_from_the_env_key():
  """hdt.random_actions: the actions come from the env's own key, whatever the policy would do."""
  policy = load_policy("zoo:point/low")
  zeroed = dataclasses.replace(policy, params=jax.tree.map(np.zeros_like, policy.params))
  kw = dict(episodes=2, seeds=[0], key=3)
  a, b = evaluate(random_actions(policy), **kw), evaluate(random_actions(zeroed), **kw)
  assert a["params"] == "uniform random actions"
  for k in a["per_seed"]:  # the policy's actions are ignored: another policy, the same episodes
    np.testing.assert_array_equal(a["per_seed"][k], b["per_seed"][k])
  own = evaluate(policy, **kw)["per_seed"]
  assert not np.allclose(own["goal_dist"], a["per_seed"]["goal_dist"])  # not the given actions


def test_sweep_trains_same_shape_points_together_and_writes_each_run(tmp_path):
  """sweep: two learning rates (one vmapped program) and another batch size (in turn); each
  grid point writes the run directory train_low writes, with the results of training it alone."""
  from hdt.transfer.sweep import sweep
  base = configs.low_config("point", total_env_steps=400, num_envs=2, steps_per_chunk=100, batch_size=16,
                            buffer_size=1000, learning_starts=100, num_eval_episodes=4)
  cfgs = [dataclasses.replace(base, actor_lr=lr, critic_lr=lr) for lr in (1e-4, 3e-4)]
  cfgs.append(dataclasses.replace(base, batch_size=32))
  runs = [(c, tmp_path / "sweep" / f"p{i}") for i, c in enumerate(cfgs)]
  results = sweep("low", runs, options=RunOptions(seeds=2, quiet=True), agent="point")
  alone = train_low("point", cfgs[1], options=RunOptions(seeds=2, out=tmp_path / "alone", quiet=True))
  hashed = {"tb", "d", "ocdbt.process_0"}  # event files and array shards named by time or content hash
  listing = lambda d: sorted(str(p.relative_to(d)) for p in d.rglob("*") if not hashed & set(p.relative_to(d).parts))
  for (cfg, out), res in zip(runs, results):
    assert res.run_dir == out and listing(out) == listing(alone.run_dir)
    assert ckpt.load_meta(out)["sac"]["actor_lr"] == cfg.actor_lr
    assert res.history["eval/return"].shape == alone.history["eval/return"].shape
  for k, v in alone.history.items():
    if k != "walltime":
      np.testing.assert_allclose(results[1].history[k], v, rtol=1e-4, atol=1e-5, equal_nan=True, err_msg=k)
  assert not np.allclose(results[0].history["critic_loss"], results[1].history["critic_loss"], rtol=1e-3)
