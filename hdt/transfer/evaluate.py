"""Composing an HL with an LL, evaluating policies over seeds, and zero-shot transfer matrices."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from hdt.agents import acting
from hdt.envs.tasks import TASKS, get_task
from hdt.transfer import checkpoint as ckpt
from hdt.transfer import names
from hdt.transfer.card import LOW_PARAMS, PolicyCard
from hdt.transfer.memory import check_memory, state_bytes


@dataclasses.dataclass
class Policy:
  """A runnable policy: an HL over an LL (``low_card`` set) or a flat policy (LL on reach, or Full)."""

  params: Any  # policy params, leading seed axis
  card: PolicyCard  # its card; ``card.loaded`` says which parameters
  low_params: Any = None  # LL policy params, leading seed axis (paired with the HL seeds)
  low_card: PolicyCard | None = None
  delta_max: float | None = None
  uniform_actions: bool = False  # a random baseline: uniform actions in [-1, 1] instead of the policy's
  obs_norm: Any = None  # observation statistics saved beside params (leading seed axis), or None
  low_obs_norm: Any = None  # the same for low_params

  @property
  def agent(self) -> str:
    return (self.low_card or self.card).agent

  @property
  def num_seeds(self) -> int:
    return int(jax.tree.leaves(self.params)[0].shape[0])


def _load(run, which: str, what: str) -> tuple[Any, PolicyCard, int]:
  """(params of every seed, the card of seed 0 whose ``loaded`` labels them all (ckpt.params_label),
  the number of seeds)."""
  params, metas = ckpt.load_all(run, ckpt.check_which(which, what))
  for i, m in enumerate(metas):
    PolicyCard.from_json(m, Path(run) / f"seed_{i}" / "meta.json")  # of a format and with fields this hdt reads
  card = PolicyCard.from_json(dict(metas[0], params=ckpt.params_label(metas)), run)
  card.check_params(params)
  return params, card, len(metas)


def trained_over(high: PolicyCard, low: str | Path) -> int | None:
  """The seed of ``low`` the HL was trained over, if ``low`` is the LL run it was trained over."""
  if high.low is None:
    return None
  same = lambda p: Path(ckpt.zoo_path(str(p))).resolve()
  return high.low.seed_index if same(high.low.path) == same(low) else None


def check_low_unchanged(high: str | Path, card: PolicyCard, low: str | Path) -> None:
  """Refuses an HL over the LL run it was trained over if that LL changed since (retrained): against
  every hash recorded of it, the HL's card's and (a zoo HL) its zoo.json's."""
  seed = trained_over(card, low)
  if seed is None:
    return  # another LL: a transfer, not a dependency (ckpt.load checks the LL's own record)
  wanted = {h for h in (card.low.sha256, names.recorded_low_hash(high)) if h}
  if wanted - names.hash_aliases(low, seed):
    raise ckpt.CheckpointError(f"the LL in {low} changed after the HL in {high} was trained over it (its "
                               f"content hash differs: was it retrained?); retrain the HL over it, or "
                               f"restore the LL it was trained over")


def random_actions(policy: Policy) -> Policy:
  """``policy`` acting uniformly at random (for an HL: uniform sub-goals over the same LL), the
  "random HL" baseline of a transfer table."""
  return dataclasses.replace(policy, uniform_actions=True)


@dataclasses.dataclass(frozen=True)
class _UniformActions:
  """``env`` stepped with uniform random actions from the env's own key, whatever action it is given."""
  env: Any

  def __getattr__(self, name):
    return getattr(self.env, name)

  def reset(self, key):
    return self.env.reset(key)

  def step(self, state, action):
    k_act, k_env = jax.random.split(state.key)
    return self.env.step(state.replace(key=k_env), jax.random.uniform(k_act, action.shape, action.dtype, -1.0, 1.0))


def load_policy(run: str | Path, which: str = "final") -> Policy:
  """A flat policy run; ``which``: its "final" parameters or its "best" evaluation's."""
  params, card, _ = _load(run, which, "which")
  return Policy(params["policy"], card, obs_norm=params.get(ckpt.NORM))


BOXES = ("refuse", "scale", "keep")  # what compose does when the HL's and the LL's goal boxes differ


