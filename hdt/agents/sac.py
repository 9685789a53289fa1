"""Soft actor-critic: configuration, losses (pure closures) and one gradient update.

SAC as in Haarnoja et al. 2018 ("SAC and applications"): twin Q functions with target networks and
a clipped double-Q (twin-min) target, a tanh-squashed Gaussian policy, and a learned temperature
``alpha = exp(log_alpha)`` driven towards a target entropy (default ``-action_size``).

``SACConfig.value_net`` selects stable-baselines 2's SAC instead, the one the authors' code runs
(``bot_transfer/algs/discrim_sac.py``, ``kl_sac.py``, built on SB2's ``sac.py``): both Q functions
regress on ``r + gamma * V'(s')`` from a target state-value net, V regresses on
``min_i Q_i(s, a) - alpha * log pi(a|s)`` with ``a ~ pi``, the actor maximises ``Q_1`` (not the
minimum), only V has a target network, and all losses are taken at the parameters before the update
(one ``sess.run`` in SB2).

Two optional hooks, both no-ops by default (:mod:`hdt.agents.train` builds them from its plug-ins):

* ``actor_regularizer(policy_params, obs) -> (term, metrics)``: ``term`` is added to the actor loss
  (with an observation normaliser it is called as ``actor_regularizer(policy_params, obs, obs_norm)``),
  e.g. ``w * KL(pi || pi_ref)`` to a frozen reference policy; ``metrics`` (a dict of scalars, e.g.
  each term and its weight) are logged with the update's.
* ``reward_fn(aux_state, batch) -> rewards`` recomputes the rewards of a sampled batch before the
  critic target is formed, e.g. a discriminator bonus whose state lives in ``aux_state``.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from typing import Any, Callable

import jax
import jax.numpy as jnp
import optax
from flax import struct

from hdt.agents import networks as nets
from hdt.agents import normalizer
from hdt.agents.replay import Transition

Params = Any
ActorRegularizer = Callable[[Params, jax.Array], tuple[jax.Array, dict]]  # -> (loss term, metrics)
RewardFn = Callable[[Any, Transition], jax.Array]


@dataclasses.dataclass(frozen=True)
class SACConfig:
  """Hyper-parameters. Defaults are the paper's point-mass low-level values (SPEC section 4).

  A *training step* is ``num_envs`` parallel environment steps followed by ``updates_per_step``
  gradient updates, so the update-to-data ratio is ``updates_per_step / num_envs`` (1 with the
  defaults, as in stable-baselines' ``train_freq=1, gradient_steps=1``). A *chunk* is
  ``steps_per_chunk`` training steps compiled into one ``lax.scan``; the host sees the state only
  between chunks. Counts called ``*_env_steps`` / ``learning_starts`` are in environment steps
  summed over the parallel environments.
  """

  hidden_sizes: tuple[int, ...] = (64, 64)  # actor MLP
  critic_hidden_sizes: tuple[int, ...] | None = None  # None: same as hidden_sizes
  actor_lr: float = 3e-4
  critic_lr: float = 3e-4
  alpha_lr: float = 3e-4
  batch_size: int = 64
  buffer_size: int = 200_000
  tau: float = 0.005  # soft target update rate
  gamma: float = 0.99
  updates_per_step: int = 1  # gradient updates per training step (= per num_envs env steps)
  num_envs: int = 1
  total_env_steps: int = 200_000
  learning_starts: int = 100  # env steps of uniform-random actions before learning (SB2 default)
  reward_scale: float = 1.0
  target_entropy: float | None = None  # None: -action_size
  init_alpha: float = 1.0
  steps_per_chunk: int = 1000  # training steps per compiled chunk
  num_eval_episodes: int = 10
  # Running mean/std of the collected observations (SACState.obs_norm, hdt.agents.normalizer),
  # applied to the inputs of the policy and critics.
  normalize_observations: bool = False
  # SB2's SAC (the authors'): a state-value net V with a target V', Q on r + gamma V'(s'), the actor
  # on Q_1; False: twin-min target Q (module docstring). --preset paper sets it.
  value_net: bool = False
  # False: a time-limit end is stored as terminal, as the authors' SB2 SAC stores float(done)
  # (algs/discrim_sac.py, algs/kl_sac.py); True: bootstrap through it (only falls and solved tasks
  # are terminal).
  bootstrap_time_limits: bool = False
  # LayerNorm in every hidden layer of Q (and V): stable critics at higher learning rates and update
  # ratios (DroQ, RLPD); the policy is unchanged, so a card's policy loads either way.
  critic_layer_norm: bool = False
  # Critic targets from n-step returns (sampled as in Rainbow and DrQ-v2, no off-policy correction);
  # 1 is plain SAC, the authors'.
  n_step: int = 1
  # The actor and temperature step once every policy_delay gradient updates, the critics and their
  # targets every update (SBX's SAC policy_delay; TD3's delay): fewer updates' worth of compute.
  policy_delay: int = 1
  # The eval metric whose highest mean keeps a seed's best parameters: "return", as the authors'
  # trainer.py callback, or another of the env's (e.g. "success_max", which tracks a reach LL's
  # success more closely than its return does).
  best_by: str = "return"
  # An exponential moving average of the policy's parameters (this rate per actor step) is what
  # evaluations and checkpoints use, as Polyak averaging for the actor; 0 uses the trained policy
  # itself (the authors'). Acting during training always uses the trained policy.
  policy_ema: float = 0.0

  def __post_init__(self):
    # Plain Python numbers (numpy ones, e.g. an np.int64 budget, are accepted) and tuples, so the
    # config stays hashable (it is a static jit argument); anything else is left for validate().
    for f in dataclasses.fields(self):
      v = getattr(self, f.name)
      if _is_int(v):
        object.__setattr__(self, f.name, int(v))
      elif _is_number(v) and not isinstance(v, float):
        object.__setattr__(self, f.name, float(v))
    for name in ("hidden_sizes", "critic_hidden_sizes"):
      v = getattr(self, name)
      if isinstance(v, (list, tuple)) or hasattr(v, "__array__"):
        object.__setattr__(self, name, tuple(int(h) if _is_int(h) else h for h in v))
    self.validate()

  # -- derived quantities ------------------------------------------------------------------------
  @property
  def critic_sizes(self) -> tuple[int, ...]:
    return self.hidden_sizes if self.critic_hidden_sizes is None else self.critic_hidden_sizes

  @property
  def env_steps_per_chunk(self) -> int:
    return self.num_envs * self.steps_per_chunk

  @property
  def num_chunks(self) -> int:
    return self.total_env_steps // self.env_steps_per_chunk

  def target_entropy_for(self, action_size: int) -> float:
    return float(-action_size if self.target_entropy is None else self.target_entropy)

  def to_dict(self) -> dict:
    return dataclasses.asdict(self)

  @classmethod
  def from_dict(cls, d: dict) -> "SACConfig":
    return cls(**d)

  # -- validation --------------------------------------------------------------------------------
  def validate(self) -> None:
    errors = []

    def need(cond, msg):
      if not cond:
        errors.append(msg)

    for name in ("hidden_sizes", "critic_hidden_sizes")[:1 if self.critic_hidden_sizes is None else 2]:
      sizes = getattr(self, name)
      need(
          isinstance(sizes, tuple) and len(sizes) > 0 and all(_is_int(h) and h > 0 for h in sizes),
          f"{name}={sizes!r}: give at least one hidden layer, all sizes positive integers, e.g. (64, 64)",
      )
    for name in ("actor_lr", "critic_lr", "alpha_lr", "tau", "gamma", "reward_scale", "init_alpha"):
      v = getattr(self, name)
      need(_is_number(v), f"{name}={v!r}: must be a number, e.g. {getattr(SACConfig, name)!r}")
    need(self.target_entropy is None or _is_number(self.target_entropy),
         f"target_entropy={self.target_entropy!r}: must be a number or None (-action_size)")
    for name in ("batch_size", "buffer_size", "updates_per_step", "num_envs", "steps_per_chunk",
                 "num_eval_episodes", "total_env_steps", "n_step", "policy_delay"):
      v = getattr(self, name)
      need(_is_int(v) and v > 0, f"{name}={v!r}: must be a positive integer")
      need(not _is_int(v) or v < MAX_COUNT,
           f"{name}={v}: must be below 2**31 = {MAX_COUNT} (hdt counts in int32)")
    need(_is_int(self.learning_starts) and self.learning_starts >= 0,
         f"learning_starts={self.learning_starts!r}: must be an integer >= 0")
    if errors:  # the checks below assume numbers of the right kinds
      raise ValueError("invalid SACConfig:\n  " + "\n  ".join(errors))
    for name in ("actor_lr", "critic_lr", "alpha_lr"):
      v = getattr(self, name)
      need(math.isfinite(v) and v > 0, f"{name}={v}: learning rates must be positive, e.g. 3e-4")
    need(
        self.batch_size <= self.buffer_size,
        f"batch_size={self.batch_size} > buffer_size={self.buffer_size}: lower batch_size or "
        "raise buffer_size",
    )
    need(
        self.num_envs <= self.buffer_size,
        f"num_envs={self.num_envs} > buffer_size={self.buffer_size}: one training step inserts "
        "num_envs transitions, raise buffer_size",
    )
    need(
        self.n_step == 1 or self.learning_starts >= self.n_step * self.num_envs,
        f"n_step={self.n_step} needs learning_starts >= n_step * num_envs = {self.n_step * self.num_envs} "
        f"(got {self.learning_starts}): an n-step return needs n stored steps of each env",
    )
    need(
        self.updates_per_step % self.policy_delay == 0,
        f"policy_delay={self.policy_delay} must divide updates_per_step={self.updates_per_step}: the actor steps "
        f"at fixed places among each training step's updates",
    )
    need(0.0 < self.tau <= 1.0, f"tau={self.tau}: must be in (0, 1], e.g. 0.005")
    need(0.0 <= self.gamma <= 1.0, f"gamma={self.gamma}: must be in [0, 1], e.g. 0.99")
    need(self.total_env_steps % self.env_steps_per_chunk == 0, self._budget_error())
    need(
        self.learning_starts < self.total_env_steps,
        f"learning_starts={self.learning_starts} >= total_env_steps={self.total_env_steps}: the "
        "agent would never learn; lower learning_starts",
    )
    for name in ("normalize_observations", "value_net", "bootstrap_time_limits", "critic_layer_norm"):
      v = getattr(self, name)
      need(isinstance(v, bool), f"{name}={v!r}: must be True or False")
    need(math.isfinite(self.reward_scale), f"reward_scale={self.reward_scale}: must be finite")
    need(
        self.init_alpha > 0 and math.isfinite(self.init_alpha),
        f"init_alpha={self.init_alpha}: must be positive, e.g. 1.0",
    )
    need(
        self.target_entropy is None or math.isfinite(self.target_entropy),
        f"target_entropy={self.target_entropy}: must be finite or None (-action_size)",
    )
    need(_is_number(self.policy_ema) and 0.0 <= self.policy_ema < 1.0,
         f"policy_ema={self.policy_ema!r}: must be in [0, 1): 0 for none, e.g. 0.001")
    need(isinstance(self.best_by, str) and self.best_by.strip() == self.best_by and self.best_by != "",
         f"best_by={self.best_by!r}: name an evaluation metric, e.g. 'return' or 'success_max'")
    if errors:
      raise ValueError("invalid SACConfig:\n  " + "\n  ".join(errors))

  def _budget_error(self) -> str:
    """A budget is never rounded: name the nearest whole-chunk budgets and the other fix."""
    unit = self.env_steps_per_chunk
    lo, hi = self.total_env_steps // unit * unit, (self.total_env_steps // unit + 1) * unit
    nearest = max(1, round(self.total_env_steps / unit)) * unit
    other = lo if nearest == hi else hi
    near = f"{nearest} or {other}" if other > 0 else f"{nearest}"
    per_env = self.total_env_steps // self.num_envs
    other = (f"a steps_per_chunk that divides {per_env}" if self.total_env_steps % self.num_envs == 0
             else f"a budget that is a multiple of num_envs={self.num_envs}")
    return (f"total_env_steps={self.total_env_steps} is not a multiple of num_envs*steps_per_chunk="
            f"{unit}: set total_env_steps to {near} (--total-env-steps), or use {other}")


MAX_COUNT = 2**31  # step counters and buffer indices are int32


# SACConfig fields added after runs were saved without them, at the behaviour those runs had: a
# saved state missing a field resumes under this value (hdt.transfer.runner).
ADDED_FIELDS = {"bootstrap_time_limits": True, "critic_layer_norm": False, "n_step": 1, "policy_delay": 1,
                "best_by": "return", "policy_ema": 0.0}


def _is_int(v) -> bool:
  return isinstance(v, numbers.Integral) and not isinstance(v, bool)


def _is_number(v) -> bool:
  return isinstance(v, numbers.Real) and not isinstance(v, bool)


# ----------------------------------------------------------------------------------------------
# Losses.


def make_losses(
    networks: nets.SACNetworks,
    *,
    gamma: float,
    reward_scale: float,
    target_entropy: float,
    actor_regularizer: ActorRegularizer | None = None,
):
  """Returns ``(critic_loss, actor_loss, alpha_loss)``, pure functions returning ``(loss, aux)``.

  critic_loss(q_params, target_q_params, policy_params, log_alpha, batch, eps, obs_norm=None)
      0.5 * sum_i mean_b (Q_i(s, a) - y)^2 with
      y = reward_scale * r + discount * gamma * (min_i Q'_i(s', a') - alpha * log pi(a'|s')),
      a' = tanh(loc(s') + scale(s') * eps), y under stop_gradient.
  actor_loss(policy_params, q_params, log_alpha, obs, eps, obs_norm=None)
      mean_b (alpha * log pi(a|s) - min_i Q_i(s, a)) + term, (term, aux["regularizer"]) =
      actor_regularizer(params, obs) (0 and {} without one), a = tanh(loc(s) + scale(s) * eps).
      aux["log_prob"] is the per-sample log-prob (for alpha_loss).
  alpha_loss(log_alpha, log_prob)
      -mean_b log_alpha * stop_gradient(log_prob + target_entropy)   (as in SB2 / softlearning)

  With ``networks.value_net`` (SB2's SAC), ``q_params`` holds Q and V, ``target_q_params`` V', and
      critic_loss = 0.5 sum_i mean_b (Q_i(s, a) - y)^2 + 0.5 mean_b (V(s) - y_v)^2 with
      y = reward_scale * r + discount * gamma * V'(s'),  y_v = min_i Q_i(s, a~) - alpha * log pi(a~|s),
      a~ = tanh(loc(s) + scale(s) * eps) (``eps``: the actor's noise, the same action as the actor's);
      actor_loss uses Q_1 instead of min_i Q_i.

  ``eps`` is standard-normal noise of shape ``(batch, action_size)``: the losses are deterministic
  functions of their inputs, which keeps them testable and lets the training step draw all its
  randomness at once. ``obs_norm``: the observation statistics every network applies (None: raw
  observations); never differentiated.
  """
  policy_apply, q_apply, v_apply = networks.policy_apply, networks.q_apply, networks.v_apply

  def q_regression(q, target):  # 0.5 * sum_i mean_b (Q_i - y)^2, both SACs
    return 0.5 * jnp.sum(jnp.mean(jnp.square(q - target[..., None]), axis=0))

  def value_critic_loss(q_params, target_v_params, policy_params, log_alpha, batch: Transition, eps,
                        obs_norm=None):
    alpha = jnp.exp(log_alpha)
    target = jax.lax.stop_gradient(
        reward_scale * batch.reward + batch.discount * gamma * v_apply(target_v_params, batch.next_obs, obs_norm)
    )
    q = q_apply(q_params, batch.obs, batch.action, obs_norm)
    loc, scale = policy_apply(policy_params, batch.obs, obs_norm)
    action, log_prob = nets.sample_from_noise(loc, scale, eps)
    v_target = jax.lax.stop_gradient(
        jnp.min(q_apply(q_params, batch.obs, action, obs_norm), axis=-1) - alpha * log_prob)
    v = v_apply(q_params, batch.obs, obs_norm)
    loss = q_regression(q, target) + 0.5 * jnp.mean(jnp.square(v - v_target))
    return loss, {"q": jnp.mean(q), "target_q": jnp.mean(target), "v": jnp.mean(v)}

  def critic_loss(q_params, target_q_params, policy_params, log_alpha, batch: Transition, eps,
                  obs_norm=None):
    alpha = jnp.exp(log_alpha)
    loc, scale = policy_apply(policy_params, batch.next_obs, obs_norm)
    next_action, next_log_prob = nets.sample_from_noise(loc, scale, eps)
    next_q = q_apply(target_q_params, batch.next_obs, next_action, obs_norm)
    next_v = jnp.min(next_q, axis=-1) - alpha * next_log_prob
    target = jax.lax.stop_gradient(
        reward_scale * batch.reward + batch.discount * gamma * next_v
    )
    q = q_apply(q_params, batch.obs, batch.action, obs_norm)
    return q_regression(q, target), {"q": jnp.mean(q), "target_q": jnp.mean(target)}

  def actor_loss(policy_params, q_params, log_alpha, obs, eps, obs_norm=None):
    alpha = jnp.exp(log_alpha)
    loc, scale = policy_apply(policy_params, obs, obs_norm)
    action, log_prob = nets.sample_from_noise(loc, scale, eps)
    q = q_apply(q_params, obs, action, obs_norm)
    q = q[..., 0] if networks.value_net else jnp.min(q, axis=-1)  # SB2's actor maximises Q_1
    loss = jnp.mean(alpha * log_prob - q)
    reg_metrics = {}
    if actor_regularizer is not None:
      # the statistics only when there are some: regularisers of raw-observation runs take two arguments
      term, reg_metrics = actor_regularizer(policy_params, obs, *(() if obs_norm is None else (obs_norm,)))
      loss = loss + term
    return loss, {"log_prob": log_prob, "regularizer": reg_metrics}

  def alpha_loss(log_alpha, log_prob):
    return -jnp.mean(log_alpha * jax.lax.stop_gradient(log_prob + target_entropy))

  return (value_critic_loss if networks.value_net else critic_loss), actor_loss, alpha_loss


def soft_update(target_params: Params, online_params: Params, tau: float) -> Params:
  """target <- tau * online + (1 - tau) * target, leaf by leaf."""
  return jax.tree_util.tree_map(
      lambda t, o: (1.0 - tau) * t + tau * o, target_params, online_params
  )


# ----------------------------------------------------------------------------------------------
# Learner state and one gradient update.


@struct.dataclass
class SACState:
  policy_params: Params
  q_params: Params  # twin Q; with value_net {"q": twin Q, "v": V}
  target_q_params: Params  # target twin Q; with value_net {"v": V'} (SB2 keeps a target of V only)
  policy_opt_state: Any
  q_opt_state: Any
  log_alpha: jax.Array  # float32 scalar
  alpha_opt_state: Any
  update_steps: jax.Array  # int32, gradient updates done
  # Running observation statistics (hdt.agents.normalizer) the networks apply, updated by the training
  # loop from collected observations, never by gradients; None (no leaves) without normalisation.
  obs_norm: Any = None
  # The policy's moving average (SACConfig.policy_ema); None (no leaves) without one.
  policy_ema_params: Any = None

  @property
  def deployed_policy(self) -> Params:
    """The policy parameters evaluations and checkpoints use: the moving average when kept."""
    return self.policy_params if self.policy_ema_params is None else self.policy_ema_params


# The SACConfig fields that change no array shape: ``make_update``'s update takes them as an
# argument (``hyper``), so a grid over them runs as one vmapped program (hdt.agents.train.run).
SWEEPABLE = ("actor_lr", "critic_lr", "alpha_lr", "tau", "gamma", "reward_scale", "target_entropy")


def hyperparams(config: SACConfig, hyper: dict | None = None) -> dict:
  """The SWEEPABLE values: ``hyper``'s (scalars, possibly traced) where given, else the config's."""
  unknown = set(hyper or {}) - set(SWEEPABLE)
  if unknown:
    raise ValueError(f"hyper-parameters {sorted(unknown)} cannot be vmapped (they change shapes or are "
                     f"not SAC fields); vmappable: {', '.join(SWEEPABLE)}")
  return {k: getattr(config, k) for k in SWEEPABLE} | dict(hyper or {})


# Networks no wider than this run Adam on their parameters raveled into one vector (optax.flatten):
# XLA:CPU then runs the step as a few kernels instead of a few per layer, a large share of a small
# network's update. Wider ones keep per-layer moments: raveling gained nothing there (BENCHMARKS.md).
RAVEL_MAX_WIDTH = 256


def make_optimizers(config: SACConfig, hyper: dict | None = None):
  """(policy, q, alpha) optax optimisers: plain Adam (learning rates from :func:`hyperparams`; Adam's
  state does not depend on them), raveled for networks up to :data:`RAVEL_MAX_WIDTH` units wide."""
  h = hyperparams(config, hyper)
  ravel = max(config.hidden_sizes + config.critic_sizes) <= RAVEL_MAX_WIDTH
  return tuple((optax.flatten if ravel else lambda o: o)(optax.adam(h[k]))
               for k in ("actor_lr", "critic_lr", "alpha_lr"))


def target_part(networks: nets.SACNetworks, q_params: Params) -> Params:
  """The part of the critics that has a target network: all of them, or V alone (SB2)."""
  return {"v": q_params["v"]} if networks.value_net else q_params


def init_sac_state(networks: nets.SACNetworks, config: SACConfig, key: jax.Array) -> SACState:
  """Fresh parameters, optimiser states and temperature; empty observation statistics when
  ``config.normalize_observations``."""
  k_pi, k_q = jax.random.split(key)
  policy_params = networks.policy_init(k_pi)
  q_params = networks.q_init(k_q)
  pi_opt, q_opt, a_opt = make_optimizers(config)
  log_alpha = jnp.asarray(math.log(config.init_alpha), jnp.float32)
  return SACState(
      policy_params=policy_params,
      q_params=q_params,
      target_q_params=jax.tree_util.tree_map(jnp.copy, target_part(networks, q_params)),
      policy_opt_state=pi_opt.init(policy_params),
      q_opt_state=q_opt.init(q_params),
      log_alpha=log_alpha,
      alpha_opt_state=a_opt.init(log_alpha),
      update_steps=jnp.zeros((), jnp.int32),
      obs_norm=normalizer.init(networks.observation_size) if config.normalize_observations else None,
      policy_ema_params=jax.tree_util.tree_map(jnp.copy, policy_params) if config.policy_ema > 0 else None,
  )


def make_update(
    networks: nets.SACNetworks,
    config: SACConfig,
    action_size: int,
    *,
    actor_regularizer: ActorRegularizer | None = None,
    reward_fn: RewardFn | None = None,
):
  """Returns ``update(state, batch, noise, aux_state=None, hyper=None, actor=True) -> (state, metrics)``;
  with ``actor=False`` (a Python bool) the critic and target steps only (metrics of those only).

  ``noise``: standard-normal array of shape ``(2, batch, action_size)``, the reparameterisation
  noise of the critic target's next action (``noise[0]``) and of the actor loss (``noise[1]``),
  e.g. ``jax.random.normal(key, (2, batch_size, action_size))``.

  ``hyper``: {name: scalar} overriding the config's :data:`SWEEPABLE` values (e.g. per grid point,
  under vmap); None uses the config's, as constants.

  Order within one update: critic step (current alpha), actor step (new critic), alpha step (the
  actor's log-probs), then the soft target update. With ``networks.value_net`` (SB2) the actor's loss
  is taken at the critics before their step, and the critic loss's V target uses the actor's noise.
  """
  def update(state: SACState, batch: Transition, noise, aux_state=None, hyper=None, actor: bool = True):
    h = hyperparams(config, hyper)
    target_entropy = h["target_entropy"]
    if target_entropy is None:
      target_entropy = config.target_entropy_for(action_size)
    critic_loss, actor_loss, alpha_loss = make_losses(
        networks, gamma=h["gamma"], reward_scale=h["reward_scale"], target_entropy=target_entropy,
        actor_regularizer=actor_regularizer,
    )
    pi_opt, q_opt, a_opt = make_optimizers(config, h)
    critic_grad = jax.value_and_grad(critic_loss, has_aux=True)
    actor_grad = jax.value_and_grad(actor_loss, has_aux=True)
    alpha_grad = jax.value_and_grad(alpha_loss)
    eps_critic, eps_actor = noise[0], noise[1]
    if reward_fn is not None:
      batch = batch.replace(reward=reward_fn(aux_state, batch).astype(batch.reward.dtype))

    (c_loss, c_aux), g = critic_grad(
        state.q_params, state.target_q_params, state.policy_params, state.log_alpha, batch,
        eps_actor if networks.value_net else eps_critic, state.obs_norm,
    )
    upd, q_opt_state = q_opt.update(g, state.q_opt_state, state.q_params)
    q_params = optax.apply_updates(state.q_params, upd)
    target_q_params = soft_update(state.target_q_params, target_part(networks, q_params), h["tau"])
    if not actor:
      return state.replace(q_params=q_params, target_q_params=target_q_params, q_opt_state=q_opt_state,
                           update_steps=state.update_steps + 1), {"critic_loss": c_loss}

    (a_loss, a_aux), g = actor_grad(
        state.policy_params, state.q_params if networks.value_net else q_params, state.log_alpha,
        batch.obs, eps_actor, state.obs_norm
    )
    upd, policy_opt_state = pi_opt.update(g, state.policy_opt_state, state.policy_params)
    policy_params = optax.apply_updates(state.policy_params, upd)

    al_loss, g = alpha_grad(state.log_alpha, a_aux["log_prob"])
    upd, alpha_opt_state = a_opt.update(g, state.alpha_opt_state, state.log_alpha)
    log_alpha = optax.apply_updates(state.log_alpha, upd)

    new_state = SACState(
        policy_params=policy_params,
        q_params=q_params,
        target_q_params=target_q_params,
        policy_opt_state=policy_opt_state,
        q_opt_state=q_opt_state,
        log_alpha=log_alpha,
        alpha_opt_state=alpha_opt_state,
        update_steps=state.update_steps + 1,
        obs_norm=state.obs_norm,
        policy_ema_params=None if state.policy_ema_params is None else soft_update(
            state.policy_ema_params, policy_params, config.policy_ema),
    )
    metrics = {
        "critic_loss": c_loss,
        "actor_loss": a_loss,
        "alpha_loss": al_loss,
        "alpha": jnp.exp(log_alpha),
        "entropy": -jnp.mean(a_aux["log_prob"]),
        "q": c_aux["q"],
        "target_q": c_aux["target_q"],
        "batch_reward": jnp.mean(batch.reward),
    } | ({"v": c_aux["v"]} if networks.value_net else {}) | a_aux["regularizer"]
    return new_state, metrics

  return update
