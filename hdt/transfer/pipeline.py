"""One call per stage: ``train_low``, ``train_high``, ``train_full``, each a vmapped seed sweep that
writes a run directory (config.json, meta.json, metrics.csv, seed_<i>/ checkpoints). Each builds its
:class:`hdt.transfer.runner.Stage` (``low_stage``, ``high_stage``, ``full_stage``: env, config, card,
plug-ins) and hands it with its :class:`hdt.transfer.runner.RunOptions` (keyword ``options``: seeds,
out, quiet, resume, save_every, overwrite) to :func:`hdt.transfer.runner.run_stage`; meta.json is the
run's :class:`hdt.transfer.card.PolicyCard`. An HL's frozen LL is a run directory (or ``zoo:NAME``), or
a :class:`hdt.transfer.card.LowRef` naming its seed and parameters."""

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
from hdt.transfer.align import AlignSpec, align_low
from hdt.transfer.card import LOW_PARAMS, LowRef, PolicyCard, load_low, low_policy_fn  # noqa: F401 (part of this API)
from hdt.transfer.hierarchy import HighLevelEnv
from hdt.transfer.runner import Level, RunOptions, RunResult, Stage, run_stage


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


def train_low(agent: str, config: SACConfig | None = None, *, imitate: AlignSpec | str | Path | None = None,
              backend: str = "auto", options: RunOptions = RunOptions(), **env_overrides) -> RunResult:
  """Goal-conditioned LL of ``agent`` on its ``reach`` task (SPEC 3). With ``imitate`` (A's LL run, or
  an :class:`hdt.transfer.align.AlignSpec`) the LL is aligned to A's behaviour by a discriminator
  (Algorithm 1, :func:`hdt.transfer.align.align_low`). backend: the physics backend ("auto", "mjx",
  "native"); options: how it runs (:class:`hdt.transfer.runner.RunOptions`)."""
  if imitate is not None:
    return align_low(agent, imitate, config, backend=backend, options=options, **env_overrides)
  return run_stage(low_stage(agent, config, backend, **env_overrides), options)


def low_stage(agent: str, config: SACConfig | None = None, backend: str = "auto", **env_overrides) -> Stage:
  """The stage of :func:`train_low` (without ``imitate``)."""
  configs.check_config(config, allow_none=True)
  check_env_overrides(env_overrides, agent, "reach")
  env = make(agent, "reach", backend=backend, **env_overrides)
  config = configs.stage_default("low", backend, agent) if config is None else config
  return Stage(env, config, PolicyCard.from_env(env, "low", config, env_overrides=env_overrides), f"low {agent}")


def high_env_with_low(task: str, low: LowRef | str | Path, backend: str = "auto", **kw) -> tuple[HighLevelEnv, LowRef]:
  """(the HL env of ``task`` over the frozen LL ``low``, the :class:`LowRef` an HL's card records of
  it: with its parameters' env steps and the seed's content hash)."""
  low = LowRef.of(low)
  params, card, _ = load_low(low.path, low.seed_index, low.params or LOW_PARAMS)
  env = card.high_env(params["policy"], task, backend, low_obs_norm=params.get(ckpt.NORM), **kw)
  return env, dataclasses.replace(low, params=card.loaded, params_env_steps=card.loaded_env_steps,
                                  sha256=ckpt.content_hash(low.path, low.seed_index))


def high_env(task: str, low: LowRef | str | Path, backend: str = "auto", **kw) -> HighLevelEnv:
  """The HL env of ``task`` over the frozen LL ``low``: a run directory (its seed 0 and its "best"
  evaluation's parameters, as the authors compose) or a :class:`LowRef` naming another seed or its
  "final" parameters; ``kw``: :meth:`hdt.transfer.card.PolicyCard.high_env`'s options (k, record, ...)
  and task options."""
  return high_env_with_low(task, low, backend, **kw)[0]


def train_high(task: str, low: LowRef | str | Path, config: SACConfig | None = None, *, k: int | None = None,
               backend: str = "auto", options: RunOptions = RunOptions(), **task_overrides) -> RunResult:
  """HL SAC on ``task`` over the frozen LL ``low`` (a run directory, whose seed 0 drives every HL seed
  with its "best" evaluation's parameters, as the authors; or a :class:`LowRef` naming another seed or
  its "final" parameters). k: LL steps per HL decision (default the LL's). backend: the physics
  backend ("auto", "mjx", "native"); options: how it runs (:class:`hdt.transfer.runner.RunOptions`)."""
  return run_stage(high_stage(task, low, config, k, backend, **task_overrides), options)


def high_stage(task: str, low: LowRef | str | Path, config: SACConfig | None = None, k: int | None = None,
               backend: str = "auto", **task_overrides) -> Stage:
  """The stage of :func:`train_high`."""
  configs.check_config(config, allow_none=True)
  check_env_overrides(task_overrides, task=task)
  env, low = high_env_with_low(task, low, backend, k=k, **task_overrides)
  config = configs.stage_default("high", backend, task=task) if config is None else config
  card = PolicyCard.from_env(env, "high", config, low=low, task_overrides=task_overrides)
  return Stage(env, config, card, f"high {task}", save_extra=sac_extras)


def sac_extras(ts) -> dict:
  """The rest of an HL's SAC beside "policy" and "q" (target critics, log temperature), saved so that
  finetuning can start from A's whole SAC (``hdt.transfer.finetune``)."""
  return {"target_q": ts.agent.target_q_params, "log_alpha": ts.agent.log_alpha}


def train_full(agent: str, task: str, config: SACConfig | None = None, *, backend: str = "auto",
               options: RunOptions = RunOptions(), **env_overrides) -> RunResult:
  """The flat 'Full' baseline: SAC on the task with the agent's own torques. backend: the physics
  backend ("auto", "mjx", "native"); options: how it runs (:class:`hdt.transfer.runner.RunOptions`)."""
  return run_stage(full_stage(agent, task, config, backend, **env_overrides), options)


def full_stage(agent: str, task: str, config: SACConfig | None = None, backend: str = "auto",
               **env_overrides) -> Stage:
  """The stage of :func:`train_full`."""
  configs.check_config(config, allow_none=True)
  check_env_overrides(env_overrides, agent, task)
  env = make(agent, task, backend=backend, **env_overrides)
  config = configs.stage_default("full", backend, agent, task) if config is None else config
  card = PolicyCard.from_env(env, "full", config, env_overrides=env_overrides)
  return Stage(env, config, card, f"full {agent}/{task}")


LOW = Level("low", low_stage, needs=("agent",))
HIGH = Level("high", high_stage, needs=("task", "low"))
FULL = Level("full", full_stage, needs=("agent", "task"))
