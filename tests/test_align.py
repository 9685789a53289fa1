"""Discriminative LL alignment (paper Algorithm 1): discriminator, reward sign, schedules, plug-ins,
offline collection and the align_low entry point."""

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
from hdt.transfer.align import align_low, collect_offline, load_discriminator
from hdt.transfer.pipeline import load_low, train_low


def _taus(rng, n, speed):
  """Synthetic goal-space taus: uniform g - s in the nav box, a step of ``speed`` toward the goal."""
  d = rng.uniform(-4, 4, (n, 2)).astype(np.float32)
  norm = np.linalg.norm(d, axis=1, keepdims=True)
  return np.concatenate([d, d - np.minimum(speed, norm) * d / norm], 1)


def test_discriminator_separates_distributions():
  rng = np.random.default_rng(0)
  tau_a = _taus(rng, 4096, 0.05)  # A: slow
  tau_b = _taus(rng, 4096, 2.0)  # B: fast
  cfg = D.DiscConfig(lr=3e-3, stop=1.0)
  al = D.make_alignment(cfg, tau_a, total_env_steps=400 * cfg.update_every, num_envs=cfg.update_every,
                        tau_scale=4.0)
  aux = al.aux_init(jax.random.PRNGKey(0))
  buf = jnp.asarray(tau_b)
  aux = dict(aux, buf=aux["buf"].at[: len(buf)].set(buf), size=jnp.int32(len(buf)))
  obs = jnp.zeros((0, 2))
  empty = Transition(obs=obs, action=obs, reward=jnp.zeros(0), next_obs=obs, discount=jnp.zeros(0))
  step = jax.jit(lambda aux, s, k: al.aux_update(aux, empty, s, k))
  for i in range(400):
    aux, m = step(aux, jnp.int32((i + 1) * cfg.update_every), jax.random.PRNGKey(i + 1))
  held_a, held_b = _taus(rng, 2000, 0.05), _taus(rng, 2000, 2.0)
  acc = 0.5 * (np.mean(al.apply(aux["params"], held_a) < 0) + np.mean(al.apply(aux["params"], held_b) > 0))
  assert acc > 0.9, acc  # measured 0.99
  assert int(aux["opt_state"][0].count) == 400


def test_reward_sign_and_weight_schedule():
  r = jnp.zeros(3)
  logits = jnp.array([-5.0, 0.0, 5.0])  # q(B|tau) low (looks like A), 0.5, high (clearly B)
  shaped = D.shaped_reward(r, logits, 0.3, clip=10.0)
  # r - w log q(B): a bonus >= 0, largest when tau looks like A's
  np.testing.assert_allclose(shaped, -0.3 * np.log(1 / (1 + np.exp(-np.asarray(logits)))), rtol=1e-5)
  assert shaped[0] > shaped[1] > shaped[2] >= 0
  assert float(shaped[1]) == pytest.approx(0.3 * np.log(2), rel=1e-5)
  assert float(D.shaped_reward(0.0, -1e4, 1.0, clip=10.0)) == pytest.approx(10.0)  # clipped

  cfg = D.DiscConfig(w_init=0.3, w_final=0.1, w_frac=0.9)
  w = lambda s: float(D.reward_weight(cfg, s, 1000))
  assert w(0) == pytest.approx(0.3)
  assert w(450) == pytest.approx(0.2)
  assert w(900) == pytest.approx(0.1) and w(950) == pytest.approx(0.1) and w(1000) == pytest.approx(0.1)


