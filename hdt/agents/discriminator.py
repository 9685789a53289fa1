"""Discriminative low-level alignment (paper Algorithm 1) as the authors' code does it.

Follows ``bot_transfer/algs/discrim_sac.py`` (class ``DSAC``) and ``bot_transfer/envs/hierarchical.py``
(class ``DiscriminatorEnv``), which win over the paper text and SPEC 4 where they differ:

* Input (``DSAC.learn``, ``DiscriminatorEnv.step``): ``x = (g - s_t, g - s_{t+1}, z)`` in raw
  goal-space units, where ``z`` is the relative sub-goal the episode was given (``skill``); the
  authors' ``discrim_include_next_state`` / ``discrim_include_skill`` both default to True.
* Output: ``D(x) = sigmoid(mlp(x))``, trained by mean squared error towards soft labels 0.95 for B
  (the agent being trained) and 0.05 for A (the expert) (``DSAC.learn`` / ``setup_model``), so D is
  the probability that x is B's.
* Reward (``DSAC._train_step``, ``_get_discrim_reward``): for a sampled batch, with ``step`` the
  index of the latest env step (0-based, the authors' loop variable)::

      r = (1 - w) * r_task + [step > start] * w * clip(-coef * log(D + 1e-6), 0, clip)

  with ``start = 200``, ``coef = 2``, ``clip = 10`` and, with ``discrim_decay`` (the README's
  command sets it), ``w = max(w0 * (1 - step / T), 0.1)``. The bonus is recomputed with the current
  discriminator every time a batch is sampled.
* Discriminator updates: one Adam step on ``batch_size`` samples drawn from a class-balanced buffer
  (one A sample stored per B sample), every ``update_every`` env steps while ``step < stop * T``,
  at ``lr * max(0, 1 - step / (stop * T))``.

A's data. In both of the authors' modes A's frozen deterministic LL runs in A's reach env alongside
every B env, and A's rows carry B's relative goal z (``DiscriminatorEnv``, ``DSAC.learn``):
``"offline"`` (the class default; the README's Ant command, ``--discrim-online false``; the transfer layer's
``configs.disc_config`` picks it for nav agents and ``"online"`` for manipulation) starts A,
at each of B's new goals, on a random goal of its own (``reset(low=True)`` samples a skill), and
``"online"`` on B's z (``reset`` then ``set_skill``). In both, when A's own episode ends (its done, or
``expert_time_limit`` steps: the README's ``--discrim-time-limit 32``) A restarts from a fresh start of
its HL episodes (``expert_env.reset()``, ``low=False``; ``expert_restart``) on B's current z
(``DiscriminatorEnv.step``); A's next row still begins at its last observation before that restart
(``prev_expert_obs``; ``expert_prev_obs``). ``"fixed"`` is the paper text's description instead: a
fixed set of A's taus on uniformly drawn goals, each with A's own z.

The plug-ins (:func:`make_alignment`) follow ``hdt.agents.train.make_train``'s contract and are pure
and vmappable over seeds.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable, NamedTuple, Sequence

import flax.linen as nn
from flax import struct
import jax
import jax.numpy as jnp
import optax

from hdt.agents.plugins import Plugin

TAU_SIZE = 4  # (g - s_t, g - s_{t+1})
Z_SIZE = 2
B_LABEL, A_LABEL = 0.95, 0.05  # the authors' soft labels: agent (B) 0.95, expert (A) 0.05
DATA_MODES = ("offline", "online", "fixed")


WEIGHT = "disc_weight"  # the alignment plug-in's vmappable hyper-parameter (DiscConfig.weight, w0)
# DiscConfig fields added after alignment runs had been saved, each with the value that gives those
# runs' behaviour: a saved run without the field resumes under that value (hdt.transfer.runner).
ADDED_FIELDS = {"expert_restart": "low", "expert_prev_obs": "post_restart"}

@dataclasses.dataclass(frozen=True)
class DiscConfig:
  """Discriminator hyper-parameters. Mechanisms follow ``discrim_sac.py``; the per-experiment numbers
  (lr, weight, batch, update frequency, stop) follow the paper's table "discriminator training"."""

  lr: float = 2e-4  # Nav PM 2e-4 (also the README); PM/2Link (manip) 3e-4; 3Link 5e-4
  batch_size: int = 64  # samples per update from the class-balanced buffer (discrim_batch_size)
  hidden_sizes: tuple[int, ...] = (32, 32)  # paper text [42, 42]; authors' code [32, 32] tanh
  update_every: int = 8  # env steps between updates: paper table 8; DSAC's default discrim_train_freq=1
  weight: float = 0.3  # w0, the initial weight: 0.3 nav, 0.4 manip (paper table); DSAC's default discrim_weight=0.5
  w_min: float = 0.1  # floor of the decayed weight (DSAC.learn)
  w_decay: bool = True  # w = max(w0 (1 - step/T), w_min); False: constant w0 (DSAC's default)
  start: int = 200  # the bonus is added only for step > start (discrim_start)
  coef: float = 2.0  # bonus = clip(-coef log(D + 1e-6), 0, reward_clip) (discrim_coef)
  reward_clip: float = 10.0  # (discrim_clip)
  stop: float = 0.5  # updates only while step < stop T, lr linearly to 0 at stop T (discrim_stop)
  buffer_size: int = 125_000  # per class (the authors' 250k buffer holds both classes)
  # Every test_every-th LL episode of each B env (with A's rows beside it) goes to a held-out buffer of
  # buffer_size / 2 rows per class that only measures accuracy, disc/test_acc (DSAC.learn,
  # discrim_test_data_collection_freq = 10); 0: every row trains. Needs episode starts (include_z or A alongside).
  test_every: int = 10
  include_z: bool = True  # z in the input (discrim_include_skill)
  data: str = "offline"  # A's data: "offline" / "online" (A alongside B; see the module) or "fixed" (a set)
  expert_time_limit: int = 32  # A's episode length alongside B (README --discrim-time-limit); 0: A's LL horizon
  # where A restarts after its own episode ends: "high", the start of its HL episodes (DiscriminatorEnv.step's
  # expert_env.reset(), low=False); "low", its LL start (an older hdt default)
  expert_restart: str = "high"
  # A's input row after its own restart: "pre_restart", from its last observation before the restart, as
  # DiscriminatorEnv.step (prev_expert_obs is set before expert_env.reset(), so one row per A episode mixes
  # the old goal with the new); "post_restart", from its fresh observation (an older hdt default)
  expert_prev_obs: str = "pre_restart"
  scale_inputs: bool = False  # True: divide inputs by A's delta_max (the authors feed raw units)

  def __post_init__(self):
    object.__setattr__(self, "hidden_sizes", tuple(int(h) for h in self.hidden_sizes))
    bad = []
    bad += [f"{k}={getattr(self, k)!r} must be True or False" for k in ("w_decay", "include_z", "scale_inputs")
            if not isinstance(getattr(self, k), bool)]  # the CLI parses true/false (cli._bool)
    bad += [f"{k}={getattr(self, k)!r} must be a positive integer" for k in
           ("batch_size", "update_every", "buffer_size") if not getattr(self, k) > 0]
    bad += [f"stop={self.stop!r} must be in (0, 1]"] if not 0.0 < self.stop <= 1.0 else []
    bad += [f"{k}={getattr(self, k)!r} must be positive" for k in ("lr", "reward_clip", "coef")
            if not getattr(self, k) > 0]
    bad += [f"{k}={getattr(self, k)!r} must be in [0, 1]" for k in ("weight", "w_min")
            if not 0.0 <= getattr(self, k) <= 1.0]
    bad += [f"start={self.start!r} must be >= 0"] if not self.start >= 0 else []
    bad += [f"test_every={self.test_every!r} must be >= 0 (0: no held-out episodes)"] \
        if not self.test_every >= 0 else []
    bad += [f"expert_time_limit={self.expert_time_limit!r} must be >= 0 (0: A's LL horizon)"] \
        if not self.expert_time_limit >= 0 else []
    bad += [f"data={self.data!r} must be one of {DATA_MODES}"] if self.data not in DATA_MODES else []
    bad += [f"expert_restart={self.expert_restart!r} must be 'high' or 'low'"] \
        if self.expert_restart not in ("high", "low") else []
    bad += [f"expert_prev_obs={self.expert_prev_obs!r} must be 'pre_restart' or 'post_restart'"] \
        if self.expert_prev_obs not in ("pre_restart", "post_restart") else []
    if bad:
      raise ValueError(f"invalid DiscConfig: {'; '.join(bad)}; the defaults are the authors' values")

  @property
  def input_size(self) -> int:
    return TAU_SIZE + (Z_SIZE if self.include_z else 0)


