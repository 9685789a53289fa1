"""SAC training as pure, vmappable functions, plus a host-side driver.

``make_train(env, config)`` returns a :class:`Trainer` whose functions are pure and work under
``jax.jit(jax.vmap(...))`` over a leading seed axis (that is how seed sweeps run)::

    trainer = make_train(env, SACConfig(total_env_steps=20_000))
    keys = seed_keys(range(4))
    ts = jax.jit(jax.vmap(trainer.init))(keys, seed_indices(4))
    ts, metrics = jax.jit(jax.vmap(trainer.run_chunk), donate_argnums=0)(ts)
    ev = jax.jit(jax.vmap(trainer.evaluate))(ts.agent.deployed_policy, eval_keys, ts.agent.obs_norm)
    ts, out = jax.jit(jax.vmap(trainer.train))(keys)           # everything in one call

(:func:`vmapped` builds and caches exactly these jitted functions), or use :func:`run`, which
loops chunks on the host, evaluates and reports progress.

One *training step* = policy actions for the ``num_envs`` parallel envs (uniform-random while
fewer than ``learning_starts`` env steps have been taken) -> vmapped ``env.step`` -> insert the
transitions ``(obs, action, next.reward, next.next_obs, next.discount)`` into the replay ->
the plug-ins' ``update`` (:mod:`hdt.agents.plugins`) -> ``updates_per_step`` gradient updates in a ``lax.scan`` (skipped
while fewer than ``learning_starts`` env steps have been taken). A *chunk* is ``steps_per_chunk``
training steps in one ``lax.scan``; the host sees the state only between chunks.
"""

from __future__ import annotations

import dataclasses
import functools
import sys
import time
from typing import Any, Callable, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from hdt import cache
from hdt.agents import acting
from hdt.agents import networks as nets
from hdt.agents import plugins as plugin_lib
from hdt.agents import normalizer
from hdt.agents import sharding as sharding_lib
from hdt.agents import replay as replay_lib
from hdt.agents.replay import Transition
from hdt.agents.sac import (
    SWEEPABLE,
    SACConfig,
    SACState,
    init_sac_state,
    make_update,
)


@struct.dataclass
class TrainState:
  """Everything needed to resume training (all arrays; a leading seed axis under vmap)."""

  agent: SACState  # policy/q params, target q params, optimiser states, log_alpha (+opt), update count,
  # observation statistics (None without normalisation)
  replay: replay_lib.ReplayState
  env_state: Any  # hdt.envs.core.State batched over num_envs
  key: jax.Array
  env_steps: jax.Array  # int32, env steps taken (summed over parallel envs)
  episode_return: jax.Array  # (num_envs,) float32, running return of the current training episodes
  aux: Any  # {plug-in name: its per-seed state} (e.g. a DiscState, a KLState); {} without plug-ins
  # env step at which this seed's training went NaN/inf, -1 while it is finite; from then on its agent and
  # plug-in state stay as they were before that chunk, while the other seeds of the program train on
  diverged_at: jax.Array


class Trainer(NamedTuple):
  init: Callable[[jax.Array, Any], TrainState]  # (seed key, seed index=0)
  run_chunk: Callable[[TrainState], tuple[TrainState, dict]]
  evaluate: Callable[[Any, jax.Array], dict]
  train: Callable[[jax.Array], tuple[TrainState, dict]]
  networks: nets.SACNetworks
  config: SACConfig
  sweepable: tuple[str, ...] = SWEEPABLE  # what run(hyper=...) may vary: SWEEPABLE + the plug-ins' hyper
  native_physics: bool = False  # the physics is a custom call (not XLA ops): see RUN_ONCE


def physics_backend(env) -> str | None:
  """The physics backend ("native", "mjx") of ``env`` or of the env it wraps (an HL env); None if unknown."""
  return getattr(env, "backend", None) or getattr(getattr(env, "env", None), "backend", None)


def plugin_key(key: jax.Array, index: int) -> jax.Array:
  """The key plug-in ``index`` gets from a plug-in key of make_train (the first plug-in gets it
  unchanged, so a run with one plug-in draws what it drew before plug-ins were lists)."""
  return key if index == 0 else jax.random.fold_in(key, index)


def saved_params(agent: SACState) -> dict:
  """What a checkpoint keeps of ``agent``: {"policy", "q"} and, with a normaliser, its statistics
  beside them as "obs_norm" (:mod:`hdt.agents.normalizer`)."""
  out = {"policy": agent.deployed_policy, "q": agent.q_params}
  return out if agent.obs_norm is None else dict(out, **{normalizer.KEY: agent.obs_norm})


NONFINITE = "nonfinite/"  # run_chunk metrics prefix: first non-finite step in the chunk, or -1


def _all_finite(tree) -> jax.Array:
  leaves = [jnp.all(jnp.isfinite(x)) for x in jax.tree_util.tree_leaves(tree)
            if jnp.issubdtype(jnp.asarray(x).dtype, jnp.inexact)]
  return jnp.all(jnp.stack(leaves)) if leaves else jnp.ones((), bool)


def _nonfinite_flags(m: dict, ts: "TrainState") -> dict:
  """Per loss term, the index of the chunk's first training step where it was NaN/inf (-1: none);
  parameters and plug-in state are checked once, at the end of the chunk (index steps-1). Computed
  inside the jitted chunk so that the host can stop at the first bad chunk for a few bytes."""
  def first_bad(ok_per_step):
    bad = ~ok_per_step
    return jnp.where(jnp.any(bad), jnp.argmax(bad), -1).astype(jnp.int32)

  per_step = {k: v for k, v in m["update"].items() if k.endswith("loss")}
  per_step |= {k: v for k, v in m["aux"].items() if k.endswith("loss")}
  flags = {NONFINITE + k: first_bad(jnp.isfinite(v).reshape(v.shape[0], -1).all(axis=1))
           for k, v in per_step.items()}
  last = m["learn"].shape[0] - 1
  for name, tree in (("parameters", ts.agent), ("aux_state", ts.aux)):
    flags[NONFINITE + name] = jnp.where(_all_finite(tree), -1, last).astype(jnp.int32)
  return flags


