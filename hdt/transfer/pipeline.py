"""One call per stage: ``train_low``, ``train_high``, ``train_full``, each a vmapped seed sweep that
writes a run directory (config.json, meta.json, metrics.csv, seed_<i>/ checkpoints)."""

from __future__ import annotations

import csv
import dataclasses
import sys
import time
from pathlib import Path
from typing import Any, Callable

import jax
import numpy as np

from hdt.agents import networks as nets
from hdt.agents import train as sac_train
from hdt.agents.sac import SACConfig
from hdt.envs import make
from hdt.envs.robot import check_recorded, robot_record
from hdt.envs.spec import AgentSpec
from hdt.envs.tasks import TASKS
from hdt.transfer import checkpoint as ckpt
from hdt.transfer import configs
from hdt.transfer.hierarchy import HighLevelEnv


@dataclasses.dataclass
class RunResult:
  run_dir: Path | None
  params: Any  # {"policy", "q"} with a leading seed axis
  history: dict[str, np.ndarray]  # leading seed axis
  meta: dict


def low_policy_fn(hidden_sizes, obs_size: int, action_size: int) -> Callable:
  """Deterministic action of a saved SAC policy: tanh of the pre-tanh mean."""
  net = nets.make_sac_networks(obs_size, action_size, tuple(hidden_sizes))
  return lambda params, obs: nets.deterministic_action(net.policy_apply(params, obs)[0])


def env_meta(env, level: str, config: SACConfig, **extra) -> dict:
  agent = env.agent if hasattr(env, "agent") else env.env.agent
  task = env.task if hasattr(env, "task") else env.env.task
  return dict(level=level, agent=agent.name, task=task.name, family=agent.family,
              goal_space=f"{agent.family}:{task.point_sensor}", delta_max=agent.delta_max, k=agent.k,
              obs_size=int(env.observation_size), action_size=int(env.action_size),
              obs_lo_size=int(env.obs_lo_size), obs_hi_size=int(env.obs_hi_size),
              hidden_sizes=list(config.hidden_sizes), sac=dataclasses.asdict(config)) \
      | robot_record(agent) | extra  # a robot file: its path is the agent, and its sha256


def print_progress(total: int, quiet: bool = False, label: str = "") -> Callable[[int, dict], None]:
  """A one-line progress report per chunk: steps, steps/s, ETA and the latest evaluation."""
  t0 = time.perf_counter()

  def progress(step, metrics):
    if quiet:
      return
    dt = time.perf_counter() - t0
    rate = step / max(dt, 1e-9)
    evals = {k[5:]: float(np.mean(v)) for k, v in metrics.items()
             if k in ("eval/return", "eval/success_max", "eval/goal_dist")}
    ev = " ".join(f"{k}={v:.3g}" for k, v in evals.items())
    frac = step / total
    bar = "#" * int(20 * frac) + "-" * (20 - int(20 * frac))
    print(f"{label} [{bar}] {step}/{total} steps {rate:.0f}/s ETA {(total - step) / max(rate, 1e-9):.0f}s {ev}",
          file=sys.stderr, flush=True)
  return progress