class Discriminator(nn.Module):
  hidden_sizes: Sequence[int] = (32, 32)

  @nn.compact
  def __call__(self, x):
    for h in self.hidden_sizes:
      x = jnp.tanh(nn.Dense(h)(x))
    return nn.Dense(1)(x)[..., 0]  # logit; D = sigmoid(logit) = P(x is B's)


def disc_input(obs: jax.Array, next_obs: jax.Array, z: jax.Array | None = None) -> jax.Array:
  """``(g - s_t, g - s_{t+1}[, z])``: the last 2 entries of the LL obs and next obs (Reach layout),
  then the episode's relative sub-goal, in the order of ``DSAC.learn``'s discriminator components."""
  parts = [obs[..., -2:], next_obs[..., -2:]] + ([] if z is None else [z])
  return jnp.concatenate(parts, axis=-1)


def disc_loss(apply_fn, params, x, labels):
  """Mean squared error between ``D(x) = sigmoid(logit)`` and the soft labels
  (``tf.losses.mean_squared_error`` in ``DSAC.setup_model``). Returns (loss, accuracy at 0.5)."""
  d = jax.nn.sigmoid(apply_fn(params, x))
  loss = jnp.mean(jnp.square(d - labels))
  acc = jnp.mean((d > 0.5) == (labels > 0.5))
  return loss, acc


