"""One call per stage: ``train_low``, ``train_high``, ``train_full``, each a vmapped seed sweep that
writes a run directory (config.json, meta.json, metrics.csv, seed_<i>/ checkpoints)."""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import os
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
from hdt.transfer import rundir
from hdt.transfer.hierarchy import HighLevelEnv


@dataclasses.dataclass
class RunResult:
  run_dir: Path | None
  params: Any  # {"policy", "q"} with a leading seed axis
  history: dict[str, np.ndarray]  # leading seed axis
  meta: dict
  best: dict | None = None  # best periodic evaluation per seed (hdt.agents.train.update_best)


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
         overwrite: bool = False, **plugins) -> RunResult:
  """Trains, saving the resumable state to ``out/state`` every ``save_every`` env steps and at the
  end, then writes the run directory. Every argument is checked before anything is written, and
  ``out`` is claimed (hdt.transfer.rundir: owned by hdt, locked, replaced whole with ``overwrite``)
  before anything is compiled. save_extra(final TrainState) -> {name: pytree with a seed axis}
  saved next to "policy" and "q" in every seed's checkpoint (e.g. the discriminator of an aligned LL)."""
  check_train_memory(env, config, seeds)
  seeds = sac_train.seed_list(seeds)
  run_dir, source = _outputs(out, resume, overwrite)
  save_steps = _save_steps(config, save_every)
  ts, trainer = plugins.pop("initial_state", None), plugins.pop("trainer", None)
  trainer = trainer or sac_train.make_train(env, config, **plugins)
  info = dict(config=dataclasses.asdict(config), meta=meta, seeds=seeds)
  if source is not None:
    _check_resumable(source, info)
  claim = (contextlib.nullcontext() if run_dir is None else
           rundir.claim(run_dir, resume=source is not None and _same(source, run_dir), overwrite=overwrite))
  with claim:
    history = best = None
    if run_dir is not None and source is not None and _same(source, run_dir):
      ckpt.settle_state(run_dir)
    if source is not None:
      ts, history, best = _resume(source, trainer, info)

    def on_chunk(step, ts, hist, best):
      if run_dir is not None and (step // save_steps > (step - config.env_steps_per_chunk) // save_steps
                                  or step == config.total_env_steps):
        with rundir.deferred_interrupt():
          ckpt.save_state(run_dir, ts, {k: np.stack(v, axis=1) for k, v in hist.items()},
                          dict(info, env_steps=step), best)

    progress = print_progress(config.total_env_steps, quiet, label)
    try:
      with counted_mujoco_warnings(quiet) as warned:
        res = sac_train.run(env, config, seeds, progress_fn=progress, trainer=trainer, initial_state=ts,
                            initial_history=history, initial_best=best, eval_at_start=history is None,
                            on_chunk=on_chunk)
    except sac_train.TrainingDiverged as e:
      kept = run_dir is not None and ckpt.has_state(run_dir)
      note = (f" The last good training state is kept in {ckpt.state_dir(run_dir)}." if kept else "")
      note += f" MuJoCo reported {len(warned)} simulation warning(s) before." if warned else ""
      raise sac_train.TrainingDiverged(str(e) + note, e.term, e.env_step, e.seeds) from None
    params = dict(res.params, **(save_extra(res.state) if save_extra else {}))
    if run_dir is not None:
      with rundir.deferred_interrupt():  # a Ctrl-C here would leave some seeds unwritten
        _write_run(run_dir, config, meta, seeds, params, res)
  return RunResult(run_dir, params, res.history, meta, res.best)


@contextlib.contextmanager
def counted_mujoco_warnings(quiet: bool = False):
  """MuJoCo prints each instability warning ("Nan, Inf or huge value in QACC ...") once per env
  step, hundreds of lines before hdt's NaN guard stops a diverging run: inside the block they are
  counted instead (yields the list of messages), and summed up in one line at the end."""
  import mujoco
  seen: list[str] = []
  previous = mujoco.get_mju_user_warning()
  mujoco.set_mju_user_warning(seen.append)  # also called from the native backend's threads
  try:
    yield seen
  finally:
    mujoco.set_mju_user_warning(previous)
    if seen and not quiet:
      print(f"MuJoCo reported {len(seen)} simulation warning(s), first: {' '.join(seen[0].split())}",
            file=sys.stderr, flush=True)


