"""Discriminative low-level alignment (paper Algorithm 1, SPEC 4 "Discriminator").

A binary classifier ``q_phi(M | tau)`` on goal-space behaviour ``tau = (g - s_t, g - s_{t+1})``
tells agent A's goal reaching (offline data) from agent B's (B's own SAC transitions). B's LL
reward becomes (paper eq. LL_update, SPEC 4)::

    r_B = r_task - w * log q(M=B | tau)

Sign: ``log q(M=B|tau) <= 0``, so ``-w log q(M=B|tau) >= 0`` is a *bonus* that is ~0 when the
discriminator is sure the behaviour is B's (q(B) -> 1) and grows as q(B) -> 0, i.e. as B's
behaviour looks like A's. This is the paper's Sec. 3.2 objective: maximise
``E[-log q_phi(m | tau)]`` (= maximise H(M | tau), minimise I(M; tau)), "generating behaviours that
maximally confuse the discriminator"; with B's own samples only the m=B term is under B's control.
We clip ``-log q(B)`` to ``[0, reward_clip]`` (unbounded as q(B) -> 0).

The plug-ins (:func:`make_alignment`) follow ``hdt.agents.train.make_train``'s contract and are pure
and vmappable over seeds: ``aux_init(key)``, ``aux_update(aux, transitions, env_steps, key)``,
``reward_fn(aux, batch)``. The discriminator outputs one logit for "tau came from B", so
``q(M=B|tau) = sigmoid(logit)``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable, NamedTuple, Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax

TAU_SIZE = 4


@dataclasses.dataclass(frozen=True)
class DiscConfig:
  """Discriminator hyper-parameters (paper Table "discriminator training"; nav PM row by default)."""

  lr: float = 2e-4  # Nav PM 2e-4; PM/2Link (manip) 3e-4; 3Link 5e-4
  batch_size: int = 64  # per class: each update sees batch_size B + batch_size A taus
  hidden_sizes: tuple[int, ...] = (32, 32)  # paper text [42, 42]; authors' code [32, 32] tanh
  update_every: int = 8  # env steps (summed over parallel envs) between discriminator updates
  w_init: float = 0.3  # reward weight at the start (0.3 nav, 0.4 manip) ...
  w_final: float = 0.1  # ... annealed linearly to this ...
  w_frac: float = 0.9  # ... over this fraction of training, then constant
  stop: float = 0.5  # lr annealed linearly to 0 over this fraction of the discriminator updates
  reward_clip: float = 10.0  # -log q(B|tau) is clipped to [0, reward_clip]
  buffer_size: int = 100_000  # circular buffer of B's taus

  def __post_init__(self):
    bad = [f"{k}={getattr(self, k)!r} must be a positive integer" for k in
           ("batch_size", "update_every", "buffer_size") if not getattr(self, k) > 0]
    bad += [f"{k}={getattr(self, k)!r} must be in (0, 1]" for k in ("w_frac", "stop")
            if not 0.0 < getattr(self, k) <= 1.0]
    bad += [f"{k}={getattr(self, k)!r} must be positive" for k in ("lr", "reward_clip")
            if not getattr(self, k) > 0]
    if bad:
      raise ValueError(f"invalid DiscConfig: {'; '.join(bad)}; the defaults are the paper's values")


class Discriminator(nn.Module):
  hidden_sizes: Sequence[int] = (32, 32)

  @nn.compact
  def __call__(self, tau):
    x = tau
    for h in self.hidden_sizes:
      x = jnp.tanh(nn.Dense(h)(x))
    return nn.Dense(1)(x)[..., 0]  # logit of "tau came from B"


def tau_from(obs: jax.Array, next_obs: jax.Array) -> jax.Array:
  """``(g - s_t, g - s_{t+1})``: the last 2 entries of the LL obs and next obs (Reach task layout)."""
  return jnp.concatenate([obs[..., -2:], next_obs[..., -2:]], axis=-1)


def disc_loss(apply_fn, params, tau_b, tau_a):
  """Sigmoid BCE on a balanced batch: label 1 for B, 0 for A. Returns (loss, accuracy)."""
  logits = apply_fn(params, jnp.concatenate([tau_b, tau_a]))
  labels = jnp.concatenate([jnp.ones(tau_b.shape[0]), jnp.zeros(tau_a.shape[0])])
  loss = jnp.mean(optax.sigmoid_binary_cross_entropy(logits, labels))
  acc = jnp.mean((logits > 0) == (labels > 0.5))
  return loss, acc


def reward_weight(cfg: DiscConfig, env_steps, total_env_steps: int) -> jax.Array:
  """w: linear from w_init to w_final over the first w_frac of training, then w_final."""
  frac = jnp.clip(jnp.asarray(env_steps, jnp.float32) / (cfg.w_frac * total_env_steps), 0.0, 1.0)
  return cfg.w_init + (cfg.w_final - cfg.w_init) * frac


def shaped_reward(r_task, logit_b, w, clip: float = 10.0):
  """``r_task - w * log q(M=B|tau)`` with ``q(M=B|tau) = sigmoid(logit_b)``; ``-log q`` clipped to
  ``[0, clip]``. The added term is >= 0 and largest when tau looks like A's (q(B) -> 0)."""
  log_q_b = jax.nn.log_sigmoid(logit_b)
  return r_task - w * jnp.clip(log_q_b, -clip, 0.0)