def _run(env, config: SACConfig, seeds, out, meta: dict, quiet: bool, label: str, resume=False,
         save_every: int | None = None, save_extra: Callable[[Any], dict] | None = None,
         **plugins) -> RunResult:
  """Trains, saving the resumable state to ``out/state`` every ``save_every`` env steps and at the
  end, then writes the run directory. Every argument is checked before anything is written.
  save_extra(final TrainState) -> {name: pytree with a seed axis} saved next to "policy" and "q"
  in every seed's checkpoint (e.g. the discriminator of an aligned LL)."""
  seeds = sac_train.seed_list(seeds)
  run_dir, source = _outputs(out, resume)
  save_steps = _save_steps(config, save_every)
  ts, trainer = plugins.pop("initial_state", None), plugins.pop("trainer", None)
  trainer = trainer or sac_train.make_train(env, config, **plugins)
  info = dict(config=dataclasses.asdict(config), meta=meta, seeds=seeds)
  history = None
  if source is not None:
    ts, history = _resume(source, trainer, info)

  def on_chunk(step, ts, hist):
    if run_dir is not None and (step // save_steps > (step - config.env_steps_per_chunk) // save_steps
                                or step == config.total_env_steps):
      ckpt.save_state(run_dir, ts, {k: np.stack(v, axis=1) for k, v in hist.items()},
                      dict(info, env_steps=step))

  progress = print_progress(config.total_env_steps, quiet, label)
  try:
    res = sac_train.run(env, config, seeds, progress_fn=progress, trainer=trainer, initial_state=ts,
                        initial_history=history, eval_at_start=history is None, on_chunk=on_chunk)
  except sac_train.TrainingDiverged as e:
    kept = run_dir is not None and ckpt.state_dir(run_dir).exists()
    note = (f" The last good training state is kept in {ckpt.state_dir(run_dir)}." if kept else "")
    raise sac_train.TrainingDiverged(str(e) + note, e.term, e.env_step, e.seeds) from None
  params = dict(res.params, **(save_extra(res.state) if save_extra else {}))
  if run_dir is not None:
    run_dir.mkdir(parents=True, exist_ok=True)
    ckpt.write_json_atomic(run_dir / "config.json", dataclasses.asdict(config))
    ckpt.write_json_atomic(run_dir / "meta.json", dict(meta, seeds=seeds))
    for i, s in enumerate(seeds):
      ckpt.save(run_dir, i, jax.tree.map(lambda x: x[i], params), dict(meta, seed=s))
    write_metrics_csv(run_dir / "metrics.csv", res.history, seeds)
    write_tensorboard(run_dir / "tb", res.history, seeds)
  return RunResult(run_dir, params, res.history, meta)


def _outputs(out, resume) -> tuple[Path | None, Path | None]:
  """(run dir to write or None, run dir to resume from or None), checked without touching disk."""
  if not isinstance(resume, (bool, str, Path)):
    raise ValueError(f"resume={resume!r}: pass True (resume from out=), a run directory, or False")
  if resume is not False and resume is not True:
    source = Path(resume)
    out = source if out is None else out
  else:
    source = None
    if resume:
      if out is None:
        raise ValueError("resume=True needs out=: the run directory of the interrupted run")
      source = Path(out)
  if out is not None and Path(out).exists() and not Path(out).is_dir():
    raise ValueError(f"out={out} is an existing file; pass a directory for the run (it will hold "
                     f"config.json, metrics.csv, seed_0/, state/, ...)")
  return (None if out is None else Path(out)), source


