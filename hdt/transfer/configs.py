"""The one table of training defaults and presets, shared by the CLI, the Python API and hdt/paper/.

The paper's SAC hyper-parameters per level and agent family (SPEC 4, paper Appendix D) and the
budgets of ``--preset``. Defaults that belong to an agent or a task are data on them and read here:
``AgentSpec.ll_budget`` (LL env steps), ``Task.hl_budget`` (HL decisions; the Full baseline's LL env
steps), ``Task.finetune_kl_weight`` / ``finetune_lr``. Budgets are validated, never rounded: a budget that
does not split into whole chunks is refused with the nearest valid values.
"""

from __future__ import annotations

import dataclasses
import numbers

from hdt.agents.sac import SACConfig
from hdt.envs.families import FAMILIES
from hdt.envs.robot import agent_spec
from hdt.envs.tasks import TASKS, get_task

# Low level per family (budgets: AgentSpec.ll_budget): PM nav lr 3e-4 / batch 64 / [64,64] / buffer
# 200k; legged 8e-4 / 100 / [400,300] / 1M; manipulation 3e-4 / 100 / [128,96] / 250k.
_LOW = {
    "point": dict(actor_lr=3e-4, batch_size=64, hidden_sizes=(64, 64), buffer_size=200_000),
    "legged": dict(actor_lr=8e-4, batch_size=100, hidden_sizes=(400, 300), buffer_size=1_000_000),
    "manip": dict(actor_lr=3e-4, batch_size=100, hidden_sizes=(128, 96), buffer_size=250_000),
}
# High level: [64,64], lr 3e-4, batch 64, buffer 50k. Budgets (Task.hl_budget) are HL decisions (the
# paper's HL "Timesteps": SB2's SAC takes one env.step per timestep, and one step of the authors'
# HighLevelEnv is one sub-goal; utils/trainer.py, utils/loader.py).
_HIGH = dict(actor_lr=3e-4, batch_size=64, hidden_sizes=(64, 64), buffer_size=50_000)
_CHUNK = 1000  # training steps per compiled chunk unless a preset or the caller sets it
# hdt's fast setting of a legged LL (`--fast`; RESULTS.md, Table 1 ‡): twin-min critics with LayerNorm at
# lr 1e-3, [256,256], batch 128, time limits bootstrapped, one update per env step over 8 envs, and 50
# evaluation episodes every 10k env steps. The zoo's legged LLs were trained with it on top of
# ``--preset paper``; the authors' SB2 SAC stays the paper preset's default.
FAST_LOW = dict(hidden_sizes=(256, 256), batch_size=128, critic_layer_norm=True, bootstrap_time_limits=True,
                actor_lr=1e-3, critic_lr=1e-3, alpha_lr=1e-3, value_net=False, num_envs=8, updates_per_step=8,
                steps_per_chunk=1250, num_eval_episodes=50)


def family_key(agent: str) -> str:
  """The budget family of ``agent`` (a name or a robot file): "point" (a nav robot that cannot fall),
  "legged" or "manip"."""
  spec = agent_spec(agent)
  return "legged" if spec.legged else "point" if spec.family == "nav" else "manip"


def hl_budget(task: str) -> int:
  """The paper's HL budget of ``task`` in HL decisions (unknown tasks and reach are refused)."""
  t = get_task(task)
  if not t.hl_budget:
    with_hl = [n for n in TASKS if TASKS[n]().hl_budget]
    raise ValueError(f"task {task!r} has no HL budget (it is the LL's task); HL tasks: {', '.join(with_hl)}")
  return t.hl_budget


def _lrs(d):
  lr = d.get("actor_lr")
  return dict(d, critic_lr=lr, alpha_lr=lr) if lr else d