def _freeze_diverged(start: "TrainState", ts: "TrainState", flags: dict, n_envs: int) -> "TrainState":
  """``ts`` after a chunk from ``start``, with a seed whose chunk went NaN/inf (``flags``), or that had
  diverged before, kept at its agent and plug-in state of ``start`` (its last finite ones) and its
  ``diverged_at`` set: one seed's divergence does not stop the others (a select per chunk, not per step)."""
  firsts = jnp.stack(list(flags.values()))
  bad = jnp.any(firsts >= 0)
  first = jnp.min(jnp.where(firsts >= 0, firsts, jnp.iinfo(jnp.int32).max))
  was_alive = start.diverged_at < 0
  diverged_at = jnp.where(was_alive & bad, start.env_steps + (first + 1) * n_envs, start.diverged_at)
  keep = diverged_at < 0
  pick = lambda new, old: jax.tree_util.tree_map(lambda a, b: jnp.where(keep, a, b), new, old)
  return ts.replace(agent=pick(ts.agent, start.agent), aux=pick(ts.aux, start.aux),
                    diverged_at=diverged_at.astype(jnp.int32))


class TrainingDiverged(FloatingPointError):
  """A loss term or the parameters became NaN/inf; raised by :func:`run` after the bad chunk."""

  def __init__(self, message: str, term: str, env_step: int, seeds: list):
    super().__init__(message)
    self.term, self.env_step, self.seeds = term, env_step, seeds


def first_nonfinite(flags: dict, chunk_start: int, num_envs: int, seeds: Sequence) -> tuple | None:
  """(env step, term, [seeds]) of the first non-finite term of a chunk's ``nonfinite/`` flags (per seed
  arrays): the earliest env step, then the order critic, actor, alpha, plug-in losses, parameters;
  None when all are finite."""
  priority = {"critic_loss": 0, "actor_loss": 1, "alpha_loss": 2, "parameters": 4, "aux_state": 5}
  worst = None
  for k, v in flags.items():
    order = priority.get(k[len(NONFINITE):], 3)  # the order they are computed in
    v = np.asarray(v).reshape(-1)
    bad = np.flatnonzero(v >= 0)
    if bad.size:
      step = chunk_start + (int(v[bad].min()) + 1) * num_envs
      cand = (step, order, k[len(NONFINITE):], [seeds[i] for i in bad if v[i] == v[bad].min()])
      worst = min(worst, cand) if worst else cand
  return None if worst is None else (worst[0], worst[2], worst[3])


def _what(term: str) -> str:
  return "the network/temperature parameters" if term == "parameters" else (
      "the plug-in (e.g. discriminator) state" if term == "aux_state" else term)


_ADVICE = ("Try lower learning rates (actor_lr/critic_lr/alpha_lr) or reward_scale, and check the environment "
           "and reward plug-ins for NaN/inf rewards or observations.")


def check_finite(flags: dict, chunk_start: int, num_envs: int, seeds: Sequence[int]) -> None:
  """Raises :class:`TrainingDiverged` naming :func:`first_nonfinite` of a chunk's flags, if any."""
  first = first_nonfinite(flags, chunk_start, num_envs, seeds)
  if first is None:
    return
  step, term, bad_seeds = first
  raise TrainingDiverged(
      f"{_what(term)} became NaN/inf at env step {step} (seed{'s' if len(bad_seeds) > 1 else ''} "
      f"{', '.join(map(str, bad_seeds))}); training stopped there. {_ADVICE}", term, step, bad_seeds)


def _report_diverged(flags: dict, before: np.ndarray, now: np.ndarray, chunk_start: int, num_envs: int,
                     labels: Sequence) -> None:
  """After a chunk: raises :class:`TrainingDiverged` when no run is left finite; else one warning line
  per run that diverged in it (``before``/``now``: every run's ``diverged_at``), which the program
  keeps at its last finite state while the others train on."""
  newly = np.flatnonzero((now >= 0) & (before < 0))
  if not newly.size:
    return
  mine = {k: np.asarray(v).reshape(-1)[newly] for k, v in flags.items()}
  if np.all(now >= 0):
    check_finite(mine, chunk_start, num_envs, [labels[i] for i in newly])
  left = int(np.sum(now < 0))
  for j, i in enumerate(newly):
    step, term, _ = first_nonfinite({k: v[j:j + 1] for k, v in mine.items()}, chunk_start, num_envs, [labels[i]])
    print(f"warning: {_what(term)} became NaN/inf at env step {step} (seed {labels[i]}); that seed stays at its "
          f"last finite state (env step {chunk_start}) and {left} other run{'s' if left > 1 else ''} train on. "
          f"{_ADVICE}", file=sys.stderr, flush=True)


def _uniform01_from_bits(bits: jax.Array) -> jax.Array:
  """float32 in [0, 1) from uint32 bits (23 random mantissa bits, as jax.random.uniform)."""
  mantissa = jnp.right_shift(bits, jnp.uint32(9)) | jnp.uint32(0x3F800000)
  return jax.lax.bitcast_convert_type(mantissa, jnp.float32) - 1.0


def _normal_from_bits(bits: jax.Array) -> jax.Array:
  """Standard normal float32 from uint32 bits via sqrt(2) erfinv(u), u in (-1, 1) (as jax.random.normal)."""
  u = 2.0 * _uniform01_from_bits(bits) - 1.0
  u = jnp.maximum(u, jnp.nextafter(jnp.float32(-1.0), jnp.float32(0.0)))
  return jnp.float32(np.sqrt(2.0)) * jax.lax.erf_inv(u)


