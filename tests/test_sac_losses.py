"""SAC loss pieces against hand-computed numpy values (float64 references, stubbed linear networks)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hdt.agents import networks as nets
from hdt.agents.replay import Transition
from hdt.agents.sac import (
    SACConfig,
    SACState,
    make_losses,
    make_optimizers,
    make_update,
    soft_update,
)

B, OBS, ACT = 3, 2, 2
GAMMA, REWARD_SCALE, TARGET_ENTROPY = 0.9, 2.0, -2.0
LOG2PI = np.log(2.0 * np.pi)


# ---------------------------------------------------------------------------------------------
# Stub networks: a linear Gaussian policy and two linear critics, with hand-set tiny parameters.


def stub_policy_apply(p, obs, obs_norm=None):  # obs_norm: None here (no normaliser)
  loc = obs @ p["W"] + p["b"]
  return loc, jnp.broadcast_to(jnp.exp(p["log_std"]), loc.shape)


def stub_q_apply(q, obs, act, obs_norm=None):
  x = jnp.concatenate([obs, act], axis=-1)
  return x @ q["w"] + q["c"]  # (..., 2): two critics


STUB = nets.SACNetworks(policy_apply=stub_policy_apply, q_apply=stub_q_apply)

POLICY = {
    "W": np.array([[0.5, -0.2], [0.1, 0.3]], np.float32),
    "b": np.array([0.05, -0.1], np.float32),
    "log_std": np.array([-0.5, 0.2], np.float32),
}
Q = {
    "w": np.array([[0.3, -0.1], [0.2, 0.4], [-0.5, 0.25], [0.1, -0.3]], np.float32),
    "c": np.array([0.1, -0.2], np.float32),
}
Q_TARGET = {
    "w": np.array([[0.25, -0.05], [0.1, 0.35], [-0.4, 0.3], [0.2, -0.2]], np.float32),
    "c": np.array([0.0, 0.05], np.float32),
}
BATCH = Transition(
    obs=np.array([[0.1, -0.4], [0.7, 0.2], [-0.3, 0.5]], np.float32),
    action=np.array([[0.2, -0.9], [-0.5, 0.4], [0.99, 0.0]], np.float32),
    reward=np.array([1.0, -0.5, 0.25], np.float32),
    next_obs=np.array([[0.2, -0.3], [0.6, 0.1], [-0.2, 0.8]], np.float32),
    discount=np.array([1.0, 0.0, 1.0], np.float32),
)
EPS = np.array([[0.3, -1.2], [0.8, 0.1], [-0.5, 2.0]], np.float32)
LOG_ALPHA = np.float32(np.log(0.2))


def np64(tree):
  return jax.tree_util.tree_map(lambda x: np.asarray(x, np.float64), tree)


def np_policy(p, obs, eps):
  p = np64(p)
  loc = obs @ p["W"] + p["b"]
  scale = np.exp(p["log_std"]) * np.ones_like(loc)
  u = loc + scale * eps
  a = np.tanh(u)
  gauss = np.sum(-0.5 * ((u - loc) / scale) ** 2 - np.log(scale) - 0.5 * LOG2PI, axis=-1)
  log_prob = gauss - np.sum(np.log(1.0 - np.tanh(u) ** 2), axis=-1)  # change of variables
  return a, log_prob


def np_q(q, obs, act):
  q = np64(q)
  return np.concatenate([obs, act], -1) @ q["w"] + q["c"]


def losses(actor_regularizer=None):
  return make_losses(
      STUB, gamma=GAMMA, reward_scale=REWARD_SCALE, target_entropy=TARGET_ENTROPY,
      actor_regularizer=actor_regularizer,
  )


# ---------------------------------------------------------------------------------------------


def test_critic_loss_and_target_match_numpy():
  critic_loss, _, _ = losses()
  critic_loss = jax.jit(critic_loss)
  loss, aux = critic_loss(Q, Q_TARGET, POLICY, LOG_ALPHA, BATCH, EPS)

  b = np64(BATCH)
  alpha = np.exp(np.float64(LOG_ALPHA))
  next_a, next_logp = np_policy(POLICY, b.next_obs, np.float64(EPS))
  next_v = np.min(np_q(Q_TARGET, b.next_obs, next_a), -1) - alpha * next_logp
  target = REWARD_SCALE * b.reward + b.discount * GAMMA * next_v
  q = np_q(Q, b.obs, b.action)
  ref = 0.5 * np.sum(np.mean((q - target[:, None]) ** 2, axis=0))

  np.testing.assert_allclose(float(aux["target_q"]), target.mean(), rtol=1e-5)
  np.testing.assert_allclose(float(loss), ref, rtol=1e-5)
  # the terminal transition (discount 0) bootstraps nothing: its target is the scaled reward
  assert target[1] == pytest.approx(REWARD_SCALE * b.reward[1])

  # gradient w.r.t. the online critics: dL/dw_i = mean_b (q_i - y) x_b, the target held fixed
  grads, _ = jax.jit(jax.grad(critic_loss, has_aux=True))(Q, Q_TARGET, POLICY, LOG_ALPHA, BATCH, EPS)
  x = np.concatenate([b.obs, b.action], -1)
  err = q - target[:, None]
  np.testing.assert_allclose(grads["w"], x.T @ err / B, rtol=1e-4, atol=1e-6)
  np.testing.assert_allclose(grads["c"], err.mean(0), rtol=1e-4, atol=1e-6)
  # nothing flows into the policy through the target (stop_gradient)
  g_pi = jax.jit(jax.grad(lambda p: critic_loss(Q, Q_TARGET, p, LOG_ALPHA, BATCH, EPS)[0]))(POLICY)
  assert all(float(jnp.max(jnp.abs(g))) == 0.0 for g in jax.tree_util.tree_leaves(g_pi))


def test_actor_loss_matches_numpy_and_adds_regularizer():
  _, actor_loss, _ = losses()
  loss, aux = jax.jit(actor_loss)(POLICY, Q, LOG_ALPHA, BATCH.obs, EPS)
  obs = np.float64(BATCH.obs)
  a, logp = np_policy(POLICY, obs, np.float64(EPS))
  ref = np.mean(np.exp(np.float64(LOG_ALPHA)) * logp - np.min(np_q(Q, obs, a), -1))
  np.testing.assert_allclose(float(loss), ref, rtol=1e-5)
  np.testing.assert_allclose(aux["log_prob"], logp, rtol=1e-5)
  assert aux["regularizer"] == {}

  def reg(p, o):  # a term weighted 0.5, and what it logs
    term = jnp.sum(p["W"] ** 2) + jnp.mean(o)
    return 0.5 * term, {"custom": term, "custom_weight": 0.5}
  _, actor_loss_reg, _ = losses(actor_regularizer=reg)
  loss_reg, aux_reg = jax.jit(actor_loss_reg)(POLICY, Q, LOG_ALPHA, BATCH.obs, EPS)
  reg_ref = np.sum(np.float64(POLICY["W"]) ** 2) + obs.mean()
  np.testing.assert_allclose(float(aux_reg["regularizer"]["custom"]), reg_ref, rtol=1e-5)
  np.testing.assert_allclose(float(loss_reg), ref + 0.5 * reg_ref, rtol=1e-5)


def test_alpha_loss_and_gradient():
  _, _, alpha_loss = losses()
  logp = np.array([-1.5, 0.3, -2.6], np.float32)
  loss, grad = jax.value_and_grad(alpha_loss)(LOG_ALPHA, logp)
  ref = -np.mean(np.float64(LOG_ALPHA) * (np.float64(logp) + TARGET_ENTROPY))
  np.testing.assert_allclose(float(loss), ref, rtol=1e-5)
  # d/dlog_alpha = -mean(logp + target_entropy): entropy (-logp) above target -> alpha decreases
  np.testing.assert_allclose(float(grad), -np.mean(np.float64(logp) + TARGET_ENTROPY), rtol=1e-5)
  # log_prob is treated as a constant
  g_logp = jax.grad(lambda lp: alpha_loss(LOG_ALPHA, lp))(logp)
  assert float(jnp.max(jnp.abs(g_logp))) == 0.0


def test_soft_target_update():
  target = {"a": np.array([1.0, -2.0], np.float32), "b": {"c": np.float32(3.0)}}
  online = {"a": np.array([0.0, 2.0], np.float32), "b": {"c": np.float32(-1.0)}}
  out = soft_update(target, online, 0.1)
  np.testing.assert_allclose(out["a"], [0.9, -1.6], rtol=1e-6)
  np.testing.assert_allclose(out["b"]["c"], 2.6, rtol=1e-6)
  same = soft_update(target, online, 1.0)
  np.testing.assert_allclose(same["a"], online["a"])


def test_tanh_gaussian_log_prob_change_of_variables():
  loc = np.array([[0.3, -1.0], [2.0, 0.0]], np.float32)
  scale = np.array([[0.5, 1.5], [0.2, 1.0]], np.float32)
  u = np.array([[0.1, -0.7], [1.8, 3.0]], np.float32)
  a = np.tanh(np.float64(u))
  # manual: log N(u) - log|da/du| with da/du = 1 - tanh(u)^2, per dimension, summed
  ref = np.sum(
      -0.5 * ((u - loc) / np.float64(scale)) ** 2 - np.log(np.float64(scale)) - 0.5 * LOG2PI
      - np.log(1.0 - a ** 2),
      axis=-1,
  )
  eps = (u - loc) / scale

  @jax.jit
  def compute():
    return (
        nets.log_prob_from_pre_tanh(loc, scale, u),
        # distrax's own Transformed distribution (inverts the tanh): fine away from |a| ~ 1
        nets.tanh_gaussian(loc[:1], scale[:1]).log_prob(np.float32(a[:1])),
        nets.sample_from_noise(loc, scale, eps),  # a = tanh(loc + scale * eps) and its log-prob
        # where tanh saturates (a == 1.0 in float32)
        nets.log_prob_from_pre_tanh(np.zeros(1, np.float32), np.ones(1, np.float32),
                                    np.array([12.0], np.float32)),
    )

  lp_u, lp_distrax, (act, lp), lp_far = compute()
  np.testing.assert_allclose(lp_u, ref, rtol=1e-5)
  np.testing.assert_allclose(lp_distrax, ref[:1], rtol=1e-4)
  np.testing.assert_allclose(act, a, rtol=1e-5)
  np.testing.assert_allclose(lp, ref, rtol=1e-5)
  # numerically safe: finite, and close to the asymptote log|da/du| ~ log 4 - 2|u|
  assert np.isfinite(float(lp_far))
  np.testing.assert_allclose(float(lp_far), -0.5 * 144 - 0.5 * LOG2PI - (np.log(4) - 24), rtol=1e-5)


def test_kl_between_pre_tanh_gaussians():
  lp, sp = np.array([0.2, -0.5], np.float32), np.array([0.5, 1.2], np.float32)
  lq, sq = np.array([0.0, 0.3], np.float32), np.array([1.0, 0.8], np.float32)
  ref = np.sum(np.log(sq / sp) + (sp ** 2 + (lp - lq) ** 2) / (2 * sq ** 2) - 0.5)
  np.testing.assert_allclose(float(nets.gaussian_kl(lp, sp, lq, sq)), ref, rtol=1e-5)
  assert float(nets.gaussian_kl(lp, sp, lp, sp)) == pytest.approx(0.0, abs=1e-6)


def test_real_networks_shapes_and_bounds():
  n = nets.make_sac_networks(5, 3, (16, 8))

  @jax.jit
  def run(key):
    k1, k2 = jax.random.split(key)
    pp, qp = n.policy_init(k1), n.q_init(k2)
    obs = jnp.linspace(-100.0, 100.0, 35).reshape(7, 5)
    loc, scale = n.policy_apply(pp, obs)
    det = nets.deterministic_action(loc)
    return pp, qp, loc, scale, det, n.q_apply(qp, obs, det)

  pp, qp, loc, scale, det, q = run(jax.random.PRNGKey(0))
  assert loc.shape == scale.shape == (7, 3) and loc.dtype == jnp.float32
  assert np.all(scale >= np.exp(nets.LOG_STD_MIN) * 0.999) and np.all(scale <= np.exp(nets.LOG_STD_MAX) * 1.001)
  np.testing.assert_allclose(det, np.tanh(loc), rtol=1e-6)
  assert q.shape == (7, 2)
  assert not np.allclose(q[:, 0], q[:, 1])  # two independently initialised critics
  # lecun-uniform kernels within +-sqrt(3 / fan_in), zero biases
  k0 = qp["params"]["critics"]["hidden_0"]["kernel"]
  assert k0.shape == (2, 8, 16) and float(jnp.max(jnp.abs(k0))) <= np.sqrt(3 / 8)
  assert float(jnp.max(jnp.abs(pp["params"]["mlp"]["out"]["bias"]))) == 0.0
  # the stacked twin critics' biases, shape (2, out), are biases too
  for layer in ("hidden_0", "hidden_1", "out"):
    assert float(jnp.max(jnp.abs(qp["params"]["critics"][layer]["bias"]))) == 0.0


@pytest.mark.parametrize("value_net", [False, True])
def test_layer_norm_critics_start_as_unit_gains_and_normalise(value_net):
  n = nets.make_sac_networks(5, 3, (16, 8), critic_layer_norm=True, value_net=value_net)
  qp = n.q_init(jax.random.PRNGKey(1))
  q_params = qp["q"] if value_net else qp
  gain, shift = q_params["params"]["critics"]["norm_0"]["scale"], q_params["params"]["critics"]["norm_0"]["bias"]
  assert gain.shape == (2, 16) and np.all(np.asarray(gain) == 1.0) and np.all(np.asarray(shift) == 0.0)
  # normalised hidden layers: scaling the inputs by 1e4 moves Q far less than without LayerNorm
  obs, act = jnp.linspace(-1.0, 1.0, 35).reshape(7, 5), jnp.zeros((7, 3))
  plain = nets.make_sac_networks(5, 3, (16, 8), value_net=value_net)
  pq = plain.q_init(jax.random.PRNGKey(1))
  grow = lambda net, p: float(jnp.max(jnp.abs(net.q_apply(p, 1e4 * obs, act))))
  assert grow(n, qp) < 10.0 < grow(plain, pq)
  if value_net:
    assert n.v_apply(qp, obs).shape == (7,)


def to_j(tree):
  return jax.tree_util.tree_map(jnp.asarray, tree)


def stub_state(cfg):
  pi_opt, q_opt, a_opt = make_optimizers(cfg)
  return SACState(
      policy_params=to_j(POLICY), q_params=to_j(Q), target_q_params=to_j(Q_TARGET),
      policy_opt_state=pi_opt.init(to_j(POLICY)), q_opt_state=q_opt.init(to_j(Q)),
      log_alpha=jnp.asarray(LOG_ALPHA), alpha_opt_state=a_opt.init(jnp.asarray(LOG_ALPHA)),
      update_steps=jnp.zeros((), jnp.int32),
  )


def test_full_update_first_adam_step_and_target():
  """One update with stubs: Adam's first step moves every parameter by lr * sign(grad)."""
  cfg = SACConfig(actor_lr=1e-2, critic_lr=2e-2, alpha_lr=3e-2, tau=0.1, gamma=GAMMA,
                  reward_scale=REWARD_SCALE, target_entropy=TARGET_ENTROPY, batch_size=B)
  noise = np.stack([EPS, EPS[::-1]])
  new, metrics = jax.jit(make_update(STUB, cfg, ACT))(stub_state(cfg), to_j(BATCH), noise)

  critic_loss, actor_loss, _ = losses()
  gq, _ = jax.jit(jax.grad(critic_loss, has_aux=True))(Q, Q_TARGET, POLICY, LOG_ALPHA, BATCH, noise[0])
  expect_q = jax.tree_util.tree_map(lambda p, g: p - 2e-2 * np.sign(g), Q, gq)
  np.testing.assert_allclose(new.q_params["w"], expect_q["w"], atol=1e-6)
  # the actor step uses the updated critics
  gp, aux = jax.jit(jax.grad(actor_loss, has_aux=True))(POLICY, expect_q, LOG_ALPHA, BATCH.obs, noise[1])
  np.testing.assert_allclose(new.policy_params["W"], POLICY["W"] - 1e-2 * np.sign(gp["W"]), atol=1e-6)
  g_alpha = -np.mean(np.asarray(aux["log_prob"]) + TARGET_ENTROPY)
  np.testing.assert_allclose(float(new.log_alpha), LOG_ALPHA - 3e-2 * np.sign(g_alpha), atol=1e-6)
  np.testing.assert_allclose(
      new.target_q_params["w"], 0.9 * Q_TARGET["w"] + 0.1 * np.asarray(new.q_params["w"]), atol=1e-6
  )
  assert int(new.update_steps) == 1
  np.testing.assert_allclose(float(metrics["alpha"]), np.exp(float(new.log_alpha)), rtol=1e-6)


