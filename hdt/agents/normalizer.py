"""Running observation statistics (as brax's ``running_statistics``), kept WITH the parameters.

A normalised network's parameters are its flax variables plus an ``"obs_norm"`` entry::

    {"params": {...}, "obs_norm": {"count": (), "mean": (obs,), "m2": (obs,)}}

``networks.make_sac_networks(..., normalize_observations=True)`` initialises that layout and its
``policy_apply`` / ``q_apply`` normalise their observation input with it whenever the entry is present
(structurally, at trace time), so a checkpointed policy carries its normaliser: anything that applies
saved policy parameters (``compose``, ``evaluate``, ``finetune_high``, the KL reference) uses the
statistics the policy was trained with, and parameters without the entry (every LL, older runs) are
applied unchanged. The statistics are not trained by gradient: the training loop updates them from the
observations it collects (:func:`update`) and writes them into the policy, critic and target critic.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

KEY = "obs_norm"
STD_MIN = 1e-3  # floor of the standard deviation (a constant input stays finite)
CLIP = 10.0  # normalised inputs are clipped to [-CLIP, CLIP] (as SB3's VecNormalize clip_obs)


def init(size: int) -> dict:
  return {"count": jnp.zeros((), jnp.float32), "mean": jnp.zeros((size,), jnp.float32),
          "m2": jnp.zeros((size,), jnp.float32)}


def update(stats: dict, obs: jax.Array) -> dict:
  """Statistics of everything seen so far plus the rows of ``obs`` (leading axes = samples);
  Chan et al.'s parallel combination of counts, means and summed squared deviations."""
  x = jnp.asarray(obs, jnp.float32).reshape(-1, stats["mean"].shape[-1])
  n = jnp.float32(x.shape[0])
  b_mean = jnp.mean(x, axis=0)
  b_m2 = jnp.sum(jnp.square(x - b_mean), axis=0)
  count = stats["count"] + n
  delta = b_mean - stats["mean"]
  mean = stats["mean"] + delta * n / count
  m2 = stats["m2"] + b_m2 + jnp.square(delta) * stats["count"] * n / count
  return {"count": count, "mean": mean, "m2": m2}


def std(stats: dict) -> jax.Array:
  var = stats["m2"] / jnp.maximum(stats["count"], 1.0)
  return jnp.where(stats["count"] > 1, jnp.maximum(jnp.sqrt(var), STD_MIN), 1.0)


def normalize(stats: dict, obs: jax.Array) -> jax.Array:
  stats = jax.lax.stop_gradient(stats)
  return jnp.clip((obs - stats["mean"]) / std(stats), -CLIP, CLIP)


def has(params) -> bool:
  return isinstance(params, dict) and KEY in params


def split(params):
  """(flax variables without the normaliser, the normaliser or None)."""
  if has(params):
    return {k: v for k, v in params.items() if k != KEY}, params[KEY]
  return params, None


def with_stats(params, stats):
  """``params`` with its normaliser replaced by ``stats`` (unchanged if it has none)."""
  return dict(params, **{KEY: stats}) if has(params) else params