def compose(high: str | Path, low: str | Path, box: str = "refuse", which: str = "final",
            low_which: str = LOW_PARAMS) -> Policy:
  """HL of ``high`` driving the LL of ``low``. Goal spaces must agree; goal boxes that differ are
  refused unless ``box='scale'`` (the HL's [-1, 1] actions span the LL's box) or ``box='keep'``
  (the HL's box in metres). ``which`` / ``low_which``: the HL's / LL's "final" parameters or their
  "best" evaluation's (the LL's best by default, as the authors compose and as train_high does)."""
  if box not in BOXES:
    raise ValueError(f"box={box!r}: pass 'refuse' (goal boxes must agree), 'scale' (map the HL's box onto the "
                     f"LL's) or 'keep' (the HL's box in metres)")
  hp, hc, n_high = _load(high, which, "which")
  lp, lc, n_low = _load(low, low_which, "low_which")
  check_low_unchanged(high, hc, low)
  dm = hc.compose_box(lc, box)
  # Over its own LL run an HL is evaluated on the LL seed it was trained over (train_high's LowRef
  # seed); in a transfer, HL seed i drives LL seed i (cycling when one run has fewer seeds).
  own = trained_over(hc, low)
  n = n_high if own is not None else max(n_high, n_low)
  ll_idx = np.full(n, own) if own is not None else np.arange(n) % n_low
  take = lambda tree, idx: jax.tree.map(lambda x: x[idx], tree)
  hi_idx = np.arange(n) % n_high
  return Policy(take(hp["policy"], hi_idx), hc, take(lp["policy"], ll_idx), lc, dm,
                obs_norm=take(hp.get(ckpt.NORM), hi_idx), low_obs_norm=take(lp.get(ckpt.NORM), ll_idx))


def _env_for(policy: Policy, task: str | None, backend: str, low_params=None, record=False,
             low_obs_norm=None, **task_overrides):
  card = policy.card
  task = task or card.task
  if policy.low_card is None:  # flat policy: LL on reach, or a Full policy on its task
    env = card.make_env(task, backend, **task_overrides)
  else:
    env = policy.low_card.high_env(low_params, task, backend, record=record, delta_max=policy.delta_max,
                                   low_obs_norm=low_obs_norm,
                                   **(card.obs_layout.task_options() | task_overrides))
  card.check_env(env, task)
  return env


def evaluate(policy: Policy, task: str | None = None, episodes: int = 100, seeds=None,
             backend: str = "auto", key: int = 1234, **task_overrides) -> dict:
  """Deterministic evaluation of every seed of ``policy`` (vmapped): per-seed mean return and
  success, and their mean and std across seeds, as in the paper's tables."""
  n = policy.num_seeds
  if isinstance(episodes, bool) or not isinstance(episodes, (int, np.integer)) or episodes <= 0:
    raise ValueError(f"episodes={episodes!r}: the number of evaluation episodes must be a positive "
                     f"integer, e.g. 100")
  if task is not None and task not in TASKS:
    raise ValueError(f"unknown task {task!r}; valid tasks: {', '.join(TASKS)}")
  idx = np.arange(n) if seeds is None else np.asarray(seeds)
  if idx.ndim != 1 or idx.size == 0 or not np.issubdtype(idx.dtype, np.integer) or \
      idx.min() < 0 or idx.max() >= n:
    raise ValueError(f"seeds={seeds!r}: pick seed indices of the policy, in 0..{n - 1}")

  def one(params, norm, low_params, low_norm, k):
    env = _env_for(policy, task, backend, low_params, low_obs_norm=low_norm, **task_overrides)
    act = policy.card.policy_fn(norm)
    return acting.evaluate(_UniformActions(env) if policy.uniform_actions else env, act, params, k, episodes,
                            per_episode=True)

  first = lambda tree: jax.tree.map(lambda x: x[0], tree)
  first_low = None if policy.low_params is None else first(policy.low_params)
  check_memory(len(idx) * episodes * 4 * state_bytes(_env_for(policy, task, backend, first_low,
                                                               low_obs_norm=first(policy.low_obs_norm),
                                                               **task_overrides)),
               f"evaluating {len(idx)} seeds x {episodes} episodes in parallel (env states, ~4 copies)",
               "lower the number of episodes or seeds")
  pick = lambda tree: jax.tree.map(lambda x: x[idx], tree)  # None stays None
  keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.PRNGKey(key), i))(jnp.asarray(idx))
  out = jax.device_get(jax.jit(jax.vmap(one))(pick(policy.params), pick(policy.obs_norm), pick(policy.low_params),
                                              pick(policy.low_obs_norm), keys))
  per_seed = {"return": np.asarray(out["return"])}
  if "success_max" in out:
    per_seed["success"] = np.asarray(out["success_max"])
  for extra in ("goal_dist", "waypoints_max"):
    if extra in out:
      per_seed[extra] = np.asarray(out[extra])
  summary = {f"{k}_mean": float(np.mean(v)) for k, v in per_seed.items()}
  summary |= {f"{k}_std": float(np.std(v)) for k, v in per_seed.items()}
  # every number says which parameters made it
  which = {"params": "uniform random actions" if policy.uniform_actions else policy.card.loaded}
  which["metric"] = get_task(task or policy.card.task).headline  # what a table reports
  if policy.low_card is not None:
    which["low_params"] = policy.low_card.loaded
  rets = np.asarray(out["episode_return"])  # [seed, episode]
  spread = {f"episode_return_{k}": getattr(rets, k)(axis=1).tolist() for k in ("std", "min", "max")}
  return dict(per_seed=per_seed, seeds=idx.tolist(), episodes=episodes, **which, **summary, **spread)