def test_critic_only_update_is_the_full_updates_critic_and_target_step():
  """update(..., actor=False) (SACConfig.policy_delay) steps the critics and their targets exactly as a
  whole update does and leaves the actor, the temperature and their optimisers alone."""
  cfg = SACConfig(actor_lr=1e-2, critic_lr=2e-2, alpha_lr=3e-2, tau=0.1, gamma=GAMMA,
                  reward_scale=REWARD_SCALE, target_entropy=TARGET_ENTROPY, batch_size=B)
  noise = np.stack([EPS, EPS[::-1]])
  update, state = make_update(STUB, cfg, ACT), stub_state(cfg)
  whole, _ = jax.jit(update)(state, to_j(BATCH), noise)
  critic, metrics = jax.jit(lambda s, b, e: update(s, b, e, actor=False))(state, to_j(BATCH), noise)
  for name in ("q_params", "target_q_params", "q_opt_state", "update_steps"):
    for a, b in zip(jax.tree_util.tree_leaves(getattr(critic, name)), jax.tree_util.tree_leaves(getattr(whole, name))):
      np.testing.assert_array_equal(a, b, err_msg=name)
  for name in ("policy_params", "policy_opt_state", "log_alpha", "alpha_opt_state"):
    for a, b in zip(jax.tree_util.tree_leaves(getattr(critic, name)), jax.tree_util.tree_leaves(getattr(state, name))):
      np.testing.assert_array_equal(a, b, err_msg=name)
  assert not np.allclose(whole.policy_params["W"], state.policy_params["W"])  # the whole update moved it
  assert set(metrics) == {"critic_loss"}