def reward_weight(cfg: DiscConfig, step, total_env_steps: int, disc_weight=None) -> jax.Array:
  """``max(w0 (1 - step/T), w_min)`` with ``w_decay`` (the authors' ``discrim_decay``), else ``w0``;
  ``w0``: ``disc_weight`` if given (e.g. a grid point's, traced), else ``cfg.weight``."""
  w0 = cfg.weight if disc_weight is None else disc_weight
  frac = 1.0 - jnp.asarray(step, jnp.float32) / float(total_env_steps)
  w = jnp.maximum(w0 * frac, cfg.w_min) if cfg.w_decay else jnp.asarray(w0, jnp.float32) + 0 * frac
  return w.astype(jnp.float32)


def disc_bonus(d, coef: float = 2.0, clip: float = 10.0):
  """``clip(-coef log(D + 1e-6), 0, clip)`` (``DSAC._get_discrim_reward``): large when D, the
  probability of "B", is small, i.e. when B's behaviour looks like A's."""
  return jnp.clip(-coef * jnp.log(d + 1e-6), 0.0, clip)


def shaped_reward(cfg: DiscConfig, r_task, d, step, total_env_steps: int, disc_weight=None):
  """``(1 - w) r_task + [step > start] w bonus(D)`` (``DSAC._train_step``); ``step`` is the index of
  the latest env step (0-based). The task reward is scaled by ``1 - w`` even before ``start``.
  ``disc_weight``: see :func:`reward_weight`."""
  w = reward_weight(cfg, step, total_env_steps, disc_weight)
  on = jnp.asarray(step) > cfg.start
  return (1.0 - w) * r_task + jnp.where(on, w * disc_bonus(d, cfg.coef, cfg.reward_clip), 0.0)


def disc_lr(cfg: DiscConfig, step, total_env_steps: int) -> jax.Array:
  """``lr max(0, 1 - step / (stop T))`` (``DSAC.learn``)."""
  return cfg.lr * jnp.maximum(0.0, 1.0 - jnp.asarray(step, jnp.float32) / (cfg.stop * total_env_steps))


class OnlineExpert(NamedTuple):
  """A's frozen LL for online data: its reach env, ``policy_fn(params, obs) -> action`` and params."""
  env: Any
  policy_fn: Callable
  params: Any


def z_extras(state, next_state) -> dict:
  """``make_train``'s ``transition_extras``: the episode's relative sub-goal z (Reach task state) and
  whether the transition starts an episode (when online A restarts on B's z)."""
  t = state.task
  return {"z": t["t"]["z"].astype(jnp.float32), "first": (t["steps"] == 0).astype(jnp.float32)}


def _select(c, a, b):
  return jax.tree_util.tree_map(lambda x, y: jnp.where(c, x, y), a, b)


def _ring_slots(mask, ptr, size, cap):
  """Slots for the rows where ``mask`` is set, in order from ``ptr`` in a ring of ``cap`` rows (index
  ``cap`` elsewhere, which ``.at[].set(mode="drop")`` skips), and the ring's new ``ptr`` and ``size``."""
  idx = jnp.where(mask, (ptr + jnp.cumsum(mask) - 1) % cap, cap)
  k = jnp.sum(mask).astype(jnp.int32)
  return idx, (ptr + k) % cap, jnp.minimum(size + k, cap)


