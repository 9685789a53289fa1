"""Discriminative LL alignment (paper Algorithm 1): discriminator, reward sign, schedules, plug-ins,
offline collection and the align_low entry point."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from hdt.agents import discriminator as D
from hdt.agents.replay import Transition
from hdt.transfer import configs
from hdt.transfer import checkpoint as ckpt
from hdt.transfer.align import AlignSpec, align_low, collect_offline, load_discriminator
from hdt.transfer.pipeline import load_low, train_low
from hdt.transfer.runner import RunOptions


def _taus(rng, n, speed, z=True):
  """Synthetic discriminator inputs: uniform g - s in the nav box, a step of ``speed`` toward the
  goal, and (with ``z``) the episode's sub-goal, here the start g - s itself."""
  d = rng.uniform(-4, 4, (n, 2)).astype(np.float32)
  norm = np.linalg.norm(d, axis=1, keepdims=True)
  return np.concatenate([d, d - np.minimum(speed, norm) * d / norm] + ([d] if z else []), 1)


def _np_reward(r, logit, env_steps, total, w0=0.3, start=200):
  """Independent reference of DSAC._train_step / _get_discrim_reward (discrim_decay=True): step is
  the loop index of the latest env step, D = sigmoid output = P(B)."""
  step = env_steps - 1
  w = max(w0 * (1.0 - step / total), 0.1)
  d = 1.0 / (1.0 + np.exp(-np.asarray(logit, np.float64)))
  bonus = np.clip(-2.0 * np.log(d + 1e-6), 0.0, 10.0)
  return (1.0 - w) * np.asarray(r) + (w * bonus if step > start else 0.0)


def _empty(n_in=6):
  obs = jnp.zeros((0, 2))
  return Transition(obs=obs, action=obs, reward=jnp.zeros(0), next_obs=obs, discount=jnp.zeros(0),
                    extras={"z": jnp.zeros((0, 2)), "first": jnp.zeros(0)})


def test_discriminator_separates_distributions():
  rng = np.random.default_rng(0)
  tau_a = _taus(rng, 4096, 0.05)  # A: slow
  tau_b = _taus(rng, 4096, 2.0)  # B: fast
  cfg = D.DiscConfig(lr=3e-3, stop=1.0, update_every=1, data="fixed")
  al = D.make_alignment(cfg, tau_a, total_env_steps=400, num_envs=1)
  aux = al.aux_init(jax.random.PRNGKey(0))
  buf = jnp.asarray(tau_b)
  aux = aux.replace(buf=aux.buf.at[: len(buf)].set(buf), size=jnp.int32(len(buf)))
  step = jax.jit(lambda aux, s, k: al.aux_update(aux, _empty(), s, k))
  for i in range(400):
    aux, m = step(aux, jnp.int32(i + 1), jax.random.PRNGKey(i + 1))
  held_a, held_b = _taus(rng, 2000, 0.05), _taus(rng, 2000, 2.0)
  acc = 0.5 * (np.mean(al.apply(aux.params, held_a) < 0) + np.mean(al.apply(aux.params, held_b) > 0))
  assert acc > 0.9, acc  # measured 0.99
  assert int(aux.opt_state.count) == 400