def _fit(cfg: dict, given=()) -> SACConfig:
  """The chunk defaults to at most 1000 training steps (fewer for a tiny budget) and learning starts
  within the first half unless ``given`` (the caller's own fields) sets it; the budget itself is never
  changed (SACConfig refuses one that does not split into whole chunks, naming the nearest valid
  values, and a learning_starts at or past it)."""
  total, n = cfg.get("total_env_steps"), cfg.get("num_envs", 1)
  counts = all(isinstance(v, numbers.Integral) and not isinstance(v, bool) and v > 0 for v in (total, n))
  if counts:  # else SACConfig names what is wrong
    cfg["steps_per_chunk"] = min(cfg.get("steps_per_chunk", _CHUNK), max(1, total // n))
    if "learning_starts" not in given and isinstance(cfg.get("learning_starts", 100), numbers.Integral):
      cfg["learning_starts"] = min(cfg.get("learning_starts", 100), total // 2)
  return SACConfig(**cfg)


def low_config(agent: str, **overrides) -> SACConfig:
  base = dict(_LOW[family_key(agent)], total_env_steps=agent_spec(agent).ll_budget)
  return _fit(_lrs(base) | overrides, overrides)


def high_config(task: str, **overrides) -> SACConfig:
  """HL SAC config; ``total_env_steps`` counts HL decisions."""
  return _fit(_lrs(dict(_HIGH, total_env_steps=hl_budget(task))) | overrides, overrides)


def finetune_config(task: str, **overrides) -> SACConfig:
  """HL finetuning config: the HL's, with the task's finetuning learning rate for actor, critic and
  temperature (paper: 0.01 Waypoint and manipulation, 0.001 Maze and Steps; :func:`finetune_params`)."""
  return high_config(task, **(dict.fromkeys(("actor_lr", "critic_lr", "alpha_lr"), finetune_params(task)["lr"])
                              | overrides))


def full_config(agent: str, task: str, **overrides) -> SACConfig:
  """Flat SAC on the task with the agent's torques: the agent's LL network, the task's budget (the
  Full baseline takes one torque per env step, so its budget is in LL env steps; paper table)."""
  return low_config(agent, **(dict(total_env_steps=hl_budget(task)) | overrides))


def replace(cfg: SACConfig, **kw) -> SACConfig:
  return _fit(dataclasses.asdict(check_config(cfg)) | kw, kw)


def check_config(config, what: str = "config", allow_none: bool = False) -> SACConfig | None:
  """``config`` if it is a SACConfig (or None with ``allow_none``: the stage's default), else a
  one-line error naming the argument."""
  if not (isinstance(config, SACConfig) or (allow_none and config is None)):
    raise ValueError(f"{what}={config!r}: pass a hdt.agents.sac.SACConfig (e.g. "
                     f"hdt.transfer.configs.low_config('point', total_env_steps=20000)), or None for the default")
  return config


def chunk_for(total_env_steps: int, num_envs: int, evals: int) -> int:
  """``steps_per_chunk`` that splits a budget into ``evals`` equal chunks (an evaluation after each);
  a budget that does not split is refused with the nearest ones that do."""
  unit = num_envs * evals
  if total_env_steps <= 0 or total_env_steps % unit:
    lo, hi = total_env_steps // unit * unit, (total_env_steps // unit + 1) * unit
    near = f"{lo} or {hi}" if lo > 0 else f"{hi}"
    raise ValueError(f"total_env_steps={total_env_steps} does not split into {evals} chunks of {num_envs} "
                     f"envs: use a multiple of {unit}, e.g. {near}")
  return total_env_steps // unit


# Budgets of --preset: "smoke" (CI, seconds), "cpu" (this 2-core machine, minutes), "paper" (the
# defaults above). Entries are SACConfig overrides per level ("low" also serves Full); the cpu LL
# budget is per family, split into 10 evaluation chunks.
PRESETS = {
    "smoke": dict(low=dict(total_env_steps=2000, num_envs=4, updates_per_step=4, steps_per_chunk=100,
                           num_eval_episodes=4),
                  high=dict(total_env_steps=400, num_envs=4, updates_per_step=4, steps_per_chunk=25,
                            num_eval_episodes=4)),
    "cpu": dict(low=dict(num_envs=8, updates_per_step=8, num_eval_episodes=16),
                high=dict(total_env_steps=6000, num_envs=8, updates_per_step=8, steps_per_chunk=75,
                          num_eval_episodes=8)),
    # the authors' SAC is SB2's (a state-value net, SACConfig.value_net); hdt's default is twin-min Q
    "paper": dict(low=dict(value_net=True), high=dict(value_net=True)),
}
CPU_LOW_STEPS = {"point": 20_000, "manip": 60_000, "legged": 100_000}
CPU_LOW_EVALS = 10

# MJX on a GPU or TPU: the throughput fields of the paper preset, in place of the authors' one env and
# one update per env step (a CPU schedule). Sources: brax's SAC configs (training colab: hopper and
# walker2d, 128 envs, batch 512 / 128, 64 / 32 updates per step, 8192 transitions before learning) and
# mujoco_playground's brax_sac_config (128 envs, batch 512, 8 updates per step). "high" also serves
# finetuning. Only with ``--preset paper`` (the budgets they were chosen for); options given win.
ACCELERATOR = {
    "low": dict(
        # MJX steps thousands of envs in one batched program for little more than the time of a few
        # (playground trains locomotion with 2048-8192, brax's PPO ant 4096); 2000 splits the paper's
        # decimal budgets, which powers of two do not
        num_envs=2000,
        # an update on a GPU costs about the same up to thousands of samples, so a batch ten times SB2's
        # 100 is nearly free and lowers the gradient noise (brax and playground SAC: 512)
        batch_size=1024,
        # 64 x 1024 samples per 2000 new transitions use each about 33 times, playground's ratio
        # (8 x 512 per 128); brax's SAC takes 32-64 updates per step
        updates_per_step=64,
        # brax and playground fill 8192 transitions (min_replay_size) before the first update
        learning_starts=10_000,
    ),
    "high": dict(
        # an HL env step runs up to k LL steps inside it, so 200 HL envs keep thousands of LL physics
        # steps in flight; 200 splits the HL budgets (200k-500k decisions)
        num_envs=200,
        batch_size=256,  # as the LL's: larger batches are nearly free on a GPU
        # 50 x 256 samples per 200 decisions use each 64 times, as the paper's HL (batch 64, one
        # update per decision)
        updates_per_step=50,
    ),
}
ACCELERATOR_EVALS = 10  # evaluations per run on an accelerator (playground's num_evals=10)


def on_accelerator(backend: str | None) -> bool:
  """Whether ``backend`` ("auto", "mjx", "native"; None: not known) runs MJX on a GPU or TPU."""
  import jax
  from hdt.envs.physics import resolve_backend
  return backend is not None and resolve_backend(backend) == "mjx" and jax.default_backend() != "cpu"


def accelerator_overrides(level: str, backend: str | None, total_env_steps: int, given=()) -> dict:
  """:data:`ACCELERATOR`'s fields of ``level`` when ``backend`` runs MJX on an accelerator (else {}),
  but those in ``given`` (the caller's own), with the chunk that splits ``total_env_steps`` into
  :data:`ACCELERATOR_EVALS` evaluations where it does (else SACConfig names the budgets that would)."""
  if not on_accelerator(backend):
    return {}
  over = {k: v for k, v in ACCELERATOR["high" if level in ("high", "finetune") else "low"].items() if k not in given}
  n = dict(over, **{k: v for k, v in dict(given).items() if k == "num_envs"}).get("num_envs", 1)
  if "steps_per_chunk" not in given and total_env_steps % (n * ACCELERATOR_EVALS) == 0:
    over["steps_per_chunk"] = total_env_steps // (n * ACCELERATOR_EVALS)
  if "learning_starts" in over:  # within the first half of a short run
    over["learning_starts"] = min(over["learning_starts"], total_env_steps // 2)
  return over


def stage_default(level: str, backend: str | None, agent: str | None = None, task: str | None = None,
                  **overrides) -> SACConfig:
  """A stage's config when it is given none: the paper's values of ``level`` (:func:`low_config`,
  :func:`high_config`, :func:`finetune_config`, :func:`full_config`) and ``overrides``, with
  :data:`ACCELERATOR`'s throughput where ``backend`` runs MJX on an accelerator."""
  build = {"low": lambda **kw: low_config(agent, **kw), "high": lambda **kw: high_config(task, **kw),
           "finetune": lambda **kw: finetune_config(task, **kw), "full": lambda **kw: full_config(agent, task, **kw)}
  total = overrides.get("total_env_steps") or build[level]().total_env_steps
  return build[level](**(accelerator_overrides(level, backend, total, overrides) | overrides))


# Deliberate departures from the authors' code that hdt makes by default (SPEC.md, "Departures"), as
# task options; ``--preset paper`` switches each off, so that "paper" is the authors' setup.
PAPER_TASK_OPTIONS = {
    # The authors' HL sees both absolute positions; hdt's sees the waypoint relative to the agent.
    "waypoint": dict(hl_relative=(), hl_absolute=True),
}


def task_options(preset: str, task: str) -> dict:
  """Task overrides that ``preset`` implies (``paper``: the authors' choices)."""
  return dict(PAPER_TASK_OPTIONS.get(task, {})) if preset == "paper" else {}


def preset_overrides(preset: str, level: str, agent: str | None = None) -> dict:
  """SACConfig overrides of ``preset`` for ``level`` ("low", "high", "finetune" (as "high") or "full")."""
  if preset not in PRESETS:
    raise ValueError(f"unknown preset {preset!r}; choose one of {sorted(PRESETS)}")
  over = dict(PRESETS[preset]["high" if level in ("high", "finetune") else "low"])
  if preset == "cpu" and level in ("low", "full"):
    steps = CPU_LOW_STEPS[family_key(agent)]
    over |= dict(total_env_steps=steps, steps_per_chunk=chunk_for(steps, over["num_envs"], CPU_LOW_EVALS))
  return over


def describe_paper_budgets() -> str:
  """The paper preset's budgets in one line (``--preset`` help), read from the agents and tasks."""
  k = lambda n: f"{n / 1e6:g}M" if n >= 1e6 else f"{n // 1000}k"
  low = "/".join(k(f["ll_budget"]) for f in FAMILIES.values())
  high = ", ".join(f"{k(hl_budget(t))} {t}" for t in TASKS if TASKS[t]().hl_budget)
  return f"{low} LL steps ({'/'.join(FAMILIES)}), {high} HL decisions"


def config(level: str, preset: str = "paper", agent: str | None = None, task: str | None = None,
           backend: str | None = None, **overrides) -> SACConfig:
  """The SACConfig of a training stage: the paper's values for the agent (``low``, ``full``) or the
  task (``high``, ``finetune``, ``full``), then ``preset``'s budget, with ``paper`` on a ``backend``
  that runs MJX on an accelerator its :data:`ACCELERATOR` throughput, then ``overrides``. The CLI and
  hdt/paper/ both build their configs here."""
  over = preset_overrides(preset, level, agent) | overrides
  if preset == "paper" and on_accelerator(backend):
    total = over.get("total_env_steps") or (agent_spec(agent).ll_budget if level == "low" else hl_budget(task))
    over = accelerator_overrides(level, backend, total, over) | over
  if level == "high":
    return high_config(task, **over)
  if level == "finetune":
    return finetune_config(task, **over)
  if level == "full":
    return full_config(agent, task, **over)
  if level == "low":
    return low_config(agent, **over)
  raise ValueError(f"unknown level {level!r}; choose low, high, finetune or full")


def disc_config(agent_a: str, **overrides):
  """The discriminator of an alignment to ``agent_a``'s LL: the paper's hyper-parameters by A (paper
  table "discriminator training": nav PM lr 2e-4 weight 0.3; manipulation PM and 2Link lr 3e-4, 3Link
  (and 4Link) 5e-4, weight 0.4) and A's data mode: offline for nav (the authors' README command,
  ``--discrim-online false``), online for manipulation (``DiscriminatorEnv``'s default; the paper's
  main Table 2 manipulation numbers are its Table 8 "Discrim On" row)."""
  from hdt.agents.discriminator import DiscConfig  # configs stays importable without flax
  spec = agent_spec(agent_a)
  base = {} if spec.family == "nav" else dict(lr=3e-4 if agent_a in ("arm_point", "arm2") else 5e-4,
                                              weight=0.4, data="online")
  return DiscConfig(**(base | overrides))


def finetune_params(task: str) -> dict:
  """KL weight and learning rate of HL finetuning (SPEC 4; ``Task.finetune_kl_weight`` / ``finetune_lr``):
  Maze and Steps beta 0.01 lr 1e-3; Waypoint and manipulation beta 1, lr 1e-2."""
  t = get_task(task)
  return dict(kl_weight=t.finetune_kl_weight, lr=t.finetune_lr)