def zero_shot_matrix(highs: dict[str, str | Path], lows: dict[str, str | Path], task: str,
                     episodes: int = 100, backend: str = "auto", which: str = "final",
                     low_which: str = LOW_PARAMS, **kw) -> dict:
  """Table-1-style matrix: rows = LL agents, columns = HL sources; entries (mean, std) of the task
  metric (success rate where the task has one, else return). ``which`` / ``low_which``: as in
  :func:`compose`; ``params`` maps each cell to the (HL, LL) parameters it used."""
  cells, used = {}, {}
  for lname, lrun in lows.items():
    for hname, hrun in highs.items():
      ev = evaluate(compose(hrun, lrun, which=which, low_which=low_which), task, episodes=episodes,
                    backend=backend, **kw)
      metric = ev["metric"]
      cells[(lname, hname)] = (ev[f"{metric}_mean"], ev[f"{metric}_std"], metric)
      used[(lname, hname)] = (ev["params"], ev["low_params"])
  return dict(task=task, rows=list(lows), cols=list(highs), cells=cells, params=used)


def trajectory(policy: Policy, task: str | None = None, seed_index: int = 0, key: int = 0,
               backend: str = "auto", **task_overrides) -> dict:
  """One episode of an HL policy, recorded per LL step: goal-space xy (torso / effector / peg),
  block xy, and each sub-goal, for top-down plots; for videos (hdt.render) also every LL step's qpos
  and sub-goal (``qpos``, ``step_goals``) and the scene's MjModel (``model``)."""
  if policy.low_card is None:
    raise ValueError("trajectory() needs a composed HL + LL policy (see compose)")
  at = lambda tree: jax.tree.map(lambda x: x[seed_index], tree)
  params, low = at(policy.params), at(policy.low_params)
  env = _env_for(policy, task, backend, low, record=True, low_obs_norm=at(policy.low_obs_norm), **task_overrides)
  apply = policy.card.policy_fn(at(policy.obs_norm))

  def run(params, key):
    s = env.reset(key)

    def f(s, _):
      n = env.step(s, apply(params, s.obs))
      return n, (n.metrics["xy"], n.metrics["block"], n.metrics["active"], n.metrics["goal"], n.done,
                 n.reward, n.metrics["qpos"])
    return jax.lax.scan(f, s, None, length=env.horizon)[1]

  xy, block, active, goals, done, reward, qpos = jax.device_get(jax.jit(run)(params, jax.random.PRNGKey(key)))
  end = int(np.argmax(done > 0)) + 1 if np.any(done > 0) else len(done)
  keep = active[:end].reshape(-1) > 0
  per_ll = lambda x: x[:end].reshape((-1,) + x.shape[2:])[keep]  # (HL step, LL step, ...) -> LL steps taken
  return dict(xy=per_ll(xy), block=per_ll(block), goals=goals[:end], rewards=reward[:end],
              task=task or policy.card.task, agent=policy.agent, qpos=per_ll(qpos),
              step_goals=np.repeat(goals[:end], active.shape[1], axis=0)[keep], model=env.env.mj_model)


def hl_rollouts(high, low, record: Callable, episodes: int = 16, key: int = 1):
  """For each seed of ``compose(high, low)``: ``(env, arrays)``, where ``arrays`` stacks
  ``record(state, next_state)`` over ``episodes`` deterministic HL episodes (leading axes
  [episode, HL step], one full horizon each: steps after an episode's end belong to the next one)."""
  p = compose(high, low)
  for i in range(p.num_seeds):
    at = lambda t: jax.tree.map(lambda x: x[i], t)
    env = _env_for(p, None, "auto", at(p.low_params), low_obs_norm=at(p.low_obs_norm))
    act, params = p.card.policy_fn(at(p.obs_norm)), at(p.params)

    def episode(k):
      def step(s, _):
        n = env.step(s, act(params, s.obs))
        return n, record(s, n)
      return jax.lax.scan(step, env.reset(k), None, length=env.horizon)[1]

    keys = jax.random.split(jax.random.PRNGKey(key), episodes)
    yield env, jax.tree.map(np.asarray, jax.jit(jax.vmap(episode))(keys))