def test_reward_fn_plugin_replaces_rewards():
  cfg = SACConfig(batch_size=B, gamma=GAMMA, reward_scale=REWARD_SCALE)
  seen = {}

  def reward_fn(aux_state, batch):
    seen["aux"] = aux_state
    return batch.reward * 0.0 + aux_state

  noise = np.stack([EPS, EPS])
  upd = jax.jit(make_update(STUB, cfg, ACT, reward_fn=reward_fn))
  _, m = upd(stub_state(cfg), to_j(BATCH), noise, aux_state=7.0)
  assert float(m["batch_reward"]) == pytest.approx(7.0)
  # the critic target uses the recomputed rewards: same loss as with rewards replaced by 7
  critic_loss, _, _ = losses()
  ref, _ = critic_loss(Q, Q_TARGET, POLICY, LOG_ALPHA, BATCH.replace(reward=np.full(B, 7.0, np.float32)), EPS)
  np.testing.assert_allclose(float(m["critic_loss"]), float(ref), rtol=1e-5)


@pytest.mark.parametrize(
    "kwargs, fragment",
    [
        (dict(batch_size=512, buffer_size=256), "lower batch_size or raise buffer_size"),
        (dict(hidden_sizes=()), "hidden_sizes"),
        (dict(actor_lr=0.0), "actor_lr"),
        (dict(tau=1.5), "tau"),
        (dict(total_env_steps=1500, steps_per_chunk=1000), "set total_env_steps to 2000"),
        (dict(learning_starts=10**6), "lower learning_starts"),
        (dict(num_envs=0), "num_envs"),
    ],
)
def test_config_validation_messages(kwargs, fragment):
  with pytest.raises(ValueError, match=fragment):
    SACConfig(**kwargs)


