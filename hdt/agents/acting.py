"""Acting in an environment with a fixed policy: deterministic evaluation rollouts (as brax's
``training/acting.py``). Pure and vmappable; needs an env and a policy function, no training config."""

from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp

# policy(params, obs) -> action, e.g. the deterministic tanh(mean) of a SAC policy
Policy = Callable[[Any, jax.Array], jax.Array]


def evaluate(env, policy: Policy, params, key: jax.Array, num_episodes: int, per_episode: bool = False) -> dict:
  """``num_episodes`` parallel rollouts of ``policy(params, obs)`` on ``env``.

  Each episode is counted up to and including its first ``done`` (within ``env.horizon`` steps).
  Returns ``return`` (mean over episodes), ``return_std``, ``length``, and for each entry ``k``
  of ``state.metrics``: ``k`` (mean over the episode's steps), ``k_max`` and ``k_final`` (value
  at the episode's last step), each averaged over episodes; ``per_episode``: also ``episode_return``,
  each episode's return (what one episode can move the mean by).
  """
  n = num_episodes
  v_reset, v_step = jax.vmap(env.reset), jax.vmap(env.step)
  s0 = v_reset(jax.random.split(key, n))
  m0 = jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float32), s0.metrics)
  zeros_like = lambda t: jax.tree_util.tree_map(jnp.zeros_like, t)
  carry0 = dict(
      state=s0,
      alive=jnp.ones((n,), jnp.float32),
      ret=jnp.zeros((n,), jnp.float32),
      length=jnp.zeros((n,), jnp.float32),
      msum=zeros_like(m0),
      mmax=jax.tree_util.tree_map(lambda x: jnp.full_like(x, -jnp.inf), m0),
      mlast=zeros_like(m0),
  )

  def bcast(alive, x):
    return alive.reshape(alive.shape + (1,) * (x.ndim - 1))

  def step(c):
    s = v_step(c["state"], policy(params, c["state"].obs))
    alive = c["alive"]
    m = jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float32), s.metrics)
    on = lambda x: bcast(alive, x) > 0
    return dict(
        state=s,
        alive=alive * (1.0 - jnp.asarray(s.done, jnp.float32)),
        ret=c["ret"] + alive * jnp.asarray(s.reward, jnp.float32),
        length=c["length"] + alive,
        msum=jax.tree_util.tree_map(lambda a, x: a + bcast(alive, x) * x, c["msum"], m),
        mmax=jax.tree_util.tree_map(
            lambda a, x: jnp.where(on(x), jnp.maximum(a, x), a), c["mmax"], m
        ),
        mlast=jax.tree_util.tree_map(lambda a, x: jnp.where(on(x), x, a), c["mlast"], m),
        t=c["t"] + 1,
    )

  # stops once every episode is done: later steps would add nothing (e.g. BlockPush HLs that
  # succeed in a few of their 50 steps)
  c = jax.lax.while_loop(lambda c: (c["t"] < env.horizon) & jnp.any(c["alive"] > 0), step,
                         dict(carry0, t=jnp.zeros((), jnp.int32)))
  length = jnp.maximum(c["length"], 1.0)
  out = {
      "return": jnp.mean(c["ret"]),
      "return_std": jnp.std(c["ret"]),
      "length": jnp.mean(c["length"]),
  }
  if per_episode:
    out["episode_return"] = c["ret"]
  for k in c["msum"]:
    x = c["msum"][k]
    out[k] = jnp.mean(x / length.reshape(length.shape + (1,) * (x.ndim - 1)), axis=0)
    out[k + "_max"] = jnp.mean(c["mmax"][k], axis=0)
    out[k + "_final"] = jnp.mean(c["mlast"][k], axis=0)
  return out