def make_networks(env, config: SACConfig) -> nets.SACNetworks:
  """The SAC networks make_train builds for ``env`` and ``config`` (pure functions; cheap)."""
  return nets.make_sac_networks(
      int(env.observation_size), int(env.action_size), config.hidden_sizes, config.critic_sizes,
      value_net=config.value_net, critic_layer_norm=config.critic_layer_norm)


def delayed_actor_group(update, d: int):
  """``group(agent, xs) -> (agent, metrics)``: ``d`` updates on ``xs`` (leading axis d), d - 1 of the critic
  only, then a whole one, unrolled (static: vmapped seeds really skip the actor, no cond). ``update(agent,
  xs_i, actor=)``. The critic's metrics average the d updates; the others are the one that stepped the actor."""
  def group(agent, xs):
    pick = lambda i: jax.tree_util.tree_map(lambda x: x[i], xs)
    critic = []
    for i in range(d - 1):
      agent, m = update(agent, pick(i), actor=False)
      critic.append(m)
    agent, m = update(agent, pick(d - 1))
    return agent, dict(m, **{k: jnp.mean(jnp.stack([c[k] for c in critic] + [m[k]]), axis=0) for k in critic[0]})
  return group


def make_train(
    env,
    config: SACConfig,
    *,
    networks: nets.SACNetworks | None = None,
    plugins: Sequence[plugin_lib.Plugin] = (),
) -> Trainer:
  """Builds the pure functions ``init``, ``run_chunk``, ``evaluate`` and ``train``.

  plugins: :class:`hdt.agents.plugins.Plugin` objects (init, update, reward, regularizer, schedule,
    transition_extras; each optional), folded over in order. The per-seed state of each plug-in with an
    ``init`` is ``TrainState.aux[<name>]``. Plug-in ``i`` gets the key :func:`plugin_key` ``(seed key, i)`` and the seed's
    index at init and a per-step key derived the same way. Every regulariser is added to the actor
    loss times its own schedule, logged as ``<name>`` and ``<name>_weight``; every plug-in's
    transition extras are stored under its name and handed back to it alone. Their declared
    ``hyper`` names join ``Trainer.sweepable``.
  networks: the SAC networks (default :func:`make_networks`).
  """
  obs_size, act_size = int(env.observation_size), int(env.action_size)
  networks = make_networks(env, config) if networks is None else networks
  plugins = plugin_lib.check(plugins)
  sweepable = SWEEPABLE + plugin_lib.sweepable(plugins, SWEEPABLE)
  n_envs, batch_size = config.num_envs, config.batch_size
  v_reset, v_step = jax.vmap(env.reset), jax.vmap(env.step)
  deterministic_policy = lambda obs_norm: lambda params, obs: nets.deterministic_action(
      networks.policy_apply(params, obs, obs_norm)[0])
  spec = replay_lib.make_transition_spec(obs_size, act_size, with_done=config.n_step > 1)
  extending = [p for p in plugins if p.transition_extras is not None]

  def extras_fn(state, next_state):  # {plug-in name: its extras of one transition}
    return {p.name: p.transition_extras(state, next_state) for p in extending}

  if extending:
    one = jax.eval_shape(env.reset, jax.random.PRNGKey(0))
    spec = spec.replace(extras=jax.tree_util.tree_map(
        lambda s: np.zeros(s.shape, s.dtype), jax.eval_shape(extras_fn, one, one)))

  regularizing = [p for p in plugins if p.regularizer is not None]
  rewarding = [p for p in plugins if p.reward is not None]
  if rewarding and config.n_step > 1:
    raise ValueError(f"n_step={config.n_step} cannot be combined with the reward of plug-in "
                     f"{rewarding[0].name!r} (it rewrites one-step rewards): use n_step=1")
  value = plugin_lib.values  # a plug-in's hyper values: hyper's (grid point) or its defaults
  # what a plug-in sees of a transition's (or a batch's) extras: its own
  seen = lambda p, tr: tr if not extending else tr.replace(extras=tr.extras.get(p.name))

  def weights(env_steps, hyper) -> dict:
    """Each regulariser's weight at ``env_steps``: its own schedule's, 1 without one."""
    return {p.name: jnp.ones((), jnp.float32) if p.schedule is None else
            jnp.asarray(p.schedule(env_steps, **value(p, hyper)), jnp.float32) for p in regularizing}

  def plugin_reward(aux, batch, hyper):
    for p in rewarding:
      r = p.reward(aux.get(p.name), seen(p, batch), **value(p, hyper))
      batch = batch.replace(reward=r.astype(batch.reward.dtype))
    return batch.reward

  def make_update_with(aux, reg_weights, hyper):
    """One gradient update whose actor regularisers see their plug-ins' states (per seed), each times
    its weight; logged as ``<name>`` and ``<name>_weight``."""
    reg = None
    if regularizing:
      def reg(params, obs, *obs_norm):  # obs_norm: only with a normaliser (hdt.agents.sac)
        terms = {p.name: p.regularizer(aux.get(p.name), params, obs, *obs_norm, **value(p, hyper))
                 for p in regularizing}
        total = sum(reg_weights[name] * term for name, term in terms.items())
        return total, terms | {f"{name}_weight": w for name, w in reg_weights.items()}
    return make_update(networks, config, act_size, actor_regularizer=reg,
                       reward_fn=(lambda aux, batch: plugin_reward(aux, batch, hyper)) if rewarding else None)

  def plugins_init(key, agent, seed_index):
    aux = {}
    for i, p in enumerate(plugins):
      if p.init is not None:
        agent, aux[p.name] = p.init(plugin_key(key, i), agent, seed_index)
    return agent, aux

  def plugins_update(aux, transitions, env_steps, key, hyper):
    aux, metrics = dict(aux), {}
    for i, p in enumerate(plugins):
      if p.update is not None:
        state, m = p.update(aux.get(p.name), seen(p, transitions), env_steps, plugin_key(key, i),
                            **value(p, hyper))
        if p.name in aux:
          aux[p.name] = state
        metrics.update(m)
    return aux, metrics

  # ---------------------------------------------------------------------------------------------
  def init(key: jax.Array, seed_index=0) -> TrainState:
    """The TrainState of the seed whose key is ``key``; ``seed_index``: its place in the run's seeds
    (as plug-ins see it: e.g. which of another run's seeds it starts from)."""
    k_agent, k_env, k_aux, k_next = jax.random.split(key, 4)
    agent, aux = plugins_init(k_aux, init_sac_state(networks, config, k_agent), seed_index)
    return TrainState(
        agent=agent,
        replay=replay_lib.init(config.buffer_size, spec),
        env_state=v_reset(jax.random.split(k_env, n_envs)),
        key=k_next,
        env_steps=jnp.zeros((), jnp.int32),
        episode_return=jnp.zeros((n_envs,), jnp.float32),
        aux=aux,
        diverged_at=jnp.full((), -1, jnp.int32),
    )

  # ---------------------------------------------------------------------------------------------
  # All the randomness of one training step comes from ONE jax.random.bits call (threefry is
  # slow to compile on CPU, about 0.3 s per call site under vmap): per env, 2*A words (policy noise,
  # random action); per gradient update, B words (replay indices) + 2*B*A words (critic and actor
  # noise).
  G, A = config.updates_per_step, act_size
  n_act_bits = n_envs * 2 * A
  n_upd_bits = batch_size * (1 + 2 * A)

  def sample_batches(replay, bits):
    """G batches (leading axes (G, B)) and their reparameterisation noise (G, 2, B, A)."""
    bits = bits.reshape(G, n_upd_bits)
    if config.n_step == 1:
      batches = replay_lib.sample_from_bits(replay, bits[:, :batch_size])
    else:
      flat = replay_lib.sample_n_step_from_bits(
          replay, bits[:, :batch_size].reshape(-1), config.n_step, n_envs, config.gamma)
      batches = jax.tree_util.tree_map(lambda x: x.reshape((G, batch_size) + x.shape[1:]), flat)
    noise = _normal_from_bits(bits[:, batch_size:]).reshape(G, 2, batch_size, A)
    return batches, noise

  def gradient_updates(agent: SACState, batches, noise, aux, reg_weights, hyper):
    update = make_update_with(aux, reg_weights, hyper)
    sac_hyper = None if hyper is None else {k: v for k, v in hyper.items() if k in SWEEPABLE}

    d = config.policy_delay

    def one(agent, xs, actor=True):
      batch, eps = xs
      return update(agent, batch, eps, aux, sac_hyper, actor=actor)

    if d == 1:
      agent, m = jax.lax.scan(one, agent, (batches, noise))
    else:
      grouped = jax.tree_util.tree_map(lambda x: x.reshape((G // d, d) + x.shape[1:]), (batches, noise))
      agent, m = jax.lax.scan(delayed_actor_group(one, d), agent, grouped)
    return agent, jax.tree_util.tree_map(lambda x: jnp.mean(x, axis=0), m)

  def train_step(ts: TrainState, hyper):
    key, k_aux, k_bits = jax.random.split(ts.key, 3)
    bits = jax.random.bits(k_bits, (n_act_bits + G * n_upd_bits,), jnp.uint32)
    act_bits, upd_bits = bits[:n_act_bits].reshape(2, n_envs, A), bits[n_act_bits:]
    obs = ts.env_state.obs
    loc, scale = networks.policy_apply(ts.agent.policy_params, obs, ts.agent.obs_norm)
    policy_action, _ = nets.sample_from_noise(loc, scale, _normal_from_bits(act_bits[0]))
    random_action = 2.0 * _uniform01_from_bits(act_bits[1]) - 1.0
    warmup = ts.env_steps < config.learning_starts
    action = jnp.where(warmup, random_action, policy_action)

    nxt = v_step(ts.env_state, action)
    f32 = lambda x: jnp.asarray(x, jnp.float32)
    agent = ts.agent
    if agent.obs_norm is not None:  # it sees every collected observation before the updates use it
      agent = agent.replace(obs_norm=normalizer.update(agent.obs_norm, obs))
    transitions = Transition(
        obs=f32(obs), action=f32(action), reward=f32(nxt.reward), next_obs=f32(nxt.next_obs),
        discount=f32(nxt.discount) if config.bootstrap_time_limits else 1.0 - f32(nxt.done),
        extras=jax.vmap(extras_fn)(ts.env_state, nxt) if extending else None,
        done=f32(nxt.done) if config.n_step > 1 else None,
    )
    env_steps = ts.env_steps + n_envs
    aux, aux_metrics = plugins_update(ts.aux, transitions, env_steps, k_aux, hyper)

    # Insert, then gather all G batches, outside the lax.cond. Measured on CPU: gathering from
    # the pre-insert buffer, or passing the buffer into the cond, made XLA copy the whole buffer
    # every step (O(capacity) per step instead of O(num_envs)); see also replay._take_rows.
    replay = replay_lib.insert(ts.replay, transitions)
    batches, noise = sample_batches(replay, upd_bits)
    learn = env_steps >= config.learning_starts
    upd = lambda agent: gradient_updates(agent, batches, noise, aux, weights(env_steps, hyper), hyper)
    _, metrics_shape = jax.eval_shape(upd, ts.agent)
    skip = lambda agent: (
        agent, jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), metrics_shape)
    )
    agent, upd_metrics = jax.lax.cond(learn, upd, skip, agent)

    done = f32(nxt.done)
    ep_ret = ts.episode_return + f32(nxt.reward)
    new_ts = TrainState(
        agent=agent,
        replay=replay,
        env_state=nxt,
        key=key,
        env_steps=env_steps,
        episode_return=ep_ret * (1.0 - done),
        aux=aux,
        diverged_at=ts.diverged_at,
    )
    step_metrics = {
        "update": upd_metrics,
        "aux": aux_metrics,
        "learn": f32(learn),
        "episode_return_sum": jnp.sum(ep_ret * done),
        "episodes": jnp.sum(done),
    }
    return new_ts, step_metrics

  def run_chunk(ts: TrainState, hyper: dict | None = None) -> tuple[TrainState, dict]:
    """``steps_per_chunk`` training steps; returns chunk-averaged scalar metrics. ``hyper``: values of
    ``sweepable`` names (per grid point under vmap): SAC fields (:func:`hdt.agents.sac.make_update`)
    and the plug-ins' hyper (:mod:`hdt.agents.plugins`)."""
    check_names(hyper or {}, sweepable)
    start = ts
    ts, m = jax.lax.scan(lambda ts, _: train_step(ts, hyper), ts, None, length=config.steps_per_chunk)
    flags = _nonfinite_flags(m, ts)
    ts = _freeze_diverged(start, ts, flags, n_envs)
    n_learn = jnp.sum(m["learn"])
    learn_mean = lambda x: jnp.sum(x * m["learn"]) / jnp.maximum(n_learn, 1.0)
    metrics = {k: learn_mean(v) for k, v in m["update"].items()}
    metrics.update({k: jnp.mean(v, axis=0) for k, v in m["aux"].items()})
    episodes = jnp.sum(m["episodes"])
    metrics["train_episode_return"] = jnp.where(
        episodes > 0, jnp.sum(m["episode_return_sum"]) / jnp.maximum(episodes, 1.0), jnp.nan
    )
    metrics["train_episodes"] = episodes
    metrics["env_steps"] = ts.env_steps
    metrics["update_steps"] = ts.agent.update_steps
    metrics.update(flags)
    return ts, metrics

  # ---------------------------------------------------------------------------------------------
  def evaluate(policy_params, key: jax.Array, obs_norm=None) -> dict:
    """Deterministic (tanh(mean)) rollouts of ``num_eval_episodes`` parallel episodes
    (:func:`hdt.agents.acting.evaluate`); ``obs_norm``: the policy's observation statistics
    (``SACState.obs_norm``), None without normalisation."""
    return acting.evaluate(env, deterministic_policy(obs_norm), policy_params, key, config.num_eval_episodes)

  # ---------------------------------------------------------------------------------------------
  def train(key: jax.Array, hyper: dict | None = None) -> tuple[TrainState, dict]:
    """init + all chunks + a final evaluation: ``(ts, {"train": per-chunk metrics, "eval": ...})``."""
    k_init, k_eval = jax.random.split(key)
    ts = init(k_init)
    ts, chunk_metrics = jax.lax.scan(
        lambda ts, _: run_chunk(ts, hyper), ts, None, length=config.num_chunks
    )
    return ts, {"train": chunk_metrics, "eval": evaluate(ts.agent.deployed_policy, k_eval, ts.agent.obs_norm)}

  return Trainer(init, run_chunk, evaluate, train, networks, config, sweepable,
                 native_physics=physics_backend(env) == "native")


# ------------------------------------------------------------------------------------------------
# Host-side driver.


class RunResult(NamedTuple):
  params: dict  # saved_params: {"policy", "q"} (+ "obs_norm"), leading axis = seeds
  history: dict  # name -> np.ndarray, leading axis = seeds
  state: TrainState  # final TrainState (leading axis = seeds), for checkpointing / resuming
  best: dict | None = None  # see :func:`update_best`


# Model selection as the authors did (bot_transfer/utils/trainer.py callback): after each periodic
# evaluation, a seed whose mean of the SACConfig.best_by metric (the eval return by default) beats its
# best so far keeps those params.
def best_criterion(config: SACConfig) -> str:
  """The history key whose per-seed mean picks the best parameters."""
  return f"eval/{config.best_by}"


def empty_best(params: dict) -> dict:
  """The best-so-far record before any evaluation: ``params`` (:func:`saved_params`, seed axis; arrays
  or ShapeDtypeStructs) with ``score`` -inf and ``env_steps`` -1 per seed; ``score`` is the per-seed mean
  of :func:`best_criterion`."""
  n = jax.tree.leaves(params)[0].shape[0]
  return dict(params, **{"score": np.full(n, -np.inf, np.float32), "env_steps": np.full(n, -1, np.int32)})


def update_best(best: dict, params: dict, score: np.ndarray, step: int) -> dict:
  """Per seed, ``params`` and ``score`` replace the record where ``score`` is strictly higher
  (the earliest evaluation wins ties; NaN never wins). Host numpy in and out."""
  better = np.asarray(score) > best["score"]
  if not better.any():
    return best
  pick = lambda old, new: np.where(better.reshape(better.shape + (1,) * (np.ndim(new) - 1)), new, old)
  out = {k: jax.tree.map(pick, best[k], jax.tree.map(np.asarray, params[k])) for k in params}
  return dict(out, **{"score": pick(best["score"], np.asarray(score, np.float32)),
                      "env_steps": pick(best["env_steps"], np.full(better.shape, step, np.int32))})


def seed_list(seeds: int | Sequence[int]) -> list[int]:
  """``seeds`` as a list: an int n means ``0..n-1``; a list must hold distinct ints >= 0."""
  if isinstance(seeds, (bool, np.bool_)) or not isinstance(seeds, (int, np.integer, Sequence, np.ndarray)):
    raise ValueError(f"seeds={seeds!r}: pass a number of seeds (e.g. 3 for seeds 0, 1, 2) or a list of "
                     f"seeds (e.g. [0, 5])")
  if isinstance(seeds, (int, np.integer)):
    if seeds <= 0:
      raise ValueError(f"seeds={seeds}: the number of seeds must be positive (e.g. seeds=1), or pass a "
                       f"list of seeds such as [0]")
    return list(range(int(seeds)))
  out = list(seeds)
  if not out or any(isinstance(s, (bool, np.bool_)) or not isinstance(s, (int, np.integer)) or s < 0
                    for s in out):
    raise ValueError(f"seeds={seeds!r}: give a non-empty list of integers >= 0, e.g. [0, 1, 2]")
  if len(set(out)) != len(out):
    raise ValueError(f"seeds={seeds!r}: seeds repeat, so those runs would be identical; list each once")
  return [int(s) for s in out]


def seed_keys(seeds: Sequence[int]) -> np.ndarray:
  """The training keys :func:`run` uses: ``PRNGKey(seed)`` stacked over seeds, as host numpy.

  For the default threefry keys and seeds in [0, 2**31) the key is ``[0, seed]`` (jax's
  ``threefry_seed``), built here without the small programs eager ``PRNGKey`` compiles: a warm
  start (:func:`hdt.cache.compiled_all`) then compiles nothing."""
  seeds = [int(s) for s in seeds]
  if jax.config.jax_default_prng_impl == "threefry2x32" and all(0 <= s < 2**31 for s in seeds):
    return np.array([[0, s] for s in seeds], np.uint32).reshape(len(seeds), 2)
  return np.stack([np.asarray(jax.random.PRNGKey(s)) for s in seeds])


def seed_indices(num_seeds: int, points: int = 1) -> np.ndarray:
  """Each run's seed index (its place in the seeds) for :attr:`VmappedFns.init`: ``0..S-1`` per grid
  point, point-major as :func:`run` lays the runs out."""
  return np.tile(np.arange(num_seeds, dtype=np.int32), points)


def eval_key(seed_key: jax.Array, index: int) -> jax.Array:
  """The key of :func:`run`'s ``index``-th evaluation (0 = before the first chunk, c = after chunk c)."""
  return jax.random.fold_in(jax.random.fold_in(seed_key, 0x5EED), index)


class VmappedFns(NamedTuple):
  init: Callable  # (keys[S], seed indices[S]) -> TrainState[S]
  run_chunk: Callable  # TrainState[S] (, hyper[S]) -> (TrainState[S], metrics[S]); donates the state
  evaluate: Callable  # (policy_params[S], keys[S], obs_norm[S] or None) -> metrics[S]
  eval_keys: Callable  # (seed keys[S], int32 index) -> keys[S] of that evaluation (eval_key)


# XLA's backend optimisation level per program, for a shorter cold start (BENCHMARKS.md, start-up).
# Init and the evaluation keys run once, and over native physics the evaluation is bound by the
# custom call: without the backend's passes they compile in about half the time and run as fast
# (not MJX's, whose physics is XLA ops). The chunk at level 1 compiles faster than at the default and
# runs as fast on both backends.
RUN_ONCE = {"xla_backend_optimization_level": 0}
CHUNK = {"xla_backend_optimization_level": 1}


@functools.lru_cache(maxsize=16)
def vmapped(trainer: Trainer, num_seeds: int = 1, hyper: bool = False) -> VmappedFns:
  """``jit(vmap(...))`` of the trainer's functions over a leading seed axis, cached per trainer;
  with several devices the seeds are split across them (:mod:`hdt.agents.sharding`). With
  ``hyper``, ``run_chunk(ts, hyper)`` also takes per-seed hyper-parameters (:func:`run`'s grid).

  ``run_chunk`` donates the TrainState (the replay is updated in place): do not reuse its input.
  """
  mesh = sharding_lib.seed_mesh(num_seeds)
  over = lambda fn, n=1: sharding_lib.over_seeds(jax.vmap(fn), mesh, n)
  chunk = (lambda ts, h: trainer.run_chunk(ts, h)) if hyper else (lambda ts: trainer.run_chunk(ts))
  return VmappedFns(
      init=jax.jit(over(trainer.init, 2), compiler_options=RUN_ONCE),
      run_chunk=jax.jit(over(chunk, 2 if hyper else 1), donate_argnums=0, compiler_options=CHUNK),
      evaluate=jax.jit(over(trainer.evaluate, 3), compiler_options=RUN_ONCE if trainer.native_physics else None),
      eval_keys=jax.jit(jax.vmap(eval_key, in_axes=(0, None)), compiler_options=RUN_ONCE),
  )


def check_names(hyper, sweepable: Sequence[str] = SWEEPABLE) -> None:
  """Refuses (one line, listing what can be vmapped) names of ``hyper`` not in ``sweepable``."""
  unknown = set(hyper) - set(sweepable)
  if unknown:
    raise ValueError(f"hyper-parameters {sorted(unknown)} cannot be vmapped (they change shapes, or are "
                     f"neither SAC fields nor the plug-ins' weights); vmappable: {', '.join(sweepable)}")


def grid_points(grid: dict | None, sweepable: Sequence[str] = SWEEPABLE) -> list[dict]:
  """``{name: [v1, ..., vP]}`` (names of ``sweepable``, e.g. :attr:`Trainer.sweepable`: the fields of
  hdt.agents.sac.SWEEPABLE and the plug-ins' hyper; all lists of one length P) as the P points
  ``[{name: v_i}]``; None -> ``[{}]``."""
  if not grid:
    return [{}]
  check_names(grid, sweepable)
  sizes = {k: len(v) for k, v in grid.items()}
  if len(set(sizes.values())) != 1 or 0 in sizes.values():
    raise ValueError(f"hyper={grid!r}: give every field the same number (> 0) of values, one per grid "
                     f"point (lengths {sizes})")
  return [dict(zip(grid, vals)) for vals in zip(*grid.values())]


def _ahead_of_time(fns: VmappedFns, key: str, keys: jax.Array, hyper: dict | None) -> VmappedFns:
  """``fns`` as programs loaded from (or compiled into) :func:`hdt.cache.compiled_all` under ``key``;
  abstract arguments are only traced when nothing was saved yet."""
  keys_a = jax.ShapeDtypeStruct(keys.shape, keys.dtype)
  index_a = jax.ShapeDtypeStruct(keys.shape[:1], jnp.int32)
  ts_a = functools.cache(lambda: jax.eval_shape(fns.init, keys_a, index_a))
  hyper_a = () if hyper is None else ({k: jax.ShapeDtypeStruct(keys.shape[:1], jnp.float32) for k in hyper},)
  # the chunk first: the largest compile, which the others' lowering and compiling then overlap
  chunk, init, evaluate, eval_keys = cache.compiled_all([
      (fns.run_chunk, key + "|run_chunk", lambda: (ts_a(), *hyper_a)),
      (fns.init, key + "|init", lambda: (keys_a, index_a)),
      (fns.evaluate, key + "|evaluate", lambda: (ts_a().agent.deployed_policy, keys_a, ts_a().agent.obs_norm)),
      (fns.eval_keys, key + "|eval_keys", lambda: (keys_a, jax.ShapeDtypeStruct((), jnp.int32))),
  ])
  return VmappedFns(init=init, run_chunk=chunk if hyper is None else (lambda ts, h: chunk(ts, h)),
                    evaluate=evaluate, eval_keys=eval_keys)


def run(
    env,
    config: SACConfig,
    seeds: int | Sequence[int] = 1,
    progress_fn: Callable[[int, dict], None] | None = None,
    eval_every: int | None = None,
    *,
    initial_state: TrainState | None = None,
    eval_at_start: bool = True,
    trainer: Trainer | None = None,
    initial_history: dict | None = None,
    initial_best: dict | None = None,
    on_chunk: Callable[[int, TrainState, dict, dict | None], None] | None = None,
    hyper: dict | None = None,
    cache_key: str | None = None,
    networks: nets.SACNetworks | None = None,
    plugins: Sequence[plugin_lib.Plugin] = (),
) -> RunResult:
  """Trains ``len(seeds)`` seeds in lock-step (vmapped) and returns params and history.

  seeds: an int n means seeds ``0..n-1``; a list gives the seeds explicitly.
  eval_every: env steps between deterministic evaluations; must be a multiple of
    ``config.env_steps_per_chunk``. None evaluates after every chunk; the last chunk is always
    evaluated.
  progress_fn(env_steps, metrics): called after every chunk with a dict of per-seed numpy arrays
    (training metrics, and ``eval/...`` entries when an evaluation ran).
  initial_state: a TrainState (with seed axis) to resume from instead of initialising; training
    continues from its ``env_steps`` up to ``config.total_env_steps``.
  eval_at_start: also evaluate before the first chunk (the untrained / resumed policy).
  trainer: a :class:`Trainer` from ``make_train(env, config, ...)`` to reuse (with its compiled
    functions, see :func:`vmapped`); its config may differ from ``config`` only in
    ``total_env_steps``. Without it, ``make_train(env, config, networks=networks, plugins=plugins)``
    is built.
  initial_history: the history (as returned in RunResult.history) of the run ``initial_state``
    came from; the new records are appended to it, so a resumed run returns the same history as
    an uninterrupted one.
  initial_best: the ``best`` record (RunResult.best) of the run ``initial_state`` came from.
  on_chunk(env_steps, ts, history, best): called after every chunk (and its evaluation) with the
    new TrainState, the history so far (name -> list of per-seed arrays) and the best record,
    before ``progress_fn``; e.g. to save resumable state. ``ts`` is donated to the next chunk:
    copy what you keep.
  hyper: ``{name: [v1, ..., vP]}`` over fields of :data:`hdt.agents.sac.SWEEPABLE` and the
    plug-ins' hyper (``trainer.sweepable``, see :func:`grid_points`): P grid points x the seeds train
    as ONE vmapped program; every returned leading axis (and ``initial_state``'s) is then points x seeds, point-major (runs
    ``p * len(seeds) + i``), and ``config``'s values of those fields are not used. Each run gets the
    same keys as the seed alone would, so a point matches its separate run up to float rounding.
    Plug-in values replace that plug-in's defaults.
  cache_key: a string naming everything the trainer's programs depend on besides hdt's code (env and
    its options, config, plug-ins); with it, the compiled programs are saved and later runs with the
    same key load them (:func:`hdt.cache.compiled_all`) instead of tracing and compiling (one device).
  networks, plugins: as :func:`make_train` (when ``trainer`` is None).

  After every chunk the loss terms and parameters are checked (flags computed inside the jitted
  chunk). A run (seed or grid point) whose chunk went NaN/inf stays at its state from before that chunk
  (``TrainState.diverged_at``), with one warning line naming the term, env step and seed, while the
  others train on; when none is left, :class:`TrainingDiverged` is raised before ``on_chunk`` sees the
  bad state.

  History: training metrics have shape (seeds, chunks) (``env_steps`` says where);
  ``eval/...`` entries have shape (seeds, evaluations) (``eval/env_steps`` says where).

  Best: per seed, the policy and q params of the evaluation with the highest mean eval return so
  far (:func:`update_best`; host numpy, seed axis), with its ``return`` and ``env_steps``. Only
  evaluations after a chunk count: the one at the start evaluates a policy this run did not train.
  """
  seeds = seed_list(seeds)
  chunk_steps = config.env_steps_per_chunk
  if eval_every is None:
    eval_every = chunk_steps
  if eval_every <= 0 or eval_every % chunk_steps:
    raise ValueError(
        f"eval_every={eval_every} must be a positive multiple of num_envs*steps_per_chunk="
        f"{chunk_steps}"
    )
  if trainer is None:
    trainer = make_train(env, config, networks=networks, plugins=plugins)
  else:
    if plugins or networks is not None:
      raise ValueError("pass networks and plugins to make_train, not with trainer=")
    same = dict(total_env_steps=config.total_env_steps) | {k: getattr(config, k) for k in hyper or {}
                                                           if k in SWEEPABLE}
    if dataclasses.replace(trainer.config, **same) != config:
      raise ValueError("trainer.config differs from config in more than total_env_steps"
                       + (" and the hyper fields" if hyper else ""))
  points = grid_points(hyper, trainer.sweepable)
  n_runs = len(points) * len(seeds)
  labels = seeds if hyper is None else [
      f"{s} at {','.join(f'{k}={v}' for k, v in p.items())}" for p in points for s in seeds]
  fns = vmapped(trainer, n_runs, hyper is not None)
  # Several devices (GPUs, hosts, or forced CPU host devices): each gets its share of the seeds.
  sharding = sharding_lib.seed_sharding(n_runs)
  keys = sharding_lib.shard(np.tile(seed_keys(seeds), (len(points), 1)), sharding)
  if cache_key is not None and sharding is None:
    fns = _ahead_of_time(fns, f"{cache_key}|runs={n_runs}|hyper={sorted(hyper or {})}", keys, hyper)
  if initial_state is None:
    ts = fns.init(keys, sharding_lib.shard(seed_indices(len(seeds), len(points)), sharding))
  else:
    ts = sharding_lib.shard(initial_state, sharding)
    if np.shape(ts.env_steps) != (n_runs,):
      raise ValueError(
          f"initial_state has seed axis {np.shape(ts.env_steps)}, expected ({n_runs},)"
      )
  chunk_fn, eval_fn = fns.run_chunk, fns.evaluate
  if hyper is not None:
    # a target entropy of None is the config's default (-action_size), as a number for the grid
    value = lambda k, v: (dataclasses.replace(config, target_entropy=v).target_entropy_for(env.action_size)
                          if k == "target_entropy" else v)
    per_run = {k: sharding_lib.shard(jnp.asarray([value(k, p[k]) for p in points for _ in seeds], jnp.float32),
                                     sharding) for k in hyper}
    chunk_fn = lambda ts: fns.run_chunk(ts, per_run)
  start_chunk = int(sharding_lib.to_host(ts.env_steps).reshape(-1)[0]) // chunk_steps

  # Records are per-seed arrays; a resumed run continues the saved history (and its wall clock).
  hist: dict[str, list] = {k: list(np.swapaxes(np.asarray(v), 0, 1))
                           for k, v in (initial_history or {}).items()}
  t_offset = float(hist["walltime"][-1].max()) if hist.get("walltime") else 0.0

  def current_params():
    return saved_params(ts.agent)

  best = initial_best
  criterion = best_criterion(config)

  def evaluate(index, step):
    nonlocal best
    k = fns.eval_keys(keys, np.int32(index))
    ev = sharding_lib.to_host(eval_fn(ts.agent.deployed_policy, k, ts.agent.obs_norm))
    ev = {f"eval/{name}": np.asarray(v) for name, v in ev.items()}
    ev["eval/env_steps"] = np.full(n_runs, step)
    for name, v in ev.items():
      hist.setdefault(name, []).append(v)
    if criterion not in ev:
      raise ValueError(f"best_by={config.best_by!r}: this env's evaluation has no such metric; use one of "
                       + ", ".join(sorted(k[5:] for k in ev if k != "eval/env_steps")))
    if index > start_chunk:  # not the evaluation at the start
      score = ev[criterion]
      if best is None:
        best = empty_best(sharding_lib.to_host(current_params()))
      if np.any(score > best["score"]):  # copy params off the device only when one improved
        best = update_best(best, sharding_lib.to_host(current_params()), score, step)
    return ev

  if eval_at_start:
    evaluate(start_chunk, start_chunk * chunk_steps)
  t0 = time.perf_counter()
  diverged = np.asarray(sharding_lib.to_host(ts.diverged_at)).reshape(-1)
  for c in range(start_chunk, config.num_chunks):
    ts, m = chunk_fn(ts)
    m = {k: np.asarray(v) for k, v in sharding_lib.to_host(m).items()}
    now = np.asarray(sharding_lib.to_host(ts.diverged_at)).reshape(-1)
    _report_diverged({k: m.pop(k) for k in list(m) if k.startswith(NONFINITE)}, diverged, now, c * chunk_steps,
                     config.num_envs, labels)
    diverged = now
    step = (c + 1) * chunk_steps
    m["walltime"] = np.full(n_runs, t_offset + time.perf_counter() - t0)
    for k, v in m.items():
      hist.setdefault(k, []).append(v)
    if step % eval_every == 0 or c == config.num_chunks - 1:
      m.update(evaluate(c + 1, step))
    if on_chunk is not None:
      on_chunk(step, ts, hist, best)
    if progress_fn is not None:
      progress_fn(step, m)

  history = {k: np.stack(v, axis=1) for k, v in hist.items()}  # (seeds, records, ...)
  params = saved_params(ts.agent)
  return RunResult(params=params, history=history, state=ts, best=best)