def test_config_defaults_are_paper_point_mass_values():
  c = SACConfig()
  assert (c.actor_lr, c.critic_lr, c.batch_size, c.hidden_sizes, c.buffer_size, c.gamma, c.tau) == (
      3e-4, 3e-4, 64, (64, 64), 200_000, 0.99, 0.005)
  assert c.target_entropy_for(8) == -8.0
  assert SACConfig(hidden_sizes=[32, 32]).hidden_sizes == (32, 32)
  hash(c)


# ---------------------------------------------------------------------------------------------
# stable-baselines 2's SAC (value_net=True), the authors': a numpy transcription of SB2's sac.py
# (q_backup, v_backup, qf1_pi in the policy loss, a target on V only, one sess.run per update).

V = {"w": np.array([0.4, -0.6], np.float32), "c": np.float32(0.05)}
V_TARGET = {"w": np.array([0.3, -0.5], np.float32), "c": np.float32(-0.1)}
STUB_V = nets.SACNetworks(
    policy_apply=stub_policy_apply,
    q_apply=lambda p, obs, act, obs_norm=None: stub_q_apply(p["q"], obs, act),
    v_apply=lambda p, obs, obs_norm=None: obs @ p["v"]["w"] + p["v"]["c"],
    value_net=True,
)
QV, QV_TARGET = {"q": Q, "v": V}, {"v": V_TARGET}