def test_reward_matches_authors_formula():
  """(1-w) r + [step > 200] w clip(-2 log(D + 1e-6), 0, 10), w = max(w0 (1 - step/T), 0.1)."""
  cfg = D.DiscConfig(weight=0.3)
  r = np.array([1.0, -2.0, 0.5, 3.0, 0.0], np.float32)
  logit = np.array([-20.0, -3.0, 0.0, 2.0, 9.0], np.float32)  # D from ~0 (clipped bonus) to ~1
  total = 10_000
  for env_steps in [1, 150, 201, 202, 203, 5000, 6668, 9000, 10_000]:
    got = D.shaped_reward(cfg, r, jax.nn.sigmoid(logit), env_steps - 1, total)
    np.testing.assert_allclose(np.asarray(got), _np_reward(r, logit, env_steps, total), rtol=1e-5,
                               atol=1e-5, err_msg=f"env_steps={env_steps}")
  # the gate: step 200 (the 201st env step) has no bonus, step 201 has it
  assert float(D.shaped_reward(cfg, 0.0, 1e-9, 200, total)) == 0.0
  assert float(D.shaped_reward(cfg, 0.0, 1e-9, 201, total)) == pytest.approx(10 * 0.3 * (1 - 201 / total))
  # w schedule, and constant w without decay
  w = lambda s, c=cfg: float(D.reward_weight(c, s, 1000))
  assert w(0) == pytest.approx(0.3) and w(500) == pytest.approx(0.15) and w(700) == pytest.approx(0.1)
  assert w(999) == pytest.approx(0.1)
  assert w(500, D.DiscConfig(weight=0.3, w_decay=False)) == pytest.approx(0.3)


def test_reward_fn_uses_env_step_counter():
  """The plug-in's reward_fn (what the SAC update calls on sampled batches) matches the reference."""
  cfg = D.DiscConfig(weight=0.4, data="fixed")
  rng = np.random.default_rng(3)
  al = D.make_alignment(cfg, _taus(rng, 64, 0.1), total_env_steps=1000, num_envs=4)
  aux = al.aux_init(jax.random.PRNGKey(0))
  x = _taus(rng, 8, 0.5)
  batch = Transition(obs=jnp.asarray(np.pad(x[:, :2], ((0, 0), (3, 0)))), action=jnp.zeros((8, 2)),
                     reward=jnp.asarray(rng.normal(size=8), jnp.float32),
                     next_obs=jnp.asarray(np.pad(x[:, 2:4], ((0, 0), (3, 0)))), discount=jnp.ones(8),
                     extras={"z": jnp.asarray(x[:, 4:]), "first": jnp.zeros(8)})
  logit = np.asarray(al.apply(aux.params, x))
  for env_steps in (100, 400):
    got = al.reward_fn(aux.replace(env_steps=jnp.int32(env_steps)), batch)
    np.testing.assert_allclose(np.asarray(got), _np_reward(batch.reward, logit, env_steps, 1000, 0.4),
                               rtol=1e-5, atol=1e-5)


def test_soft_label_mse_loss():
  """MSE between sigmoid outputs and the labels 0.95 (B, the agent) / 0.05 (A, the expert)."""
  net = D.Discriminator((8,))
  x = jnp.asarray(_taus(np.random.default_rng(0), 10, 0.3))
  params = net.init(jax.random.PRNGKey(0), x)
  labels = jnp.asarray([D.B_LABEL] * 5 + [D.A_LABEL] * 5)
  loss, acc = D.disc_loss(net.apply, params, x, labels)
  d = 1 / (1 + np.exp(-np.asarray(net.apply(params, x), np.float64)))
  want = np.mean((d - np.array([0.95] * 5 + [0.05] * 5)) ** 2)
  assert float(loss) == pytest.approx(want, rel=1e-5)
  assert float(acc) == pytest.approx(np.mean((d > 0.5) == np.array([True] * 5 + [False] * 5)))
  assert (D.B_LABEL, D.A_LABEL) == (0.95, 0.05)


