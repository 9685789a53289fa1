"""One call per stage: ``train_low``, ``train_high``, ``train_full``, each a vmapped seed sweep that
writes a run directory (config.json, meta.json, metrics.csv, seed_<i>/ checkpoints). Each builds its
:class:`hdt.transfer.runner.Stage` (``low_stage``, ``high_stage``, ``full_stage``: env, config, card,
plug-ins) and hands it with its :class:`hdt.transfer.runner.RunOptions` to
:func:`hdt.transfer.runner.run_stage`; meta.json is the run's :class:`hdt.transfer.card.PolicyCard`."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from hdt.agents.sac import SACConfig
from hdt.envs import make
from hdt.envs.agents import AGENTS
from hdt.envs.tasks import TASKS
from hdt.transfer import checkpoint as ckpt
from hdt.transfer import configs
from hdt.transfer.align import align_low
from hdt.transfer.card import LOW_PARAMS, ObsLayout, PolicyCard, load_low, low_policy_fn  # noqa: F401 (part of this API)
from hdt.transfer.hierarchy import HighLevelEnv
from hdt.transfer.runner import RunOptions, RunResult, Stage, run_stage


def env_meta(env, level: str, config: SACConfig, **extra) -> dict:
  """The card (as meta.json) of a policy about to be trained on ``env`` with ``config``."""
  return PolicyCard.from_env(env, level, config, **extra).to_json()


# Options that only make sense positive (a zero k or box later breaks the HL over this LL).
_POSITIVE = {"k", "delta_max", "frame_skip", "ll_horizon", "hl_horizon", "reach_eps", "contact_clip", "gear_scale"}


def check_env_overrides(overrides: dict, agent: str | None = None, task: str | None = None) -> None:
  """Each agent/task option has the type of its default (finite numbers; positive where only that
  makes sense); unknown names are left to :func:`hdt.envs.make`, which lists the valid ones."""
  defaults = {}
  for t in ([TASKS[task]] if task in TASKS else TASKS.values()):
    obj = t()  # TASKS values are classes or factories
    defaults |= {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}
  specs = [AGENTS[agent]] if agent in AGENTS else AGENTS.values()
  for spec in specs:
    defaults |= {f.name: getattr(spec, f.name) for f in dataclasses.fields(spec)}
  for name, value in overrides.items():
    if name not in defaults or defaults[name] is None or isinstance(defaults[name], tuple):
      continue
    want = type(defaults[name])
    number = isinstance(value, (int, float, np.number)) and not isinstance(value, bool)
    if want is bool:
      ok = isinstance(value, bool)
    elif want in (int, float):
      ok = number and np.isfinite(value) and (want is float or float(value).is_integer())
      ok = ok and (name not in _POSITIVE or value > 0)
    else:
      ok = isinstance(value, want)
    if not ok:
      kind = {bool: "True or False", int: "an integer", float: "a finite number"}.get(want, want.__name__)
      kind += " > 0" if name in _POSITIVE and want in (int, float) else ""
      raise ValueError(f"option {name}={value!r}: expected {kind}, e.g. {name}={defaults[name]!r} (the default)")


def train_low(agent: str, config: SACConfig | None = None, seeds=1, out=None, backend="auto",
              quiet=False, imitate=None, disc=None, resume=False, save_every=None, overwrite=False,
              **env_overrides) -> RunResult:
  """Goal-conditioned LL of ``agent`` on its ``reach`` task (SPEC 3). With ``imitate=<LL run of A>``
  the LL is aligned to A's behaviour by a discriminator (Algorithm 1, ``hdt.transfer.align``).
  backend: the physics backend ("auto", "mjx", "native"); seeds, out, quiet, resume, save_every,
  overwrite: see :class:`hdt.transfer.runner.RunOptions`."""
  if imitate is not None:
    return align_low(agent, imitate, config, disc=disc, seeds=seeds, out=out, backend=backend, quiet=quiet,
                     resume=resume, save_every=save_every, overwrite=overwrite, **env_overrides)
  options = RunOptions(seeds, out, quiet, resume, save_every, overwrite)
  return run_stage(low_stage(agent, config, backend, **env_overrides), options)


def low_stage(agent: str, config: SACConfig | None = None, backend="auto", **env_overrides) -> Stage:
  """The stage of :func:`train_low` (without ``imitate``)."""
  configs.check_config(config, allow_none=True)
  check_env_overrides(env_overrides, agent, "reach")
  env = make(agent, "reach", backend=backend, **env_overrides)
  config = configs.low_config(agent) if config is None else config
  return Stage(env, config, env_meta(env, "low", config, env_overrides=env_overrides), f"low {agent}")


def hl_obs_layout(meta: dict) -> dict:
  """The task options that give an HL checkpoint the observation it was trained on: the recorded
  ``hl_obs`` (hdt.envs.tasks.Task.hl_relative / hl_absolute), or plain obs_hi for runs that predate it."""
  return ObsLayout.from_json(meta.get("hl_obs")).task_options()


def build_high_env(low_meta: dict, low_params, task: str, backend="auto", k=None, hl_horizon=None,
                   record=False, delta_max=None, low_obs_norm=None, **task_overrides) -> HighLevelEnv:
  """The HL env of ``task`` over an LL described by its checkpoint metadata
  (:meth:`hdt.transfer.card.PolicyCard.high_env`)."""
  return PolicyCard.from_json(low_meta).high_env(low_params, task, backend, k, hl_horizon, record, delta_max,
                                                 low_obs_norm,
                                                 **task_overrides)


def low_record(low: str | Path, low_seed: int, low_meta: dict) -> dict:
  """What an HL's metadata records of the frozen LL it was trained over."""
  return dict(path=str(low), seed_index=low_seed, params=low_meta["params"],
              params_env_steps=low_meta["params_env_steps"], sha256=ckpt.content_hash(low, low_seed))