def test_aux_update_buffer_and_update_cadence_vmapped():
  """num_envs=4 and update_every=8: one discriminator update every other training step, per seed;
  the circular buffer wraps; the lr schedule reaches 0 at `stop`."""
  cfg = D.DiscConfig(update_every=8, buffer_size=10, stop=0.5, lr=1e-2, batch_size=4)
  tau_a = _taus(np.random.default_rng(1), 32, 0.1)
  al = D.make_alignment(cfg, tau_a, total_env_steps=64, num_envs=4)
  seeds = 2
  aux = jax.vmap(al.aux_init)(jax.random.split(jax.random.PRNGKey(0), seeds))
  upd = jax.jit(jax.vmap(al.aux_update, in_axes=(0, 0, None, 0)))
  params0 = aux["params"]
  for t in range(1, 17):
    obs = jnp.full((seeds, 4, 5), float(t))
    tr = Transition(obs=obs, action=jnp.zeros((seeds, 4, 2)), reward=jnp.zeros((seeds, 4)),
                    next_obs=obs + 1, discount=jnp.ones((seeds, 4)))
    aux, m = upd(aux, tr, jnp.int32(4 * t), jax.random.split(jax.random.PRNGKey(t), seeds))
    assert np.all(np.asarray(aux["opt_state"][0].count) == (4 * t) // 8)
  assert np.all(np.asarray(aux["size"]) == 10) and np.all(np.asarray(aux["ptr"]) == 64 % 10)
  # the buffer holds the last 10 taus (steps 14..16), each (t, t, t+1, t+1)
  held = np.sort(np.asarray(aux["buf"][0, :, 0]))
  np.testing.assert_array_equal(held, [14, 14, 15, 15, 15, 15, 16, 16, 16, 16])
  np.testing.assert_array_equal(np.asarray(aux["buf"][0, :, 2]) - 1, np.asarray(aux["buf"][0, :, 0]))
  assert np.asarray(aux["env_steps"]).tolist() == [64, 64]
  # lr schedule: 8 updates in total, lr annealed to 0 after stop*8 = 4 updates
  sched = optax.linear_schedule(cfg.lr, 0.0, 4)
  assert float(sched(4)) == 0.0
  changed = jax.tree.leaves(jax.tree.map(lambda a, b: bool(jnp.any(a != b)), aux["params"], params0))
  assert any(changed)
  assert np.all(np.isfinite(np.asarray(m["disc/loss"])))


@pytest.fixture(scope="module")
def tiny_low(tmp_path_factory):
  """An (almost untrained) point LL checkpoint: enough to exercise collection and alignment."""
  out = tmp_path_factory.mktemp("runs") / "pm_low"
  cfg = configs.low_config("point", total_env_steps=400, num_envs=4, steps_per_chunk=100, batch_size=16,
                           buffer_size=1000, hidden_sizes=(16, 16), num_eval_episodes=2)
  return train_low("point", cfg, seeds=1, out=out, quiet=True)


def test_collect_offline_gives_goal_space_taus(tiny_low):
  tau = collect_offline(tiny_low.run_dir, 300, jax.random.PRNGKey(0), num_envs=16)
  assert tau.shape == (300, 4) and np.all(np.isfinite(tau))
  # goals are uniform in the +-4 box around the start, and one step moves the point a little
  assert np.max(np.abs(tau[:16, :2])) <= 4.0 + 1e-3 and np.std(tau[:, 0]) > 0.5
  assert np.median(np.linalg.norm(tau[:, :2] - tau[:, 2:], axis=1)) < 1.0


def test_align_low_end_to_end_and_meta(tiny_low, tmp_path):
  cfg = configs.low_config("point", total_env_steps=400, num_envs=4, steps_per_chunk=100, batch_size=16,
                           buffer_size=1000, hidden_sizes=(16, 16), num_eval_episodes=2)
  res = align_low("point", imitate=tiny_low.run_dir, config=cfg, disc=D.DiscConfig(buffer_size=500),
                  seeds=1, out=tmp_path / "aligned", n_offline=256, quiet=True)
  meta = json.loads((tmp_path / "aligned" / "meta.json").read_text())
  assert meta["level"] == "low" and meta["aligned_to"]["agent"] == "point"
  assert meta["aligned_to"]["path"] == str(tiny_low.run_dir) and meta["discriminator"]["w_init"] == 0.3
  w = res.history["disc/w"]
  assert w.shape == (1, 1) and 0.1 < w[0, 0] < 0.3  # chunk mean of the annealed weight
  assert np.all(np.isfinite(res.history["disc/loss"]))

  # The discriminator is saved with the LL (inspect / resume the alignment) and reloads exactly.
  logit, m = load_discriminator(tmp_path / "aligned")
  assert m["aligned_to"]["tau_scale"] == 4.0
  tau = collect_offline(tiny_low.run_dir, 64, jax.random.PRNGKey(3), num_envs=16)
  disc = D.Discriminator(tuple(m["discriminator"]["hidden_sizes"]))
  want = disc.apply(jax.tree.map(lambda x: x[0], res.params["discriminator"]), tau / 4.0)
  np.testing.assert_allclose(np.asarray(logit(tau)), np.asarray(want), rtol=1e-5, atol=1e-6)
  assert load_low(tmp_path / "aligned")[1]["level"] == "low"  # still an ordinary LL checkpoint
  with pytest.raises(ckpt.CheckpointError, match="no discriminator"):
    load_discriminator(tiny_low.run_dir)


def test_align_low_rejects_other_goal_space(tiny_low):
  with pytest.raises(ValueError, match="goal spaces differ"):
    align_low("arm3", imitate=tiny_low.run_dir, quiet=True)


def _energy_distance(x, y):
  """Energy distance 2E|X-Y| - E|X-X'| - E|Y-Y'| between two samples (0 iff same distribution)."""
  d = lambda u, v: np.mean(np.linalg.norm(u[:, None] - v[None], axis=-1))
  return 2 * d(x, y) - d(x, x) - d(y, y)


def test_alignment_moves_b_taus_towards_a(tmp_path):
  """Issue 5: B = point mass with 3x actuator gear; its goal-space taus, aligned to A (the normal
  point mass, LL trained 3000 steps), are closer to A's than B's plain LL's taus, by energy distance
  on tau / delta_max. Same budget (4000 steps) for both B's; the alignment weight is raised to 2 (the
  paper's 0.3 is too weak for 4000 steps to show against the progress reward).
  Measured (fixed seeds): plain 0.085, aligned 0.073 (-15%); mean |s_t+1 - s_t| / delta_max: A 0.036,
  plain B 0.088, aligned B 0.104, i.e. the gain is in direction, not yet in speed. With an untrained A
  (400 steps) and 2000 steps for B the order was reversed (plain 0.117, aligned 0.150)."""
  small = lambda steps: configs.low_config(
      "point", total_env_steps=steps, num_envs=8, updates_per_step=8, steps_per_chunk=steps // 8,
      batch_size=64, buffer_size=5000, hidden_sizes=(32, 32), num_eval_episodes=2)
  a = train_low("point", small(3000), seeds=1, out=tmp_path / "a", quiet=True)
  plain = train_low("point", small(4000), seeds=1, out=tmp_path / "plain", quiet=True, gear_scale=3.0)
  aligned = train_low("point", small(4000), seeds=1, out=tmp_path / "al", quiet=True, gear_scale=3.0,
                      imitate=a.run_dir, disc=D.DiscConfig(w_init=2.0, w_final=2.0, lr=1e-3, buffer_size=5000))
  taus = {n: collect_offline(r.run_dir, 1024, jax.random.PRNGKey(5), num_envs=64) / 4.0
          for n, r in [("a", a), ("plain", plain), ("aligned", aligned)]}
  e_plain, e_aligned = (_energy_distance(taus[n], taus["a"]) for n in ("plain", "aligned"))
  assert e_aligned < 0.95 * e_plain, (e_plain, e_aligned)