def _write_run(run_dir: Path, config: SACConfig, meta: dict, seeds: list, params, res) -> None:
  """The run's outputs; meta.json last, so a run directory with meta.json is complete."""
  unit = "HL decisions" if meta.get("level") == "high" else "env steps"  # what total_env_steps counts
  ckpt.write_json_atomic(run_dir / "config.json", dict(dataclasses.asdict(config), budget_unit=unit))
  for i, s in enumerate(seeds):
    ckpt.save(run_dir, i, jax.tree.map(lambda x: x[i], params), dict(meta, seed=s),
              best=_seed_best(res.best, i))
  write_metrics_csv(run_dir / "metrics.csv", res.history, seeds)
  write_tensorboard(run_dir / "tb", res.history, seeds)
  ckpt.write_json_atomic(run_dir / "meta.json", dict(meta, seeds=seeds))


def _same(a: Path, b: Path) -> bool:
  return Path(os.path.abspath(a)) == Path(os.path.abspath(b))


def _available_bytes() -> int:
  try:
    with open("/proc/meminfo") as f:
      return next(int(line.split()[1]) * 1024 for line in f if line.startswith("MemAvailable:"))
  except (OSError, StopIteration, ValueError):
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def _tree_bytes(tree) -> int:
  return sum(int(np.prod(x.shape)) * np.dtype(x.dtype).itemsize for x in jax.tree.leaves(tree))


def state_bytes(env) -> int:
  """Bytes of one env state (from its shapes, nothing allocated)."""
  return _tree_bytes(jax.eval_shape(env.reset, jax.ShapeDtypeStruct((2,), np.uint32)))


def check_memory(need: int, what: str, fix: str) -> None:
  """Refuses (one line) a request whose estimated size ``need`` exceeds 90% of available memory."""
  avail = _available_bytes()
  if need > 0.9 * avail:
    raise ValueError(f"{what} needs about {need / 2**30:.3g} GiB but {avail / 2**30:.3g} GiB of memory are "
                     f"available: {fix}")


def check_train_memory(env, config: SACConfig, seeds) -> None:
  """Estimate: per seed, the replay buffer (obs, next obs, action, reward, discount in float32) and
  the parallel training and evaluation env states."""
  n = seeds if isinstance(seeds, (int, np.integer)) and not isinstance(seeds, bool) else \
      (len(seeds) if hasattr(seeds, "__len__") else 1)
  if n <= 0:
    return  # seed_list explains
  transition = 4 * (2 * env.observation_size + env.action_size + 2)
  per_seed = (config.buffer_size * transition
              + (config.num_envs + config.num_eval_episodes) * state_bytes(env))
  check_memory(n * per_seed, f"training {n} seeds (replay buffer of {config.buffer_size} and "
               f"{config.num_envs} + {config.num_eval_episodes} env states per seed)",
               "lower the number of seeds, buffer_size, num_envs or num_eval_episodes")


def _seed_best(best: dict | None, i: int) -> tuple[dict, dict] | None:
  """(params, info) of seed ``i``'s best evaluation for :func:`ckpt.save`, None if it has none."""
  if best is None or best["env_steps"][i] < 0:
    return None
  info = dict(env_steps=int(best["env_steps"][i]), eval_return=float(best["return"][i]),
              criterion=f"highest mean {sac_train.BEST_CRITERION} over the periodic evaluations")
  return {k: jax.tree.map(lambda x: x[i], best[k]) for k in ("policy", "q")}, info


# Options that only make sense positive (a zero k or box later breaks the HL over this LL).
_POSITIVE = {"k", "delta_max", "frame_skip", "ll_horizon", "hl_horizon", "reach_eps", "contact_clip", "gear_scale"}


def check_env_overrides(overrides: dict, agent: str | None = None, task: str | None = None) -> None:
  """Each agent/task option has the type of its default (finite numbers; positive where only that
  makes sense); unknown names are left to :func:`hdt.envs.make`, which lists the valid ones."""
  from hdt.envs.agents import AGENTS
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