def _draw(bits, n_b, n_a):
  """A class-balanced draw from ``bits[..., 3, batch]``: a fair coin for the class, then a uniform row
  among the ``n_b`` rows of B or the ``n_a`` rows of A. Returns (is_b, row of B, row of A)."""
  is_b = (bits[..., 0, :] & 1) == 1
  row = lambda b, n: (b % jnp.asarray(n).astype(jnp.uint32)).astype(jnp.int32)
  return is_b, row(bits[..., 1, :], n_b), row(bits[..., 2, :], n_a)


def restart_on_z(env, state, z, where, reset_physics, hl_start: bool = False):
  """One reach-env state restarted (where ``where``) on relative goal ``z``: the goal becomes the
  current goal-space point + z, the physics restarts from a fresh start draw where ``reset_physics``
  (as ``DiscriminatorEnv``'s ``expert_env.reset`` + ``set_skill``), from the HL start if ``hl_start``.
  Uses the env's own observation function so A sees exactly what its LL was trained on."""
  fresh = env.initial_physics(jax.random.fold_in(state.key, 1), hl_start)  # a new episode start, as env.step's
  ps = _select(where & reset_physics, fresh, state.physics)
  q = env.quantities(ps)
  t = _select(where, {"goal": q["point"] + z, "z": z}, state.task["t"])
  lo, hi, obs = env.observe(ps, q, t)
  steps = jnp.where(where, 0, state.task["steps"])
  return state.replace(physics=ps, obs=obs, obs_hi=hi, obs_lo=lo,
                       task=dict(state.task, t=t, steps=steps))


@struct.dataclass
class DiscState:
  """The discriminator plug-in's per-seed state (``TrainState.aux["discriminator"]``)."""
  params: Any
  opt_state: Any
  buf: jax.Array  # B's inputs, a ring of cap rows
  ptr: jax.Array
  size: jax.Array
  env_steps: jax.Array
  buf_a: jax.Array | None = None  # online: A's inputs, written in lockstep with buf
  a_state: Any = None  # online: A's envs
  a_prev: jax.Array | None = None  # expert_prev_obs="pre_restart": A's last observation before its restart
  ep: jax.Array | None = None  # held-out episodes (cfg.test_every): episodes begun per B env
  tbuf: jax.Array | None = None  # the held-out ring of B's inputs (and tbuf_a, A's, online)
  tbuf_a: jax.Array | None = None
  tptr: jax.Array | None = None
  tsize: jax.Array | None = None


class Alignment(NamedTuple):
  aux_init: Callable
  aux_update: Callable
  reward_fn: Callable
  transition_extras: Callable | None
  apply: Callable  # apply(params, x) -> logit of B (x in raw goal-space units)
  cfg: DiscConfig

  @property
  def plugin(self) -> Plugin:
    """The alignment as one :class:`hdt.agents.plugins.Plugin` (combinable with others); its hyper
    ``disc_weight`` is the reward weight w0 (``cfg.weight``), vmappable over a grid."""
    return Plugin(name="discriminator", init=lambda key, agent, seed_index: (agent, self.aux_init(key)),
                  update=self.aux_update, reward=self.reward_fn,
                  transition_extras=self.transition_extras, hyper={WEIGHT: float(self.cfg.weight)})