def _save_steps(config: SACConfig, save_every) -> int:
  """Env steps between saves of the resumable state; default about a tenth of the run."""
  if save_every is None:
    return max(1, config.num_chunks // 10) * config.env_steps_per_chunk
  if isinstance(save_every, bool) or not isinstance(save_every, (int, np.integer)) or save_every <= 0:
    raise ValueError(f"save_every={save_every!r}: give a positive number of env steps between saves of "
                     f"the resumable state (it is saved at the first chunk end past each multiple), "
                     f"or None for about every 10% of training")
  return int(save_every)


def _resume(source: Path, trainer, info: dict):
  """The saved TrainState (device arrays) and history of ``source``, refused if the saved run was
  started with another configuration, run metadata or seeds than ``info`` describes."""
  saved = ckpt.load_state_info(source)
  no_sac = lambda d: {k: ({m: v for m, v in d[k].items() if m != "sac"} if k == "meta" else d.get(k))
                      for k in info}  # meta["sac"] repeats the config
  diffs = ckpt.differences(no_sac(saved), no_sac(info))
  if diffs:
    raise ckpt.CheckpointError(
        f"cannot resume from {source}: the saved run differs from the requested one in "
        f"{'; '.join(diffs[:6])}{' ...' if len(diffs) > 6 else ''}. Resume with the saved settings "
        f"(see {ckpt.state_dir(source) / 'state.json'}) or start a new run in another out= directory")
  template = jax.eval_shape(sac_train.vmapped(trainer).init,
                            sac_train.seed_keys(info["seeds"]))
  ts, history, _ = ckpt.load_state(source, template)
  return jax.device_put(ts), history


def write_metrics_csv(path: Path, history: dict, seeds) -> None:
  """Long format: one row per (seed, chunk) with training metrics, one per evaluation with eval/*."""
  rows = []
  train = {k: np.asarray(v) for k, v in history.items() if not k.startswith("eval/")}
  ev = {k: np.asarray(v) for k, v in history.items() if k.startswith("eval/")}
  for i, s in enumerate(seeds):
    for c in range(next(iter(train.values())).shape[1] if train else 0):
      rows.append({"seed": s, "kind": "train"} | {k: float(np.mean(v[i, c])) for k, v in train.items()})
    for e in range(next(iter(ev.values())).shape[1] if ev else 0):
      rows.append({"seed": s, "kind": "eval", "env_steps": float(ev["eval/env_steps"][i, e])}
                  | {k: float(np.mean(v[i, e])) for k, v in ev.items()})
  keys = list(dict.fromkeys(k for r in rows for k in r))
  tmp = path.with_name("." + path.name + ".tmp")
  with open(tmp, "w", newline="") as f:
    w = csv.DictWriter(f, fieldnames=keys)
    w.writeheader()
    w.writerows(rows)
  tmp.replace(path)


def write_tensorboard(log_dir: Path, history: dict, seeds) -> None:
  """TensorBoard event files, one run per seed (``tensorboard --logdir RUN/tb``), x = env steps."""
  from tensorboardX import SummaryWriter

  for i, s in enumerate(seeds):
    with SummaryWriter(str(log_dir / f"seed_{s}")) as w:
      steps = {"train": history.get("env_steps"), "eval": history.get("eval/env_steps")}
      for k, v in history.items():
        x = steps["eval" if k.startswith("eval/") else "train"]
        v = np.asarray(v)
        if x is None or k.endswith("env_steps") or not np.issubdtype(v.dtype, np.number):
          continue
        for c in range(v.shape[1]):
          if np.all(np.isfinite(v[i, c])):  # e.g. losses before learning starts
            w.add_scalar(k if "/" in k else f"train/{k}", float(np.mean(v[i, c])), int(np.asarray(x)[i, c]))


RESUME_DOC = """
  resume: False (default) starts afresh; True continues the interrupted run in ``out`` from its
    ``out/state`` (same arguments and config; refused with a CheckpointError naming what differs);
    a run directory continues that run (writing to ``out``, default the same directory). The
    continued run equals an uninterrupted one exactly (same seeds, same device).
  save_every: env steps between saves of the resumable state ``out/state`` (whole TrainState and
    history, written atomically); default about every 10% of training; always saved at the end."""


def train_low(agent: str, config: SACConfig | None = None, seeds=1, out=None, backend="auto",
              quiet=False, imitate=None, disc=None, resume=False, save_every=None,
              **env_overrides) -> RunResult:
  """Goal-conditioned LL of ``agent`` on its ``reach`` task (SPEC 3). With ``imitate=<LL run of A>``
  the LL is aligned to A's behaviour by a discriminator (Algorithm 1, ``hdt.transfer.align``)."""
  if imitate is not None:
    from hdt.transfer.align import align_low  # align builds on this module
    kw = {} if disc is None else {"disc": disc}
    return align_low(agent, imitate, config, seeds=seeds, out=out, backend=backend, quiet=quiet,
                     resume=resume, save_every=save_every, **kw, **env_overrides)
  env = make(agent, "reach", backend=backend, **env_overrides)
  config = config or configs.low_config(agent)
  meta = env_meta(env, "low", config, env_overrides=env_overrides)
  return _run(env, config, seeds, out, meta, quiet, f"low {agent}", resume, save_every)


def load_low(low: str | Path, seed_index: int = 0):
  """(params, meta, policy_fn) of a saved LL, checked to be a low level."""
  params, meta = ckpt.load(low, seed_index)
  if meta.get("level") != "low":
    raise ckpt.CheckpointError(f"{low} holds a {meta.get('level')!r}-level policy where a low level "
                               f"was expected (train one with `hdt train low --agent ...`)")
  check_recorded(meta)
  fn = low_policy_fn(meta["hidden_sizes"], meta["obs_size"], meta["action_size"])
  return params, meta, fn


def hl_obs_layout(meta: dict) -> dict:
  """The task options that give an HL checkpoint the observation it was trained on: the recorded
  ``hl_obs`` (hdt.envs.tasks.Task.hl_relative / hl_absolute), or plain obs_hi for runs that predate it."""
  layout = meta.get("hl_obs") or {"hl_relative": [], "hl_absolute": True}
  return {"hl_relative": tuple(int(i) for i in layout["hl_relative"]), "hl_absolute": bool(layout["hl_absolute"])}


def _hl_obs_meta(env: HighLevelEnv) -> dict:
  task = env.env.task
  return {"hl_relative": [int(i) for i in task.hl_relative], "hl_absolute": bool(task.hl_absolute)}


def build_high_env(low_meta: dict, low_params, task: str, backend="auto", k=None, hl_horizon=None,
                   record=False, delta_max=None, **task_overrides) -> HighLevelEnv:
  """The HL env of ``task`` over an LL described by its checkpoint metadata. The inner env's own
  time limit is disabled: the HL env counts HL steps."""
  if task not in TASKS:
    raise ValueError(f"unknown task {task!r}; valid tasks: {', '.join(TASKS)}")
  # hl_horizon may come as a task override too; it never reaches the inner env
  overridden = task_overrides.pop("hl_horizon", None)
  hl_horizon = next((h for h in (hl_horizon, overridden) if h is not None), TASKS[task]().hl_horizon)
  # Only the LL's morphology options carry over; its reach-task options (terrain=...) do not
  # belong to the HL task.
  check_recorded(low_meta)  # a robot file must still be there, unchanged
  agent_fields = {f.name for f in dataclasses.fields(AgentSpec)}
  morph = {k: v for k, v in (low_meta.get("env_overrides") or {}).items() if k in agent_fields}
  inner = make(low_meta["agent"], task, backend=backend, hl_horizon=10**6, **morph | task_overrides)
  if inner.obs_lo_size + 2 != low_meta["obs_size"]:
    raise ckpt.CheckpointError(
        f"the LL observes {low_meta['obs_size']} numbers but {low_meta['agent']} on {task} gives "
        f"{inner.obs_lo_size} + 2: was it trained with other options (e.g. rangefinders for steps)?")
  fn = low_policy_fn(low_meta["hidden_sizes"], low_meta["obs_size"], low_meta["action_size"])
  return HighLevelEnv(inner, fn, low_params, k=low_meta["k"] if k is None else k, hl_horizon=hl_horizon,
                      record=record, delta_max=low_meta["delta_max"] if delta_max is None else delta_max)


def high_env(task: str, low: str | Path, low_seed: int = 0, backend="auto", **kw) -> HighLevelEnv:
  """The HL env of ``task`` over the frozen LL saved in ``low`` (its seed ``low_seed``)."""
  params, meta, _ = load_low(low, low_seed)
  return build_high_env(meta, params["policy"], task, backend, **kw)


def train_high(task: str, low: str | Path, config: SACConfig | None = None, seeds=1, out=None,
               backend="auto", low_seed: int = 0, k: int | None = None, quiet=False,
               resume=False, save_every=None, **task_overrides) -> RunResult:
  """HL SAC on ``task`` over the frozen LL in ``low`` (its seed ``low_seed`` drives every HL seed)."""
  env = high_env(task, low, low_seed, backend, k=k, **task_overrides)
  config = config or configs.high_config(task, env.k)
  meta = env_meta(env, "high", config, k=env.k, hl_horizon=env.horizon, delta_max=env.delta_max,
                  low=dict(path=str(low), seed_index=low_seed), task_overrides=task_overrides,
                  hl_obs=_hl_obs_meta(env))
  return _run(env, config, seeds, out, meta, quiet, f"high {task}", resume, save_every,
              save_extra=sac_extras)


def sac_extras(ts) -> dict:
  """The rest of an HL's SAC beside "policy" and "q" (target critics, log temperature), saved so that
  finetuning can start from A's whole SAC (``hdt.transfer.finetune``)."""
  return {"target_q": ts.agent.target_q_params, "log_alpha": ts.agent.log_alpha}


def train_full(agent: str, task: str, config: SACConfig | None = None, seeds=1, out=None,
               backend="auto", quiet=False, resume=False, save_every=None,
               **env_overrides) -> RunResult:
  """The flat 'Full' baseline: SAC on the task with the agent's own torques."""
  env = make(agent, task, backend=backend, **env_overrides)
  config = config or configs.full_config(agent, task)
  meta = env_meta(env, "full", config, env_overrides=env_overrides)
  return _run(env, config, seeds, out, meta, quiet, f"full {agent}/{task}", resume, save_every)


for _f in (train_low, train_high, train_full):
  _f.__doc__ = (_f.__doc__ or "") + RESUME_DOC  # (None under python -OO)
del _f
