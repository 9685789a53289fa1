"""Running observation statistics (as brax's ``running_statistics``), kept APART from the parameters.

The statistics ``{"count": (), "mean": (obs,), "m2": (obs,)}`` live in their own field of the
training state (``SACState.obs_norm``; ``None`` without normalisation, an empty pytree), as brax's
``normalizer_params``: the policy, critics and target critics are plain flax variables, and the
apply functions of :mod:`hdt.agents.networks` take the statistics as an explicit argument. The
training loop updates them from the observations it collects (:func:`update`); they are never
differentiated nor soft-updated. A checkpoint stores them beside the parameters (``"obs_norm"`` next
to ``"policy"`` and ``"q"``), so a saved policy is applied with the statistics it was trained with.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

KEY = "obs_norm"  # the statistics' name in checkpoints, beside "policy" and "q"
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