def make_alignment(cfg: DiscConfig, tau_a=None, total_env_steps: int = 1, num_envs: int = 1,
                   tau_scale: float = 1.0, expert: OnlineExpert | None = None) -> Alignment:
  """The make_train plug-ins aligning B's LL to A.

  tau_a: A's fixed inputs, shape (n, cfg.input_size) (``data="fixed"``).
  expert: A's LL and reach env (``data="offline"`` or ``"online"``), its horizon A's time limit; B's
    env must be a reach env too (its task state gives z).
  tau_scale: inputs are divided by it before the MLP (1 = the authors' raw units).
  Its per-seed state is a :class:`DiscState`.
  """
  online = cfg.data != "fixed"  # A runs alongside B
  n_in = cfg.input_size
  if online:
    if expert is None:
      raise ValueError(f"DiscConfig(data={cfg.data!r}) needs expert=OnlineExpert(A's reach env, policy_fn, params)")
  else:
    tau_a = jnp.asarray(tau_a, jnp.float32)
    if tau_a.ndim != 2 or tau_a.shape[1] != n_in or tau_a.shape[0] == 0:
      raise ValueError(f"tau_a must have shape (n, {n_in}) (include_z={cfg.include_z}), got {tau_a.shape}")
  if cfg.include_z or online:
    extras = z_extras
  else:
    extras = None
  net = Discriminator(cfg.hidden_sizes)
  inv = 1.0 / float(tau_scale)
  apply = lambda params, x: net.apply(params, x * inv)
  adam = optax.scale_by_adam()  # the step size is applied by hand: the authors' lr is a function of env steps
  cap, bs, ue, T = cfg.buffer_size, cfg.batch_size, cfg.update_every, int(total_env_steps)
  max_k = math.ceil(num_envs / ue)  # discriminator updates per training step, at most
  te = cfg.test_every if extras is not None else 0  # held-out episodes need episode starts
  cap_t = max(cap // 2, 1)
  carry_prev = online and cfg.expert_prev_obs == "pre_restart"

  def inputs(tr: Any) -> jax.Array:
    return disc_input(tr.obs, tr.next_obs, tr.extras["z"] if cfg.include_z else None)

  def aux_init(key):
    params = net.init(key, jnp.zeros((1, n_in), jnp.float32))
    zero = jnp.zeros((), jnp.int32)
    aux = DiscState(params=params, opt_state=adam.init(params), buf=jnp.zeros((cap, n_in), jnp.float32),
                    ptr=zero, size=zero, env_steps=zero)
    if online:
      a_state = jax.vmap(expert.env.reset)(jax.random.split(key, num_envs))
      aux = aux.replace(buf_a=jnp.zeros((cap, n_in), jnp.float32), a_state=a_state,
                        a_prev=a_state.obs if carry_prev else None)  # the start of A's next row
    if te:
      aux = aux.replace(ep=jnp.zeros((num_envs,), jnp.int32), tbuf=jnp.zeros((cap_t, n_in), jnp.float32),
                        tptr=zero, tsize=zero,
                        tbuf_a=jnp.zeros((cap_t, n_in), jnp.float32) if online else None)
    return aux

  def step_expert(a_state, a_prev, extras, key):
    """A restarts where B's episode starts (on B's z online, on a random goal of its own offline; its
    LL start by A's reset coin), takes one deterministic step, and restarts on B's current z where its
    own episode ended, from a fresh HL start (``cfg.expert_restart``) (``DiscriminatorEnv.reset`` /
    ``step``). Its input row carries B's z either way and, except at B's episode start, begins at
    ``a_prev`` (``cfg.expert_prev_obs``). Returns (A's state, its observation before any restart, row)."""
    env, z, first = expert.env, extras["z"], extras["first"] > 0
    coin = jax.vmap(lambda k: env.task.physics_reset(k, env.agent, jnp.bool_(False), jnp.bool_(True)))(
        jax.random.split(key, z.shape[0]))
    d = env.agent.delta_max
    z0 = z if cfg.data == "online" else jax.random.uniform(jax.random.fold_in(key, 1), z.shape, z.dtype, -d, d)
    s = jax.vmap(lambda s, z, f, c: restart_on_z(env, s, z, f, c))(a_state, z0, first, coin)
    nxt = jax.vmap(env.step)(s, expert.policy_fn(expert.params, s.obs))
    prev = s.obs if a_prev is None else jnp.where(first[:, None], s.obs, a_prev)
    x = disc_input(prev, nxt.next_obs, z if cfg.include_z else None)
    done = nxt.done > 0
    hl = cfg.expert_restart == "high"
    last = nxt.next_obs  # before the restart (equal to the obs where A's episode goes on)
    nxt = jax.vmap(lambda s, z, d: restart_on_z(env, s, z, d, jnp.bool_(True), hl))(nxt, z, done)
    return nxt, last, x

  def one_update(params, opt_state, x, labels, lr):
    (loss, acc), g = jax.value_and_grad(lambda p: disc_loss(apply, p, x, labels), has_aux=True)(params)
    upd, opt_state = adam.update(g, opt_state, params)
    upd = jax.tree_util.tree_map(lambda u: -lr * u, upd)
    return optax.apply_updates(params, upd), opt_state, loss, acc

  def aux_update(aux, transitions, env_steps, key, disc_weight=None):  # disc_weight: w0, see reward_weight
    k_bits, k_a, k_t = jax.random.split(key, 3)
    x_b = inputs(transitions).reshape(-1, n_in)
    n = x_b.shape[0]
    out = aux
    held = jnp.zeros((n,), bool)
    if te:  # DSAC.learn: rows of every te-th episode (1-based count) go to the test buffer
      out = out.replace(ep=aux.ep + (transitions.extras["first"].reshape(n) > 0))
      held = (out.ep % te == 0) & (out.ep >= te)
    # Kept rows fill the training ring from ptr, held rows the test ring from tptr
    idx, ptr, size = _ring_slots(~held, aux.ptr, aux.size, cap)
    write = lambda b, i, x: b.at[i].set(x, mode="drop")
    if online:
      a_state, last, x_a = step_expert(aux.a_state, aux.a_prev, transitions.extras, k_a)
      out = out.replace(a_state=a_state, a_prev=last if carry_prev else None, buf_a=write(aux.buf_a, idx, x_a))
    buf = write(aux.buf, idx, x_b)
    if te:
      tidx, tptr, tsize = _ring_slots(held, aux.tptr, aux.tsize, cap_t)
      out = out.replace(tptr=tptr, tsize=tsize, tbuf=write(aux.tbuf, tidx, x_b),
                        tbuf_a=write(aux.tbuf_a, tidx, x_a) if online else None)
    env_steps = jnp.asarray(env_steps, jnp.int32)
    # The env-step indices s in [prev, env_steps) of this training step with s % update_every == 0
    # get one update each (DSAC.learn: `step % discrim_train_freq == 0 and step / T < stop`).
    prev = env_steps - num_envs
    s0 = ((prev + ue - 1) // ue) * ue
    s_j = s0 + ue * jnp.arange(max_k)
    due = (s_j < env_steps) & (s_j < cfg.stop * T) & (2 * size >= bs)
    # Samples drawn uniformly from the class-balanced buffer: a fair coin for the class, then a row.
    a_src = out.buf_a if online else tau_a
    is_b, i_b, i_a = _draw(jax.random.bits(k_bits, (max_k, 3, bs), jnp.uint32), size,
                           size if online else tau_a.shape[0])

    def body(carry, xs):
      params, opt_state = carry
      on, s, b, ib, ia = xs
      x = jnp.where(b[:, None], buf[ib], a_src[ia])
      labels = jnp.where(b, B_LABEL, A_LABEL)
      p2, o2, loss, acc = one_update(params, opt_state, x, labels, disc_lr(cfg, s, T))
      return _select(on, (p2, o2), (params, opt_state)), (loss, acc)

    (params, opt_state), (loss, acc) = jax.lax.scan(
        body, (aux.params, aux.opt_state), (due, s_j, is_b, i_b, i_a))
    on = due.astype(jnp.float32)
    n_on = jnp.maximum(jnp.sum(on), 1.0)
    step = env_steps - 1
    metrics = {"disc/loss": jnp.sum(loss * on) / n_on, "disc/acc": jnp.sum(acc * on) / n_on,
               "disc/weight": reward_weight(cfg, step, T, disc_weight), "disc/lr": disc_lr(cfg, step, T)}
    if te:  # accuracy on a held-out batch (NaN until the test buffer holds one)
      n_t = jnp.maximum(out.tsize, 1)
      t_is_b, ti, ta = _draw(jax.random.bits(k_t, (3, bs), jnp.uint32), n_t, n_t if online else tau_a.shape[0])
      x = jnp.where(t_is_b[:, None], out.tbuf[ti], (out.tbuf_a if online else tau_a)[ta])
      t_acc = disc_loss(apply, params, x, jnp.where(t_is_b, B_LABEL, A_LABEL))[1]
      metrics["disc/test_acc"] = jnp.where(2 * out.tsize >= bs, t_acc, jnp.nan)
    return out.replace(params=params, opt_state=opt_state, buf=buf, ptr=ptr, size=size, env_steps=env_steps), metrics

  def reward_fn(aux, batch, disc_weight=None):
    d = jax.nn.sigmoid(apply(aux.params, inputs(batch)))
    return shaped_reward(cfg, batch.reward, d, aux.env_steps - 1, T, disc_weight)

  return Alignment(aux_init, aux_update, reward_fn, extras, apply, cfg)
