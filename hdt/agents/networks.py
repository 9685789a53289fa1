"""SAC networks: flax MLPs, a tanh-squashed diagonal Gaussian policy, a twin Q function and, for SB2's
SAC (``value_net``), a state-value function V.

The policy network outputs the **pre-tanh** Gaussian ``(loc, scale)``; everything else (sampling,
log-probabilities, the deterministic action, the closed-form KL between two policies) is a pure
function of those two arrays, so a frozen reference policy only needs its ``(loc, scale)``.

Conventions (as in stable-baselines 2, which the paper's code used): ``log_std`` is a linear head
clipped to ``[LOG_STD_MIN, LOG_STD_MAX]``, the action is ``tanh(u)`` with ``u ~ N(loc, scale)``, and
the deterministic action is ``tanh(loc)``. Actions live in ``[-1, 1]^action_size``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, Callable, Sequence

import distrax
import flax.linen as nn
import jax
import jax.numpy as jnp

from hdt.agents import normalizer

Params = Any
LOG_STD_MIN = -20.0
LOG_STD_MAX = 2.0


class MLP(nn.Module):
  """Dense layers with ``activation`` between them and a linear output layer; with ``layer_norm``, a
  LayerNorm after each hidden Dense (before the activation), as in DroQ / RLPD critics."""

  hidden_sizes: Sequence[int]
  out_size: int
  activation: Callable[[jax.Array], jax.Array] = nn.relu
  kernel_init: Callable[..., Any] = nn.initializers.lecun_uniform()
  layer_norm: bool = False

  @nn.compact
  def __call__(self, x: jax.Array) -> jax.Array:
    for i, h in enumerate(self.hidden_sizes):
      x = nn.Dense(h, kernel_init=self.kernel_init, name=f"hidden_{i}")(x)
      if self.layer_norm:
        x = nn.LayerNorm(name=f"norm_{i}")(x)
      x = self.activation(x)
    return nn.Dense(self.out_size, kernel_init=self.kernel_init, name="out")(x)


class GaussianPolicy(nn.Module):
  """obs -> (loc, scale) of the pre-tanh diagonal Gaussian."""

  hidden_sizes: Sequence[int]
  action_size: int
  activation: Callable[[jax.Array], jax.Array] = nn.relu

  @nn.compact
  def __call__(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
    out = MLP(self.hidden_sizes, 2 * self.action_size, self.activation, name="mlp")(obs)
    loc, log_std = jnp.split(out, 2, axis=-1)
    log_std = jnp.clip(log_std, LOG_STD_MIN, LOG_STD_MAX)
    return loc, jnp.exp(log_std)


class TwinQ(nn.Module):
  """(obs, action) -> Q values of shape ``batch + (2,)``; the two critics are one vmapped MLP."""

  hidden_sizes: Sequence[int]
  activation: Callable[[jax.Array], jax.Array] = nn.relu
  num_critics: int = 2
  layer_norm: bool = False

  @nn.compact
  def __call__(self, obs: jax.Array, action: jax.Array) -> jax.Array:
    x = jnp.concatenate([obs, action], axis=-1)
    critics = nn.vmap(
        MLP,
        variable_axes={"params": 0},
        split_rngs={"params": True},
        in_axes=None,
        out_axes=-1,
        axis_size=self.num_critics,
    )(self.hidden_sizes, 1, self.activation, layer_norm=self.layer_norm, name="critics")
    return critics(x)[..., 0, :]  # (..., 1, num_critics) -> (..., num_critics)


@dataclasses.dataclass(frozen=True)
class SACNetworks:
  """Pure functions over parameter pytrees.

  policy_apply(policy_params, obs, obs_norm=None) -> (loc, scale)   pre-tanh Gaussian
  q_apply(q_params, obs, action, obs_norm=None) -> q                shape obs.shape[:-1] + (2,)
  policy_init(key) -> policy_params;  q_init(key) -> q_params

  With ``value_net`` (SB2's SAC, the authors' code), ``q_params`` is ``{"q": twin Q, "v": V}`` (SB2's
  ``values_fn`` scope, one optimiser) and ``v_apply(params, obs, obs_norm=None) -> V(s)`` (shape
  ``obs.shape[:-1]``) reads ``params["v"]``, so it applies to ``q_params`` and to the target
  ``{"v": V'}`` alike.

  ``obs_norm``: running observation statistics (:mod:`hdt.agents.normalizer`) that normalise ``obs``
  first, or None for raw observations. brax passes them first; here they come last and optional, so
  that networks without a normaliser (every LL, the default) are applied as ``(params, obs)``.
  """

  policy_apply: Callable[..., tuple[jax.Array, jax.Array]]
  q_apply: Callable[..., jax.Array]
  policy_init: Callable[[jax.Array], Params] | None = None
  q_init: Callable[[jax.Array], Params] | None = None
  observation_size: int | None = None
  action_size: int | None = None
  value_net: bool = False
  v_apply: Callable[..., jax.Array] | None = None


def make_sac_networks(
    observation_size: int,
    action_size: int,
    hidden_sizes: Sequence[int] = (64, 64),
    critic_hidden_sizes: Sequence[int] | None = None,
    activation: Callable[[jax.Array], jax.Array] = nn.relu,
    value_net: bool = False,
    critic_layer_norm: bool = False,
) -> SACNetworks:
  """Builds the policy and twin-Q networks (float32 parameters), plus V with ``value_net``; with
  ``critic_layer_norm``, Q and V normalise each hidden layer (the policy never does)."""
  critic_hidden_sizes = tuple(hidden_sizes if critic_hidden_sizes is None else critic_hidden_sizes)
  policy = GaussianPolicy(tuple(hidden_sizes), action_size, activation)
  q = TwinQ(critic_hidden_sizes, activation, layer_norm=critic_layer_norm)
  v = MLP(critic_hidden_sizes, 1, activation, layer_norm=critic_layer_norm)
  dummy_obs = jax.ShapeDtypeStruct((1, observation_size), jnp.float32)
  dummy_act = jax.ShapeDtypeStruct((1, action_size), jnp.float32)
  key_shape = jax.ShapeDtypeStruct((2,), jnp.uint32)

  # traced on first use only: a run whose programs were loaded (hdt.cache.compiled_all) never calls init
  @functools.cache
  def policy_shapes():
    return jax.eval_shape(policy.init, key_shape, dummy_obs)

  @functools.cache
  def q_shapes():
    shapes = jax.eval_shape(q.init, key_shape, dummy_obs, dummy_act)
    return {"q": shapes, "v": jax.eval_shape(v.init, key_shape, dummy_obs)} if value_net else shapes

  norm = lambda obs, obs_norm: obs if obs_norm is None else normalizer.normalize(obs_norm, obs)

  def policy_init(key):
    return lecun_uniform_init(policy_shapes(), key)

  def q_init(key):
    return lecun_uniform_init(q_shapes(), key)

  def policy_apply(params, obs, obs_norm=None):
    return policy.apply(params, norm(obs, obs_norm))

  def q_apply(params, obs, action, obs_norm=None):
    return q.apply(params["q"] if value_net else params, norm(obs, obs_norm), action)

  def v_apply(params, obs, obs_norm=None):
    return v.apply(params["v"], norm(obs, obs_norm))[..., 0]

  return SACNetworks(
      policy_apply=policy_apply,
      q_apply=q_apply,
      policy_init=policy_init,
      q_init=q_init,
      observation_size=observation_size,
      action_size=action_size,
      value_net=value_net,
      v_apply=v_apply if value_net else None,
  )


def lecun_uniform_init(shapes: Params, key: jax.Array) -> Params:
  """Parameters for the pytree of ``jax.ShapeDtypeStruct`` ``shapes`` from ONE random draw.

  Kernels (leaves named ``kernel``, fan-in = ``shape[-2]``, so stacked twin-critic kernels of shape
  ``(2, in, out)`` get fan-in ``in``) ~ U(-sqrt(3/fan_in), sqrt(3/fan_in)), the distribution of
  flax's ``lecun_uniform`` (brax's default); biases are 0 and LayerNorm gains 1. Unlike
  ``module.init``, which draws once per layer through flax's RNG folding, this compiles one threefry
  kernel per network (faster to compile under ``jit(vmap(init))``).
  """
  paths, treedef = jax.tree_util.tree_flatten_with_path(shapes)
  name = lambda path: getattr(path[-1], "key", None)
  # by name, not by rank: the stacked twin critics' biases and LayerNorm gains are 2-D too
  sizes = [math.prod(leaf.shape) if name(path) == "kernel" else 0 for path, leaf in paths]
  u = jax.random.uniform(key, (max(sum(sizes), 1),), jnp.float32, -1.0, 1.0)
  out, offset = [], 0
  for (path, leaf), size in zip(paths, sizes):
    if size:
      limit = math.sqrt(3.0 / leaf.shape[-2])
      out.append((limit * u[offset:offset + size]).reshape(leaf.shape).astype(leaf.dtype))
      offset += size
    else:
      out.append((jnp.ones if name(path) == "scale" else jnp.zeros)(leaf.shape, leaf.dtype))
  return jax.tree_util.tree_unflatten(treedef, out)


# ----------------------------------------------------------------------------------------------
# The action distribution, as pure functions of the pre-tanh (loc, scale).


def pre_tanh_gaussian(loc: jax.Array, scale: jax.Array) -> distrax.MultivariateNormalDiag:
  """The Gaussian over pre-tanh actions ``u`` (use it for KLs between policies)."""
  return distrax.MultivariateNormalDiag(loc, scale)


def tanh_gaussian(loc: jax.Array, scale: jax.Array) -> distrax.Transformed:
  """The squashed policy distribution over actions ``tanh(u)`` in [-1, 1]^d.

  Prefer :func:`sample_and_log_prob` for training: ``Transformed.log_prob(a)`` has to invert the
  tanh and loses precision for ``|a|`` close to 1.
  """
  return distrax.Transformed(pre_tanh_gaussian(loc, scale), distrax.Block(distrax.Tanh(), 1))


def log_prob_from_pre_tanh(loc: jax.Array, scale: jax.Array, u: jax.Array) -> jax.Array:
  """log pi(tanh(u)) = log N(u; loc, scale) - sum log(1 - tanh(u)^2), evaluated stably at u."""
  log_det = distrax.Tanh().forward_log_det_jacobian(u)  # log(1 - tanh(u)^2), no atanh needed
  return pre_tanh_gaussian(loc, scale).log_prob(u) - jnp.sum(log_det, axis=-1)


def sample_from_noise(
    loc: jax.Array, scale: jax.Array, eps: jax.Array
) -> tuple[jax.Array, jax.Array]:
  """Reparameterised sample ``a = tanh(loc + scale * eps)`` (eps ~ N(0, I)) and log pi(a)."""
  u = loc + scale * eps
  return jnp.tanh(u), log_prob_from_pre_tanh(loc, scale, u)


def sample_and_log_prob(
    loc: jax.Array, scale: jax.Array, key: jax.Array
) -> tuple[jax.Array, jax.Array]:
  """Reparameterised sample ``a = tanh(loc + scale * eps)`` and its log-probability."""
  return sample_from_noise(loc, scale, jax.random.normal(key, loc.shape, loc.dtype))


def deterministic_action(loc: jax.Array) -> jax.Array:
  """The evaluation action: tanh of the pre-tanh mean."""
  return jnp.tanh(loc)


def gaussian_kl(
    loc_p: jax.Array, scale_p: jax.Array, loc_q: jax.Array, scale_q: jax.Array
) -> jax.Array:
  """Closed-form KL(N_p || N_q) between two diagonal pre-tanh Gaussians, summed over the action axis."""
  return pre_tanh_gaussian(loc_p, scale_p).kl_divergence(pre_tanh_gaussian(loc_q, scale_q))