def np_v(v, obs):
  v = np64(v)
  return obs @ v["w"] + v["c"]


def sb2_losses():
  return make_losses(STUB_V, gamma=GAMMA, reward_scale=REWARD_SCALE, target_entropy=TARGET_ENTROPY)


def test_sb2_value_net_losses_match_numpy():
  critic_loss, actor_loss, _ = sb2_losses()
  loss, aux = jax.jit(critic_loss)(QV, QV_TARGET, POLICY, LOG_ALPHA, BATCH, EPS)
  b, alpha = np64(BATCH), np.exp(np.float64(LOG_ALPHA))
  q_backup = REWARD_SCALE * b.reward + b.discount * GAMMA * np_v(V_TARGET, b.next_obs)
  q = np_q(Q, b.obs, b.action)
  a_pi, logp_pi = np_policy(POLICY, b.obs, np.float64(EPS))
  v_backup = np.min(np_q(Q, b.obs, a_pi), -1) - alpha * logp_pi
  ref = (0.5 * np.mean((q_backup - q[:, 0]) ** 2) + 0.5 * np.mean((q_backup - q[:, 1]) ** 2)
         + 0.5 * np.mean((np_v(V, b.obs) - v_backup) ** 2))
  np.testing.assert_allclose(float(loss), ref, rtol=1e-5)
  np.testing.assert_allclose(float(aux["target_q"]), q_backup.mean(), rtol=1e-5)
  # policy_kl_loss = mean(alpha * logp_pi - qf1_pi): the first critic, not the minimum
  a_loss, _ = jax.jit(actor_loss)(POLICY, QV, LOG_ALPHA, BATCH.obs, EPS)
  np.testing.assert_allclose(float(a_loss), np.mean(alpha * logp_pi - np_q(Q, b.obs, a_pi)[:, 0]), rtol=1e-5)
  assert not np.allclose(np_q(Q, b.obs, a_pi)[:, 0], np.min(np_q(Q, b.obs, a_pi), -1))  # the test can tell
  # nothing flows into the policy or the target V from the critic loss
  g_pi = jax.grad(lambda p: critic_loss(QV, QV_TARGET, p, LOG_ALPHA, BATCH, EPS)[0])(POLICY)
  g_t = jax.grad(lambda t: critic_loss(QV, t, POLICY, LOG_ALPHA, BATCH, EPS)[0])(QV_TARGET)
  assert all(float(jnp.max(jnp.abs(g))) == 0.0 for g in jax.tree_util.tree_leaves((g_pi, g_t)))