def _outputs(out, resume, overwrite=False) -> tuple[Path | None, Path | None]:
  """(run dir to write or None, run dir to resume from or None), checked without touching disk."""
  if resume is not False and overwrite:
    raise ValueError("resume and overwrite exclude each other: resume continues the run in out=, "
                     "overwrite replaces it")
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
  if source is not None:
    ckpt.load_state_info(source)  # exists, readable, of this format
  if out is not None:
    same = source is not None and _same(source, out)
    out = rundir.check_claimable(out, resume=same, overwrite=overwrite)
  return out, source


def _save_steps(config: SACConfig, save_every) -> int:
  """Env steps between saves of the resumable state; default about a tenth of the run."""
  if save_every is None:
    return max(1, config.num_chunks // 10) * config.env_steps_per_chunk
  if isinstance(save_every, bool) or not isinstance(save_every, (int, np.integer)) or save_every <= 0:
    raise ValueError(f"save_every={save_every!r}: give a positive number of env steps between saves of "
                     f"the resumable state (it is saved at the first chunk end past each multiple), "
                     f"or None for about every 10% of training")
  return int(save_every)


def _check_resumable(source: Path, info: dict) -> None:
  """Refuses (reading only) to resume ``source`` if its run was started with another configuration,
  run metadata or seeds than ``info`` describes, or a checkpoint it depends on changed since."""
  saved = ckpt.load_state_info(source)
  for key, kind in (("config", dict), ("meta", dict), ("seeds", list)):
    if not isinstance(saved.get(key), kind):
      raise ckpt.CheckpointError(f"the training state in {source} has {key}={saved.get(key)!r}: state.json was "
                                 f"edited or damaged; restore it, or start over with --overwrite")
  no_sac = lambda d: {k: ({m: v for m, v in d[k].items() if m != "sac"} if k == "meta" else d.get(k))
                      for k in info}  # meta["sac"] repeats the config
  diffs = ckpt.differences(no_sac(saved), no_sac(info))
  changed = [d for d in diffs if d.split(":")[0].endswith(".sha256")]
  if changed:
    raise ckpt.CheckpointError(
        f"cannot resume {source}: a checkpoint it depends on changed since it started "
        f"({changed[0].split(':')[0].removeprefix('meta.').removesuffix('.sha256')} content hash differs; "
        f"was it retrained?); "
        f"restore that checkpoint, or start a new run with --overwrite (overwrite=True)")
  if diffs:
    raise ckpt.CheckpointError(
        f"cannot resume from {source}: the saved run differs from the requested one in "
        f"{'; '.join(diffs[:6])}{' ...' if len(diffs) > 6 else ''}. Resume with the saved settings "
        f"(see {ckpt.state_dir(source) / 'state.json'}) or start a new run in another out= directory")


def _resume(source: Path, trainer, info: dict):
  """The saved TrainState (device arrays), history and best record of ``source``."""
  template = jax.eval_shape(sac_train.vmapped(trainer).init,
                            sac_train.seed_keys(info["seeds"]))
  # a state saved before best-of-evaluation selection has no best record: it restarts empty
  best_template = sac_train.empty_best({"policy": template.agent.policy_params, "q": template.agent.q_params})
  best_template = jax.tree.map(lambda x: jax.ShapeDtypeStruct(np.shape(x), x.dtype), best_template)
  saved = ckpt.load_state(source, template, best_template)
  return jax.device_put(saved.tree), saved.history, saved.best


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
    history, written atomically); default about every 10% of training; always saved at the end.
  overwrite: replace an existing run in ``out`` as a whole (without it, an existing run is refused;
    a directory that is not an hdt run is always refused, see :mod:`hdt.transfer.rundir`)."""


def train_low(agent: str, config: SACConfig | None = None, seeds=1, out=None, backend="auto",
              quiet=False, imitate=None, disc=None, resume=False, save_every=None, overwrite=False,
              **env_overrides) -> RunResult:
  """Goal-conditioned LL of ``agent`` on its ``reach`` task (SPEC 3). With ``imitate=<LL run of A>``
  the LL is aligned to A's behaviour by a discriminator (Algorithm 1, ``hdt.transfer.align``)."""
  if imitate is not None:
    from hdt.transfer.align import align_low  # align builds on this module
    kw = {} if disc is None else {"disc": disc}
    return align_low(agent, imitate, config, seeds=seeds, out=out, backend=backend, quiet=quiet,
                     resume=resume, save_every=save_every, overwrite=overwrite, **kw, **env_overrides)
  check_env_overrides(env_overrides, agent, "reach")
  env = make(agent, "reach", backend=backend, **env_overrides)
  config = config or configs.low_config(agent)
  meta = env_meta(env, "low", config, env_overrides=env_overrides)
  return _run(env, config, seeds, out, meta, quiet, f"low {agent}", resume, save_every, overwrite=overwrite)


