"""The training plug-in protocol: what a method adds to SAC (a discriminator reward, a KL term to a
reference policy, a start from another policy), passed to :func:`hdt.agents.train.make_train` as a
list that it folds over. Every hook is optional.

A plug-in's state is per seed, of the plug-in's own type (any pytree, typically a ``flax.struct``
dataclass such as :class:`hdt.agents.discriminator.DiscState`): ``TrainState.aux[<name>]``, and each
hook sees only its own. Any number of plug-ins combine: each regulariser is weighted by its own
schedule and logged under the plug-in's name (``<name>``, ``<name>_weight``), and each plug-in's
transition extras are stored under its name and handed back to it alone.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Mapping, Sequence

import jax

State = Any  # a plug-in's state: a pytree of its own type (TrainState.aux[plug-in name])


@dataclasses.dataclass(frozen=True)
class Plugin:
  """One method's hooks into SAC training (all optional, no-ops when None).

  init(key, agent, seed_index) -> (agent, state): the plug-in's initial state (None without init); it
    may also set the starting SACState (e.g. another policy's parameters). Called once per seed, after
    the SAC init; ``seed_index``: the seed's place in the run's seeds (0..S-1; the same in every grid point).
  update(state, transitions, env_steps, key) -> (state, metrics): once per training step, after the
    new transitions were collected (metrics are averaged over the chunk).
  reward(state, batch) -> rewards: recomputes a sampled batch's rewards before the critic target.
  regularizer(state, policy_params, obs) -> scalar: added to the actor loss, times ``schedule``
    (``regularizer(state, policy_params, obs, obs_norm)`` with an observation normaliser); logged
    as ``<name>`` and its weight as ``<name>_weight``.
  schedule(env_steps) -> weight of this plug-in's regulariser (default 1).
  transition_extras(env_state, next_env_state) -> pytree stored with each transition; ``update`` and
    ``reward`` see these as ``transitions.extras`` / ``batch.extras`` (and no other plug-in's).
  hyper: {name: default} of the plug-in's vmappable scalars (names unique across plug-ins and
    SWEEPABLE), passed as ``**values`` to update, reward, regularizer and schedule (module docstring).
  scales_with_budget: its hooks follow schedules that are fractions of the run's budget (an annealed
    weight or learning rate), so a run with it cannot change its budget on resume; False for a plug-in
    whose hooks never read the budget (e.g. one that only sets the starting parameters).
  """

  name: str
  init: Callable[[jax.Array, Any, Any], tuple[Any, State]] | None = None
  update: Callable[[State, Any, jax.Array, jax.Array], tuple[State, dict]] | None = None
  reward: Callable[[State, Any], jax.Array] | None = None
  regularizer: Callable[[State, Any, jax.Array], jax.Array] | None = None
  schedule: Callable[[jax.Array], jax.Array] | None = None
  transition_extras: Callable[[Any, Any], Any] | None = None
  hyper: Mapping[str, float] = dataclasses.field(default_factory=dict, hash=False)
  scales_with_budget: bool = True


def values(plugin: Plugin, hyper: Mapping | None) -> dict:
  """The keyword arguments of ``plugin``'s per-step hooks: its hyper defaults, overridden by
  ``hyper``'s values (e.g. a grid point's, possibly traced) where given."""
  return {k: (hyper[k] if hyper and k in hyper else v) for k, v in plugin.hyper.items()}


def check(plugins: Sequence[Plugin]) -> tuple[Plugin, ...]:
  """``plugins`` as a tuple, refused in one line where they cannot be combined."""
  plugins = tuple(plugins)
  for p in plugins:
    if not isinstance(p, Plugin):
      raise TypeError(f"plugins: expected hdt.agents.plugins.Plugin objects, got {type(p).__name__}")
  names = [p.name for p in plugins]
  if len(set(names)) != len(names):
    raise ValueError(f"plugins {names}: each plug-in needs its own name")
  for p in plugins:
    if p.schedule is not None and p.regularizer is None:
      raise ValueError(f"plug-in {p.name!r} has a schedule but no regularizer: a schedule weights its own "
                       f"plug-in's regularizer")
  return plugins


def sweepable(plugins: Sequence[Plugin], taken: Sequence[str] = ()) -> tuple[str, ...]:
  """The hyper names of ``plugins``, refused in one line where one repeats another's or ``taken``'s
  (e.g. SWEEPABLE)."""
  seen = {k: "SAC" for k in taken}
  for p in plugins:
    for k in p.hyper:
      if k in seen:
        raise ValueError(f"plug-in {p.name!r} declares hyper-parameter {k!r}, which {seen[k]} already uses; "
                         f"give it another name")
      seen[k] = f"plug-in {p.name!r}"
  return tuple(k for p in plugins for k in p.hyper)