def test_sb2_update_takes_every_loss_before_the_step_and_targets_v_only():
  cfg = SACConfig(actor_lr=1e-2, critic_lr=2e-2, alpha_lr=3e-2, tau=0.1, gamma=GAMMA, value_net=True,
                  reward_scale=REWARD_SCALE, target_entropy=TARGET_ENTROPY, batch_size=B)
  pi_opt, q_opt, a_opt = make_optimizers(cfg)
  state = SACState(
      policy_params=to_j(POLICY), q_params=to_j(QV), target_q_params=to_j(QV_TARGET),
      policy_opt_state=pi_opt.init(to_j(POLICY)), q_opt_state=q_opt.init(to_j(QV)),
      log_alpha=jnp.asarray(LOG_ALPHA), alpha_opt_state=a_opt.init(jnp.asarray(LOG_ALPHA)),
      update_steps=jnp.zeros((), jnp.int32))
  noise = np.stack([EPS[::-1], EPS])  # SB2 samples one action per state, the actor's (noise[1])
  new, metrics = jax.jit(make_update(STUB_V, cfg, ACT))(state, to_j(BATCH), noise)
  critic_loss, actor_loss, _ = sb2_losses()
  gq, _ = jax.grad(critic_loss, has_aux=True)(QV, QV_TARGET, POLICY, LOG_ALPHA, BATCH, noise[1])
  step = lambda p, g, lr: jax.tree_util.tree_map(lambda x, d: x - lr * np.sign(d), p, g)
  expect_qv = step(QV, gq, 2e-2)
  for k in ("q", "v"):
    for name in ("w", "c"):
      np.testing.assert_allclose(new.q_params[k][name], expect_qv[k][name], atol=1e-6)
  # the actor's gradient is taken at the critics before their step
  gp, _ = jax.grad(actor_loss, has_aux=True)(POLICY, QV, LOG_ALPHA, BATCH.obs, noise[1])
  np.testing.assert_allclose(new.policy_params["W"], POLICY["W"] - 1e-2 * np.sign(gp["W"]), atol=1e-6)
  # Polyak averaging on V alone (SB2's target/values_fn/vf)
  assert set(new.target_q_params) == {"v"}
  np.testing.assert_allclose(new.target_q_params["v"]["w"],
                             0.9 * V_TARGET["w"] + 0.1 * np.asarray(new.q_params["v"]["w"]), atol=1e-6)
  assert "v" in metrics