def test_discriminator_input_contains_z():
  """x = (g - s_t, g - s_{t+1}, z), z taken from the transition's extras (the episode's sub-goal)."""
  obs, nxt, z = jnp.arange(5.0)[None], 10 + jnp.arange(5.0)[None], jnp.array([[7.0, -7.0]])
  np.testing.assert_array_equal(D.disc_input(obs, nxt, z), [[3, 4, 13, 14, 7, -7]])
  cfg = D.DiscConfig(data="fixed")
  assert cfg.include_z and cfg.input_size == 6
  al = D.make_alignment(cfg, _taus(np.random.default_rng(1), 32, 0.1), total_env_steps=64, num_envs=1)
  assert al.transition_extras is D.z_extras and al.plugin.transition_extras is D.z_extras
  aux = al.aux_init(jax.random.PRNGKey(0))
  tr = Transition(obs=obs, action=jnp.zeros((1, 2)), reward=jnp.zeros(1), next_obs=nxt,
                  discount=jnp.ones(1), extras={"z": z, "first": jnp.ones(1)})
  aux, _ = al.aux_update(aux, tr, jnp.int32(1), jax.random.PRNGKey(1))
  np.testing.assert_array_equal(aux.buf[0], [3, 4, 13, 14, 7, -7])
  # the reward depends on z
  r1 = al.reward_fn(aux.replace(env_steps=jnp.int32(500)), tr)
  r2 = al.reward_fn(aux.replace(env_steps=jnp.int32(500)), tr.replace(extras={"z": -z, "first": jnp.ones(1)}))
  assert float(r1[0]) != float(r2[0])