def load_low(low: str | Path, seed_index: int = 0, which: str = "final"):
  """(params, meta, policy_fn) of a saved LL, checked to be a low level; ``which``: its "final"
  parameters or its "best" evaluation's (see :func:`ckpt.load`, ``meta["params"]`` says which)."""
  params, meta = ckpt.load(low, seed_index, which)
  if meta.get("level") != "low":
    raise ckpt.CheckpointError(f"{low} holds a {meta.get('level')!r}-level policy where a low level "
                               f"was expected (train one with `hdt train low --agent ...`)")
  ckpt.require(meta, {"level": str, "agent": str, "obs_size": int, "action_size": int, "hidden_sizes": list,
                      "k": int, "delta_max": (int, float)}, Path(low) / f"seed_{seed_index}" / "meta.json")
  if meta["k"] <= 0 or not np.isfinite(meta["delta_max"]) or meta["delta_max"] <= 0:
    raise ckpt.CheckpointError(f"the LL in {low} was trained with k={meta['k']}, delta_max={meta['delta_max']}; "
                               f"an HL needs both positive: retrain the LL without such --set values")
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


# The authors compose with the LL's best model (HighLevelEnv: load_from_name(policy, best=True)).
LOW_PARAMS = "best"


def low_record(low: str | Path, low_seed: int, low_meta: dict) -> dict:
  """What an HL's metadata records of the frozen LL it was trained over."""
  return dict(path=str(low), seed_index=low_seed, params=low_meta["params"],
              params_env_steps=low_meta["params_env_steps"], sha256=ckpt.content_hash(low, low_seed))


def high_env_with_low(task: str, low: str | Path, low_seed: int = 0, backend="auto",
                      low_params: str = LOW_PARAMS, **kw) -> tuple[HighLevelEnv, dict]:
  """(HL env of ``task`` over the frozen LL saved in ``low``, :func:`low_record` of that LL)."""
  params, meta, _ = load_low(low, low_seed, ckpt.check_which(low_params, "low_params"))
  return build_high_env(meta, params["policy"], task, backend, **kw), low_record(low, low_seed, meta)


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
  ``low_params``: the LL's "best" evaluation's parameters (default, as the authors) or "final")."""
  check_env_overrides(task_overrides, task=task)
  env, low_rec = high_env_with_low(task, low, low_seed, backend, low_params, k=k, **task_overrides)
  config = config or configs.high_config(task)
  meta = env_meta(env, "high", config, k=env.k, hl_horizon=env.horizon, delta_max=env.delta_max,
                  low=low_rec, task_overrides=task_overrides, hl_obs=_hl_obs_meta(env))
  return _run(env, config, seeds, out, meta, quiet, f"high {task}", resume, save_every, overwrite=overwrite,
              save_extra=sac_extras)


def sac_extras(ts) -> dict:
  """The rest of an HL's SAC beside "policy" and "q" (target critics, log temperature), saved so that
  finetuning can start from A's whole SAC (``hdt.transfer.finetune``)."""
  return {"target_q": ts.agent.target_q_params, "log_alpha": ts.agent.log_alpha}


def train_full(agent: str, task: str, config: SACConfig | None = None, seeds=1, out=None,
               backend="auto", quiet=False, resume=False, save_every=None, overwrite=False,
               **env_overrides) -> RunResult:
  """The flat 'Full' baseline: SAC on the task with the agent's own torques."""
  check_env_overrides(env_overrides, agent, task)
  env = make(agent, task, backend=backend, **env_overrides)
  config = config or configs.full_config(agent, task)
  meta = env_meta(env, "full", config, env_overrides=env_overrides)
  return _run(env, config, seeds, out, meta, quiet, f"full {agent}/{task}", resume, save_every,
              overwrite=overwrite)


for _f in (train_low, train_high, train_full):
  _f.__doc__ = (_f.__doc__ or "") + RESUME_DOC  # (None under python -OO)
del _f
