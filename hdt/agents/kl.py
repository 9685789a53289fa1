"""KL regularisation towards a frozen reference policy, and the annealed weight of that term.

Used for KL-regularised finetuning (SPEC section 4): the actor loss of SAC gets
``w(env_steps) * KL(pi_B(.|s) || pi_A(.|s))`` where both policies are the *pre-tanh* diagonal
Gaussians ``N(loc, scale)`` their networks output (the tanh is the same bijection for both, so the KL
of the squashed distributions equals the KL of the pre-tanh ones), and the weight ``w`` decays
linearly from ``kl_weight`` (the paper's beta) to ``1e-5 kl_weight`` (KLSAC's floor).

``kl_plugin`` is the term as a :class:`hdt.agents.plugins.Plugin` whose reference lives per seed in
the training state, weighted by ``linear_anneal``; ``make_kl_regularizer`` is the same KL to a fixed
reference as one function ``(policy_params, obs[, obs_norm]) -> scalar`` (the ``actor_regularizer`` of
:func:`hdt.agents.sac.make_losses`), e.g. to measure it.
"""

from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp
from flax import struct

from hdt.agents import networks as nets
from hdt.agents.plugins import Plugin

Params = Any
MODES = ("forward", "reverse")


WEIGHT = "kl_weight"  # the KL plug-in's vmappable hyper-parameter (the paper's beta), and its metric column

def make_kl_regularizer(
    policy_apply: Callable[[Params, jax.Array], tuple[jax.Array, jax.Array]],
    reference_params: Params,
    mode: str = "forward",
    mean_only: bool = False,
    reference_obs_norm: Any = None,
) -> Callable[..., jax.Array]:
  """``regularizer(policy_params, obs, obs_norm=None) -> scalar``: batch mean of a closed-form Gaussian KL.

  ``pi`` = ``policy_apply(policy_params, obs)`` (the policy being trained, B) and
  ``ref`` = ``policy_apply(reference_params, obs)`` (frozen: a closure constant under
  ``stop_gradient``, e.g. the transferred HL of A), both pre-tanh ``(loc, scale)``.

  mode="forward": KL(pi || ref)  (= KL(pi_B || pi_A), the paper's term)
  mode="reverse": KL(ref || pi)
  mean_only=True: the authors' ``kl_type='mean'`` (``algs/kl_sac.py`` ``KLSAC.setup_model``), not a KL:
      sum_d (loc_pi - loc_ref)^2   (the same for both modes; scales are ignored).
  The KL is summed over action dimensions and averaged over all leading (batch) axes of ``obs``.
  Each policy applies its own observation statistics to the raw ``obs``: ``obs_norm`` (the trained
  policy's) and ``reference_obs_norm`` (the reference's, saved with it); None: raw observations.
  """
  term = make_kl_term(policy_apply, mode, mean_only)
  reference_params = jax.tree_util.tree_map(jnp.asarray, reference_params)
  reference_obs_norm = jax.tree_util.tree_map(jnp.asarray, reference_obs_norm)

  def regularizer(policy_params, obs, obs_norm=None):
    return term(policy_params, reference_params, obs, obs_norm, reference_obs_norm)

  regularizer.metric_name = "kl"  # logged as kl / kl_weight (hdt.agents.sac), not "regularizer"
  return regularizer


def make_kl_term(policy_apply, mode: str = "forward", mean_only: bool = False):
  """``term(policy_params, reference_params, obs, obs_norm=None, reference_obs_norm=None) -> scalar``,
  the KL of :func:`make_kl_regularizer` with the reference as an argument (gradients stopped), e.g.
  per-seed plug-in state."""
  if mode not in MODES:
    raise ValueError(f"mode={mode!r}: use 'forward' (KL(pi || ref)) or 'reverse' (KL(ref || pi))")

  def term(policy_params: Params, reference_params: Params, obs: jax.Array, obs_norm=None,
           reference_obs_norm=None) -> jax.Array:
    loc, scale = policy_apply(policy_params, obs, obs_norm)
    ref_loc, ref_scale = jax.lax.stop_gradient(policy_apply(reference_params, obs, reference_obs_norm))
    if mean_only:
      return jnp.mean(jnp.sum(jnp.square(loc - ref_loc), axis=-1))
    if mode == "forward":
      kl = nets.gaussian_kl(loc, scale, ref_loc, ref_scale)
    else:
      kl = nets.gaussian_kl(ref_loc, ref_scale, loc, scale)
    return jnp.mean(kl)

  return term


KL_FLOOR = 1e-5  # the annealed weight's floor, as a fraction of kl_weight (KLSAC.learn, kl_decay)


@struct.dataclass
class KLState:
  """The KL plug-in's per-seed state (``TrainState.aux["kl"]``)."""
  reference: Params  # the reference policy's parameters
  reference_obs_norm: Any = None  # its observation statistics, if it has some


def kl_plugin(policy_apply, reference_params: Params, kl_weight: float, anneal_steps: float,
              mode: str = "forward", mean_only: bool = False, reference_obs_norm: Any = None) -> Plugin:
  """The KL term as a training plug-in: ``w(env_steps) * KL`` (:func:`linear_anneal` from ``kl_weight``
  to ``kl_weight * KL_FLOOR`` at ``anneal_steps``) to a reference policy kept per seed in
  :class:`KLState` (``TrainState.aux["kl"]``); every seed starts with ``reference_params`` and
  ``reference_obs_norm`` (no seed axis).
  ``kl_weight`` is its hyper of that name (vmappable over a grid, :mod:`hdt.agents.plugins`): the
  weight is ``kl_weight`` times the anneal from 1, which equals :func:`linear_anneal` ``(kl_weight, ...)``
  bit for bit."""
  term = make_kl_term(policy_apply, mode, mean_only)
  f32 = lambda tree: jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float32), tree)
  state = KLState(f32(reference_params), None if reference_obs_norm is None else f32(reference_obs_norm))
  anneal = linear_anneal(1.0, anneal_steps)
  return Plugin(
      name="kl",
      init=lambda key, agent, seed_index: (agent, state),
      regularizer=lambda state, params, obs, obs_norm=None, kl_weight=None: term(
          params, state.reference, obs, obs_norm, state.reference_obs_norm),
      schedule=lambda env_steps, kl_weight: kl_weight * anneal(env_steps),
      hyper={WEIGHT: float(kl_weight)},
  )


def linear_anneal(weight: float, end_steps: float, floor: float = KL_FLOOR) -> Callable[[jax.Array], jax.Array]:
  """``schedule(env_steps)``: ``weight max(floor, 1 - env_steps / end_steps)``, so ``weight`` at 0 env
  steps, linearly down to ``weight floor`` at ``end_steps``, then constant (KLSAC.learn with ``kl_decay``:
  ``kl_coef max(1e-5, 1 - step / (kl_stop T))``, never exactly 0; ``floor=0`` ends at 0).

  ``end_steps <= 0`` gives the constant 0 (no regularisation at all).
  """
  weight = float(weight)
  end_steps = int(round(end_steps))
  if end_steps <= 0 or weight == 0.0:
    return lambda env_steps: jnp.zeros((), jnp.float32)
  lo, end = jnp.float32(floor), jnp.float32(end_steps)
  return lambda env_steps: jnp.float32(weight) * jnp.maximum(lo, 1.0 - jnp.asarray(env_steps, jnp.float32) / end)