def high_env_with_low(task: str, low: str | Path, low_seed: int = 0, backend="auto",
                      low_params: str = LOW_PARAMS, **kw) -> tuple[HighLevelEnv, dict]:
  """(HL env of ``task`` over the frozen LL saved in ``low``, :func:`low_record` of that LL)."""
  params, meta, _ = load_low(low, low_seed, ckpt.check_which(low_params, "low_params"))
  return (build_high_env(meta, params["policy"], task, backend, low_obs_norm=params.get(ckpt.NORM), **kw),
          low_record(low, low_seed, meta))


def high_env(task: str, low: str | Path, low_seed: int = 0, backend="auto", low_params: str = LOW_PARAMS,
             **kw) -> HighLevelEnv:
  """The HL env of ``task`` over the frozen LL saved in ``low`` (its seed ``low_seed``; its "best"
  evaluation's parameters by default, as the authors compose, or its "final" ones)."""
  return high_env_with_low(task, low, low_seed, backend, low_params, **kw)[0]


def train_high(task: str, low: str | Path, config: SACConfig | None = None, seeds=1, out=None,
               backend="auto", low_seed: int = 0, k: int | None = None, quiet=False,
               resume=False, save_every=None, low_params: str = LOW_PARAMS, overwrite=False,
               **task_overrides) -> RunResult:
  """HL SAC on ``task`` over the frozen LL in ``low`` (its seed ``low_seed`` drives every HL seed;
  ``low_params``: the LL's "best" evaluation's parameters (default, as the authors) or "final").
  backend: the physics backend ("auto", "mjx", "native"); seeds, out, quiet, resume, save_every,
  overwrite: see :class:`hdt.transfer.runner.RunOptions`."""
  options = RunOptions(seeds, out, quiet, resume, save_every, overwrite)
  return run_stage(high_stage(task, low, config, backend, low_seed, k, low_params, **task_overrides), options)


def high_stage(task: str, low: str | Path, config: SACConfig | None = None, backend="auto", low_seed: int = 0,
               k: int | None = None, low_params: str = LOW_PARAMS, **task_overrides) -> Stage:
  """The stage of :func:`train_high`."""
  configs.check_config(config, allow_none=True)
  check_env_overrides(task_overrides, task=task)
  env, low_rec = high_env_with_low(task, low, low_seed, backend, low_params, k=k, **task_overrides)
  config = configs.high_config(task) if config is None else config
  meta = env_meta(env, "high", config, low=low_rec, task_overrides=task_overrides)
  return Stage(env, config, meta, f"high {task}", save_extra=sac_extras)


def sac_extras(ts) -> dict:
  """The rest of an HL's SAC beside "policy" and "q" (target critics, log temperature), saved so that
  finetuning can start from A's whole SAC (``hdt.transfer.finetune``)."""
  return {"target_q": ts.agent.target_q_params, "log_alpha": ts.agent.log_alpha}


def train_full(agent: str, task: str, config: SACConfig | None = None, seeds=1, out=None,
               backend="auto", quiet=False, resume=False, save_every=None, overwrite=False,
               **env_overrides) -> RunResult:
  """The flat 'Full' baseline: SAC on the task with the agent's own torques.
  backend: the physics backend ("auto", "mjx", "native"); seeds, out, quiet, resume, save_every,
  overwrite: see :class:`hdt.transfer.runner.RunOptions`."""
  options = RunOptions(seeds, out, quiet, resume, save_every, overwrite)
  return run_stage(full_stage(agent, task, config, backend, **env_overrides), options)


def full_stage(agent: str, task: str, config: SACConfig | None = None, backend="auto", **env_overrides) -> Stage:
  """The stage of :func:`train_full`."""
  configs.check_config(config, allow_none=True)
  check_env_overrides(env_overrides, agent, task)
  env = make(agent, task, backend=backend, **env_overrides)
  config = configs.full_config(agent, task) if config is None else config
  return Stage(env, config, env_meta(env, "full", config, env_overrides=env_overrides), f"full {agent}/{task}")