def test_aux_update_buffer_and_update_cadence_vmapped():
  """num_envs=4 and update_every=8: one discriminator update every other training step (at env step
  indices 0, 8, ...) while step < stop T, per seed; the circular buffer wraps."""
  cfg = D.DiscConfig(update_every=8, buffer_size=10, stop=0.5, lr=1e-2, batch_size=4, data="fixed")
  tau_a = _taus(np.random.default_rng(1), 32, 0.1)
  al = D.make_alignment(cfg, tau_a, total_env_steps=64, num_envs=4)
  seeds = 2
  aux = jax.vmap(al.aux_init)(jax.random.split(jax.random.PRNGKey(0), seeds))
  upd = jax.jit(jax.vmap(al.aux_update, in_axes=(0, 0, None, 0)))
  params0 = aux.params
  for t in range(1, 17):
    obs = jnp.full((seeds, 4, 5), float(t))
    tr = Transition(obs=obs, action=jnp.zeros((seeds, 4, 2)), reward=jnp.zeros((seeds, 4)),
                    next_obs=obs + 1, discount=jnp.ones((seeds, 4)),
                    extras={"z": jnp.full((seeds, 4, 2), -float(t)), "first": jnp.zeros((seeds, 4))})
    aux, m = upd(aux, tr, jnp.int32(4 * t), jax.random.split(jax.random.PRNGKey(t), seeds))
    # updates at step indices 0, 8, 16, 24 (< stop T = 32); the buffer holds >= batch_size / 2 rows
    want = len([s for s in range(0, 4 * t, 8) if s < 32 and 2 * min(4 * (s // 4 + 1), 10) >= 4])
    assert np.all(np.asarray(aux.opt_state.count) == want), (t, aux.opt_state.count, want)
  assert np.all(np.asarray(aux.size) == 10) and np.all(np.asarray(aux.ptr) == 64 % 10)
  # the buffer holds the last 10 inputs (steps 14..16), each (t, t, t+1, t+1, -t, -t)
  held = np.sort(np.asarray(aux.buf[0, :, 0]))
  np.testing.assert_array_equal(held, [14, 14, 15, 15, 15, 15, 16, 16, 16, 16])
  np.testing.assert_array_equal(np.asarray(aux.buf[0, :, 2]) - 1, np.asarray(aux.buf[0, :, 0]))
  np.testing.assert_array_equal(np.asarray(aux.buf[0, :, 4]), -np.asarray(aux.buf[0, :, 0]))
  assert np.asarray(aux.env_steps).tolist() == [64, 64]
  # lr schedule: lr (1 - step / (stop T)), 0 from stop T on
  assert float(D.disc_lr(cfg, 16, 64)) == pytest.approx(0.5 * 1e-2) and float(D.disc_lr(cfg, 40, 64)) == 0.0
  changed = jax.tree.leaves(jax.tree.map(lambda a, b: bool(jnp.any(a != b)), aux.params, params0))
  assert any(changed)
  assert np.all(np.isfinite(np.asarray(m["disc/loss"])))


def test_every_nth_episode_is_held_out_to_measure_accuracy_only():
  """DSAC.learn: the rows of every discrim_test_data_collection_freq-th episode (1-based count) go to a
  test buffer that no update samples; its accuracy is logged as disc/test_acc."""
  cfg = D.DiscConfig(test_every=2, update_every=1, buffer_size=100, batch_size=4, lr=1e-2, data="fixed")
  al = D.make_alignment(cfg, _taus(np.random.default_rng(1), 32, 0.1), total_env_steps=1000, num_envs=2)
  aux, upd = al.aux_init(jax.random.PRNGKey(0)), jax.jit(al.aux_update)
  for t in range(12):  # env 0: episodes of 3 steps; env 1: of 4 steps; each row is tagged with t
    first = jnp.array([t % 3 == 0, t % 4 == 0], jnp.float32)
    obs = jnp.stack([jnp.full((5,), 10.0 * t), jnp.full((5,), 10.0 * t + 1)])
    tr = Transition(obs=obs, action=jnp.zeros((2, 2)), reward=jnp.zeros(2), next_obs=obs, discount=jnp.ones(2),
                    extras={"z": jnp.zeros((2, 2)), "first": first})
    aux, m = upd(aux, tr, jnp.int32(2 * (t + 1)), jax.random.PRNGKey(t))
  # env 0's episodes 2 and 4 (t 3-5, 9-11), env 1's episode 2 (t 4-7) are held out
  held = sorted([10 * t for t in (3, 4, 5, 9, 10, 11)] + [10 * t + 1 for t in (4, 5, 6, 7)])
  kept = sorted(set(10 * t + e for t in range(12) for e in (0, 1)) - set(held))
  assert sorted(np.asarray(aux.tbuf[: int(aux.tsize), 0]).tolist()) == held
  assert sorted(np.asarray(aux.buf[: int(aux.size), 0]).tolist()) == kept
  assert int(aux.ptr) == len(kept) and int(aux.tptr) == len(held)
  assert 0.0 <= float(m["disc/test_acc"]) <= 1.0  # a held-out batch exists by now
  # test_every=0: every row trains, as before
  al0 = D.make_alignment(dataclasses.replace(cfg, test_every=0), _taus(np.random.default_rng(1), 32, 0.1),
                         total_env_steps=1000, num_envs=2)
  aux0, m0 = jax.jit(al0.aux_update)(al0.aux_init(jax.random.PRNGKey(0)), tr, jnp.int32(2), jax.random.PRNGKey(0))
  assert aux0.tbuf is None and "disc/test_acc" not in m0 and int(aux0.size) == 2


# A: the point LL trained once per session (point_low, conftest.py).


def test_collect_offline_gives_goal_space_taus(point_low):
  tau = collect_offline(point_low.run_dir, 300, jax.random.PRNGKey(0), num_envs=16)
  assert tau.shape == (300, 6) and np.all(np.isfinite(tau))
  # goals are uniform in the +-4 box around the start, and one step moves the point a little
  assert np.max(np.abs(tau[:16, :2])) <= 4.0 + 1e-3 and np.std(tau[:, 0]) > 0.5
  assert np.median(np.linalg.norm(tau[:, :2] - tau[:, 2:4], axis=1)) < 1.0
  # z is the episode's relative goal: at each episode start (the first 16 rows) g - s_0 = z
  np.testing.assert_allclose(tau[:16, :2], tau[:16, 4:], atol=1e-5)
  assert np.max(np.abs(tau[:, 4:])) <= 4.0


def test_align_low_end_to_end_and_meta(point_low, tmp_path):
  cfg = configs.low_config("point", total_env_steps=400, num_envs=4, steps_per_chunk=100, batch_size=16,
                           buffer_size=1000, hidden_sizes=(16, 16), num_eval_episodes=2)
  spec = AlignSpec(point_low.run_dir, D.DiscConfig(buffer_size=500, data="fixed"), n_offline=256)
  res = align_low("point", spec, cfg, options=RunOptions(seeds=1, out=tmp_path / "aligned", quiet=True))
  meta = json.loads((tmp_path / "aligned" / "meta.json").read_text())
  assert meta["level"] == "low" and meta["aligned_to"]["agent"] == "point"
  assert meta["aligned_to"]["path"] == str(point_low.run_dir) and meta["discriminator"]["weight"] == 0.3
  w = res.history["disc/weight"]
  assert w.shape == (1, 1) and 0.1 < w[0, 0] < 0.3  # chunk mean of the annealed weight
  assert meta["discriminator"]["data"] == "fixed" and meta["aligned_to"]["n_offline"] == 256
  assert np.all(np.isfinite(res.history["disc/loss"]))

  # The discriminator is saved with the LL (inspect / resume the alignment) and reloads exactly.
  logit, card = load_discriminator(tmp_path / "aligned")
  assert card.aligned_to.tau_scale == 1.0  # the authors feed raw goal-space units
  tau = collect_offline(point_low.run_dir, 64, jax.random.PRNGKey(3), num_envs=16)
  disc = D.Discriminator(tuple(card.extra["discriminator"]["hidden_sizes"]))
  want = disc.apply(jax.tree.map(lambda x: x[0], res.params["discriminator"]), tau)
  np.testing.assert_allclose(np.asarray(logit(tau)), np.asarray(want), rtol=1e-5, atol=1e-6)
  assert load_low(tmp_path / "aligned")[1].level == "low"  # still an ordinary LL checkpoint
  with pytest.raises(ckpt.CheckpointError, match="no discriminator"):
    load_discriminator(point_low.run_dir)


def test_align_low_online_runs_and_a_follows_b_goals(point_low, tmp_path, monkeypatch):
  """Online data (DiscriminatorEnv): A's frozen LL runs in A's reach env next to each B env and is
  given B's relative goal z whenever B's episode gets a new goal; A's inputs are written in lockstep
  with B's, so row i of both buffers carries the same z."""
  from hdt.transfer import align as align_mod
  captured = {}
  real_run = align_mod.run_stage

  def spy(stage, options):
    res = real_run(stage, options)
    captured["stage"] = stage
    return res

  monkeypatch.setattr(align_mod, "run_stage", spy)
  # B's LL episodes last 20 steps (A's 32, the README's --discrim-time-limit), so B's new goals drive A's restarts
  cfg = configs.low_config("point", total_env_steps=200, num_envs=4, steps_per_chunk=50, batch_size=16,
                           buffer_size=1000, hidden_sizes=(16, 16), num_eval_episodes=2)
  spec = AlignSpec(point_low.run_dir, D.DiscConfig(data="online", buffer_size=500, update_every=1))
  res = align_low("point", spec, cfg, options=RunOptions(seeds=1, out=tmp_path / "online", quiet=True), ll_horizon=20)
  assert np.all(np.isfinite(res.history["disc/loss"]))
  meta = json.loads((tmp_path / "online" / "meta.json").read_text())
  assert meta["discriminator"]["data"] == "online" and meta["aligned_to"]["n_offline"] == 0
  assert any(p.transition_extras is not None for p in captured["stage"].plugins)

  # Replay the training state: A's and B's buffers, row by row, hold the same z
  from hdt.transfer import checkpoint as ck
  info = ck.load_state_info(tmp_path / "online")
  assert info["env_steps"] == 200
  import orbax.checkpoint as ocp
  arrays = ocp.PyTreeCheckpointer().restore(ck.state_dir(tmp_path / "online").resolve() / "arrays")
  leaves = {name: np.asarray(arrays["state"][f"{i:05d}"]) for i, (name, _, _) in enumerate(info["leaves"])}
  buf_b, buf_a = leaves[".aux['discriminator'].buf"][0, :200], leaves[".aux['discriminator'].buf_a"][0, :200]
  np.testing.assert_array_equal(buf_a[:, 4:], buf_b[:, 4:])
  assert len(np.unique(buf_b[:, 4], axis=0)) > 4  # several goals, not one
  # A's final goal is B's current relative goal, for B envs that did not just start a new episode
  z_b = leaves[".env_state.task['t']['z']"][0]
  z_a = leaves[".aux['discriminator'].a_state.task['t']['z']"][0]
  steps_b = leaves[".env_state.task['steps']"][0]
  mid = steps_b > 0
  assert mid.any()
  np.testing.assert_array_equal(z_a[mid], z_b[mid])


def _alongside_state(imitate, tmp_path, data, agent="point", **disc_kw):
  """(A's and B's replay rows, env leaves) of a tiny alignment with A alongside B."""
  import orbax.checkpoint as ocp

  from hdt.transfer import checkpoint as ck
  cfg = configs.low_config(agent, total_env_steps=240, num_envs=4, steps_per_chunk=60, batch_size=16,
                           buffer_size=1000, hidden_sizes=(16, 16), num_eval_episodes=2)
  spec = AlignSpec(getattr(imitate, "run_dir", imitate),
                   D.DiscConfig(data=data, buffer_size=500, update_every=1, **disc_kw))
  align_low(agent, spec, cfg, options=RunOptions(seeds=1, out=tmp_path / data, quiet=True), ll_horizon=50)
  info = ck.load_state_info(tmp_path / data)
  arrays = ocp.PyTreeCheckpointer().restore(ck.state_dir(tmp_path / data).resolve() / "arrays")
  return {name: np.asarray(arrays["state"][f"{i:05d}"])[0] for i, (name, _, _) in enumerate(info["leaves"])}


def _chain_breaks(leaves):
  """The steps where A's row does not begin where its previous row ended (row t's g - s_t against row
  t-1's g - s_t+1), from :func:`_alongside_state`'s 240 steps of 4 B envs."""
  rows = leaves[".aux['discriminator'].buf_a"][:240].reshape(60, 4, -1)
  gap = np.abs(rows[1:, :, :2] - rows[:-1, :, 2:4]).max(axis=(1, 2))
  return [int(t) + 1 for t in np.flatnonzero(gap > 1e-5)]


def test_authors_offline_mode_starts_a_on_its_own_goal_then_follows_b(point_low, tmp_path):
  """DiscriminatorEnv with discrim_online=False (the README's alignment): at B's new goal A resets on a
  random goal of its own; after A's time limit (here 10 steps) it restarts on B's current z. A's rows
  carry B's z throughout (DSAC.learn labels both classes with the agent's skill)."""
  leaves = _alongside_state(point_low, tmp_path, "offline", expert_time_limit=10)
  buf_b, buf_a = leaves[".aux['discriminator'].buf"][:240], leaves[".aux['discriminator'].buf_a"][:240]
  np.testing.assert_array_equal(buf_a[:, 4:], buf_b[:, 4:])  # B's z on A's rows
  steps_b = leaves[".env_state.task['steps']"]
  z_a, z_b = leaves[".aux['discriminator'].a_state.task['t']['z']"], leaves[".env_state.task['t']['z']"]
  # 240 steps / 4 envs = 60 steps per env: B's episodes (50) restarted at step 50; A ran 10 steps on its
  # own goal, then restarted on B's z at its time limit
  assert np.all(steps_b == 10) and np.array_equal(z_a, z_b)
  # ... and in the first 10 steps of each of B's episodes, A's goal was its own: A's tau g - s starts at
  # its own z, not at B's (row 0 of each env: B's episode start)
  first = buf_a[:4]
  assert not np.allclose(first[:, :2], first[:, 4:], atol=1e-3)
  # prev_expert_obs is set before A's own restart: A's rows chain across it, B's episode start begins afresh
  assert _chain_breaks(leaves) == [50]
  online = _alongside_state(point_low, tmp_path, "online", expert_time_limit=10)
  np.testing.assert_allclose(online[".aux['discriminator'].buf_a"][:4, :2], online[".aux['discriminator'].buf_a"][:4, 4:], atol=1e-5)


def test_expert_prev_obs_post_restart_begins_a_row_afresh_after_a_own_restart(point_low, tmp_path):
  """DiscriminatorEnv.step sets prev_expert_obs before ``expert_env.reset()``, so A's row after its own
  restart begins at its old episode's last observation (the default, checked in the offline test
  above); ``expert_prev_obs="post_restart"`` (an older hdt default) begins it at the fresh one."""
  assert D.DiscConfig().expert_prev_obs == "pre_restart"
  leaves = _alongside_state(point_low, tmp_path, "offline", expert_time_limit=10, expert_prev_obs="post_restart")
  assert _chain_breaks(leaves) == [10, 20, 30, 40, 50]
  with pytest.raises(ValueError, match="expert_prev_obs='x' must be 'pre_restart' or 'post_restart'"):
    D.DiscConfig(expert_prev_obs="x")


def test_align_low_rejects_other_goal_space(point_low):
  with pytest.raises(ValueError, match="goal spaces differ"):
    align_low("arm3", imitate=point_low.run_dir, options=RunOptions(quiet=True))


def _energy_distance(x, y):
  """Energy distance 2E|X-Y| - E|X-X'| - E|Y-Y'| between two samples (0 iff same distribution)."""
  d = lambda u, v: np.mean(np.linalg.norm(u[:, None] - v[None], axis=-1))
  return 2 * d(x, y) - d(x, x) - d(y, y)


@pytest.mark.xfail(strict=True, reason=(
    "not shown on the authors' 26.8 kg ball at this toy budget: mean energy distance over 3 seeds, plain vs "
    "aligned, 0.0137 vs 0.0178 at 4k steps and 0.0332 vs 0.0317 at 12k; one seed passed by -15% before the "
    "critics' biases were initialised at 0, and failed by -5% after"))
def test_alignment_moves_b_taus_towards_a(tmp_path):
  """B = point mass with 3x actuator gear; its goal-space taus, aligned to A (the normal
  point mass, LL trained 3000 steps), are closer to A's than B's plain LL's taus, by energy distance
  on tau / delta_max averaged over 3 seeds of each B (one seed's margin moves with any change of the
  random streams). Same budget (4000 steps) for both B's; the alignment weight is a constant 0.5
  (DSAC's default discrim_weight), the authors' reward (1-w) r + w clip(-2 log D)."""
  small = lambda steps: configs.low_config(
      "point", total_env_steps=steps, num_envs=8, updates_per_step=8, steps_per_chunk=steps // 8,
      batch_size=64, buffer_size=5000, hidden_sizes=(32, 32), num_eval_episodes=2)
  a = train_low("point", small(3000), options=RunOptions(seeds=1, out=tmp_path / "a", quiet=True))
  plain = train_low("point", small(4000), options=RunOptions(seeds=3, out=tmp_path / "plain", quiet=True),
                    gear_scale=3.0)
  disc = D.DiscConfig(weight=0.5, w_decay=False, lr=1e-3, buffer_size=5000, data="fixed")
  aligned = train_low("point", small(4000), imitate=AlignSpec(a.run_dir, disc),
                      options=RunOptions(seeds=3, out=tmp_path / "al", quiet=True), gear_scale=3.0)
  taus = lambda run, i: collect_offline(run.run_dir, 1024, jax.random.PRNGKey(5), num_envs=64, include_z=False,
                                        seed_index=i) / 4.0
  tau_a = taus(a, 0)
  e_plain, e_aligned = (np.mean([_energy_distance(taus(r, i), tau_a) for i in range(3)]) for r in (plain, aligned))
  assert e_aligned < 0.95 * e_plain, (e_plain, e_aligned)


def test_align_imitates_a_best_by_default(point_low, tmp_path, monkeypatch):
  """The authors' DiscriminatorEnv loads the imitated LL with best=True; align_low records which."""
  from test_finetune import with_distinct_best
  from hdt.transfer import align as al
  a = with_distinct_best(point_low.run_dir, tmp_path / "a")
  cfg = configs.low_config("point", total_env_steps=400, num_envs=4, steps_per_chunk=100, batch_size=16,
                           buffer_size=1000, hidden_sizes=(16, 16), num_eval_episodes=2)
  key = jax.random.PRNGKey(0)
  taus = {w: collect_offline(a, 64, key, num_envs=16, which=w) for w in ("best", "final")}
  assert not np.allclose(taus["best"], taus["final"])  # the two really act differently
  real_inputs = al._policy_inputs  # A's "fixed" data, from the LL align_stage loaded once
  for kw, want in [({}, "best"), ({"imitate_params": "final"}, "final")]:
    got = {}
    monkeypatch.setattr(al, "_policy_inputs", lambda *a_, **k: got.update(tau=real_inputs(*a_, **k)) or got["tau"])
    monkeypatch.setattr(al, "run_stage", lambda stage, options: got.update(meta=stage.card.to_json()))
    align_low("point", AlignSpec(a, D.DiscConfig(buffer_size=500, data="fixed"), n_offline=64, **kw), cfg,
              options=RunOptions(seeds=1, quiet=True))
    np.testing.assert_array_equal(got["tau"], collect_offline(a, 64, key, num_envs=64, which=want))
    rec = got["meta"]["aligned_to"]
    assert rec["params"] == want and (want == "final" or rec["params_env_steps"] == 7)


def test_a_restarts_from_its_hl_start_after_its_own_episode_ends():
  """DiscriminatorEnv.step: ``expert_env.reset()`` (low=False) when A's episode ends, so A (here the
  manipulation point mass) restarts at its HL start, (0.2, 0) +- 0.05 beyond the block, not at its LL
  start, (0, 0) +- 0.05; ``expert_restart="low"`` keeps the LL start."""
  import hdt.envs as E
  env = E.make("arm_point", "reach")
  keys = jax.random.split(jax.random.PRNGKey(0), 64)
  s = jax.vmap(env.reset)(keys)
  z = jnp.zeros((64, 2))

  def tips(hl):
    r = jax.vmap(lambda s, z: D.restart_on_z(env, s, z, jnp.bool_(True), jnp.bool_(True), hl))(s, z)
    return np.asarray(jax.vmap(env.quantities)(r.physics)["point"])
  hl, ll = tips(True), tips(False)
  assert np.all(np.abs(hl - [0.2, 0.0]) <= 0.05 + 1e-6), hl
  assert np.all(np.abs(ll) <= 0.05 + 1e-6), ll
  assert np.std(hl, axis=0).min() > 0.01  # a fresh draw per env
  assert D.DiscConfig().expert_restart == "high"
  with pytest.raises(ValueError, match="expert_restart='mid' must be 'high' or 'low'"):
    D.DiscConfig(expert_restart="mid")


def test_alongside_b_a_restarts_at_its_hl_start_when_its_time_limit_ends(tmp_path):
  """The manipulation point mass (zoo LL) as A: 60 steps per env, B's episodes of 50, A's of 10 steps.
  A restarted at its LL start with B's episode at step 50 and, at its time limit after step 60, at its
  HL start, where the run ends."""
  leaves = _alongside_state("zoo:arm_point/low", tmp_path, "offline", agent="arm_point", expert_time_limit=10)
  assert np.all(leaves[".aux['discriminator'].a_state.task['steps']"] == 0)
  qpos = leaves[".aux['discriminator'].a_state.physics.qpos"][:, :2]  # the PM's slides: its position
  assert np.all(np.abs(qpos - [0.2, 0.0]) <= 0.05 + 1e-6), qpos