class Alignment(NamedTuple):
  aux_init: Callable
  aux_update: Callable
  reward_fn: Callable
  apply: Callable  # apply(params, tau) -> logit of B (tau already in raw goal-space units)
  optimizer: optax.GradientTransformation


def make_alignment(cfg: DiscConfig, tau_a, total_env_steps: int, num_envs: int,
                   tau_scale: float = 1.0) -> Alignment:
  """The make_train plug-ins for aligning B's LL to A's offline taus ``tau_a`` (n, 4).

  tau_scale: goal-space scale (e.g. the goal box ``delta_max``) dividing tau before the tanh MLP.
  The aux state: ``params``, ``opt_state``, ``buf`` (circular buffer of B's taus), ``ptr``,
  ``size``, ``env_steps``; A's taus are a constant closed over (shared by all seeds).
  """
  tau_a = jnp.asarray(tau_a, jnp.float32)
  if tau_a.ndim != 2 or tau_a.shape[1] != TAU_SIZE or tau_a.shape[0] == 0:
    raise ValueError(f"tau_a must have shape (n, {TAU_SIZE}), got {tau_a.shape}")
  net = Discriminator(tuple(cfg.hidden_sizes))
  inv = 1.0 / float(tau_scale)
  apply = lambda params, tau: net.apply(params, tau * inv)
  total_updates = max(1, total_env_steps // cfg.update_every)
  lr = optax.linear_schedule(cfg.lr, 0.0, max(1, int(cfg.stop * total_updates)))
  opt = optax.adam(lr)
  cap, n_a, bs = cfg.buffer_size, tau_a.shape[0], cfg.batch_size
  # Discriminator updates per training step (num_envs env steps): at most this many.
  max_k = math.ceil(num_envs / cfg.update_every)

  def aux_init(key):
    params = net.init(key, jnp.zeros((1, TAU_SIZE), jnp.float32))
    return dict(params=params, opt_state=opt.init(params),
                buf=jnp.zeros((cap, TAU_SIZE), jnp.float32), ptr=jnp.zeros((), jnp.int32),
                size=jnp.zeros((), jnp.int32), env_steps=jnp.zeros((), jnp.int32))

  def one_update(params, opt_state, tau_b, tau_a_batch):
    (loss, acc), g = jax.value_and_grad(lambda p: disc_loss(apply, p, tau_b, tau_a_batch),
                                        has_aux=True)(params)
    upd, opt_state = opt.update(g, opt_state, params)
    return optax.apply_updates(params, upd), opt_state, loss, acc

  def aux_update(aux, transitions, env_steps, key):
    tau = tau_from(transitions.obs, transitions.next_obs).reshape(-1, TAU_SIZE)
    n = tau.shape[0]
    idx = (aux["ptr"] + jnp.arange(n)) % cap
    buf = aux["buf"].at[idx].set(tau)
    ptr, size = (aux["ptr"] + n) % cap, jnp.minimum(aux["size"] + n, cap)
    env_steps = jnp.asarray(env_steps, jnp.int32)
    prev = env_steps - num_envs
    k = env_steps // cfg.update_every - prev // cfg.update_every  # updates due this step
    bits = jax.random.bits(key, (max_k, 2, bs), jnp.uint32)
    i_b = (bits[:, 0] % size.astype(jnp.uint32)).astype(jnp.int32)
    i_a = (bits[:, 1] % jnp.uint32(n_a)).astype(jnp.int32)

    def body(carry, xs):
      params, opt_state = carry
      j, ib, ia = xs
      p2, o2, loss, acc = one_update(params, opt_state, buf[ib], tau_a[ia])
      on = j < k
      pick = lambda new, old: jax.tree_util.tree_map(lambda a, b: jnp.where(on, a, b), new, old)
      return (pick(p2, params), pick(o2, opt_state)), (loss, acc, on.astype(jnp.float32))

    (params, opt_state), (loss, acc, on) = jax.lax.scan(
        body, (aux["params"], aux["opt_state"]), (jnp.arange(max_k), i_b, i_a))
    n_on = jnp.maximum(jnp.sum(on), 1.0)
    w = reward_weight(cfg, env_steps, total_env_steps)
    metrics = {"disc/loss": jnp.sum(loss * on) / n_on, "disc/acc": jnp.sum(acc * on) / n_on,
               "disc/w": w}
    return dict(params=params, opt_state=opt_state, buf=buf, ptr=ptr, size=size,
                env_steps=env_steps), metrics

  def reward_fn(aux, batch):
    logit_b = apply(aux["params"], tau_from(batch.obs, batch.next_obs))
    w = reward_weight(cfg, aux["env_steps"], total_env_steps)
    return shaped_reward(batch.reward, logit_b, w, cfg.reward_clip)

  return Alignment(aux_init, aux_update, reward_fn, apply, opt)

