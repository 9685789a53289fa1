"""The one runner of every training stage: claims the run directory, trains a vmapped seed sweep
with resumable atomic saves and progress, and writes config.json, meta.json (the run's
:class:`hdt.transfer.card.PolicyCard`), metrics.csv, TensorBoard events and seed_<i>/ checkpoints."""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import functools
import json
import os
import sys
from pathlib import Path
from typing import Any, Callable, Sequence

import jax
import numpy as np

from hdt import atomic, interrupt
from hdt.progress import run_progress
from hdt.agents import sharding
from hdt.agents import train as sac_train
from hdt.agents.plugins import Plugin
from hdt.agents.sac import ADDED_FIELDS as SAC_ADDED_FIELDS, SWEEPABLE, SACConfig
from hdt.transfer import checkpoint as ckpt
from hdt.transfer import names, rundir
from hdt.transfer.memory import check_train_memory
from hdt.transfer.card import FORMAT_KEY, PolicyCard


@dataclasses.dataclass
class RunResult:
  run_dir: Path | None
  params: Any  # {"policy", "q"} (+ "obs_norm", its observation statistics) with a leading seed axis
  history: dict[str, np.ndarray]  # leading seed axis
  card: PolicyCard  # the run's card (its meta.json)
  best: dict | None = None  # best periodic evaluation per seed (hdt.agents.train.update_best)


@dataclasses.dataclass(frozen=True)
class Stage:
  """What a training stage trains, as built by ``hdt.transfer.pipeline.low_stage`` and its kin; how
  it runs (seeds, output, ...) is a :class:`RunOptions`, the same for every stage."""

  env: Any
  config: SACConfig
  card: PolicyCard  # the card of the policy it trains (meta.json), with its provenance
  label: str  # names the stage in progress lines
  plugins: tuple[Plugin, ...] = ()  # folded over by make_train (hdt.agents.plugins)
  # save_extra(final TrainState) -> {name: pytree with a seed axis}, saved next to "policy" and "q"
  # in every seed's checkpoint (e.g. an aligned LL's discriminator, an HL's target critics)
  save_extra: Callable[[Any], dict] | None = None
  # point_card(card, {plug-in hyper name: value}) -> the card of a grid point that sets the plug-ins'
  # hyper (hdt.agents.plugins); default: the card with each value in its extra under its name (kl_weight)
  point_card: Callable[[PolicyCard, dict], PolicyCard] | None = None
  # {meta key: {field: value}}: fields of a meta.json section added after runs were saved, with the
  # value in effect before (e.g. hdt.agents.discriminator.ADDED_FIELDS): a run saved without them
  # resumes under those values, and a request for others is named as a difference
  legacy_meta: dict[str, dict] = dataclasses.field(default_factory=dict)
  # meta.json fields derived from the budget that nothing trained reads (a plain finetuning's
  # anneal_env_steps): a run resumed with another budget records the requested values
  budget_meta: tuple[str, ...] = ()

  @property
  def extendable(self) -> bool:
    """Whether a resume may change the budget: no plug-in follows a schedule scaled by it."""
    return not any(p.scales_with_budget for p in self.plugins)


@dataclasses.dataclass(frozen=True)
class Weight:
  """A plug-in weight that a stage lets a grid vary, vmapped like the SAC fields of SWEEPABLE."""

  name: str  # the plug-in's hyper name: also the --grid name, the card field and the metric column
  check: Callable[[float, dict], None]  # check(value, stage keywords) refuses (one line) what the stage would
  # stage keywords for a group of points trained as one program, given their values (None: as given)
  prepare: Callable[[dict, list], dict] | None = None


@dataclasses.dataclass(frozen=True)
class Level:
  """A kind of stage as a sweep and the CLI see it: how it is built, what it needs, what a grid may vary.
  Each stage module declares its own (``pipeline.LOW``, ``finetune.FINETUNE``, ``align.ALIGN``, ...)."""

  name: str
  stage: Callable[..., Stage]  # low_stage, high_stage, ...: (config=, backend=, **keywords) -> Stage
  needs: tuple[str, ...]  # its required keywords, among agent, task, low, high, imitate
  weights: tuple[Weight, ...] = ()
  sac_level: str | None = None  # whose SAC defaults it trains with (default: its name)

  @property
  def weight_names(self) -> tuple[str, ...]:
    return tuple(w.name for w in self.weights)


@dataclasses.dataclass(frozen=True)
class RunOptions:
  """How a stage runs, whatever it trains.

  seeds: n (seeds 0..n-1) or a list of seeds, trained together as one vmapped program.
  out: the run directory to write (None: nothing is written).
  quiet: no progress lines.
  resume: False (default) starts afresh; True continues the interrupted run in ``out`` from its
    ``out/state`` (same arguments and config; refused with a CheckpointError naming what differs);
    a run directory continues that run (writing to ``out``, default the same directory). The
    continued run equals an uninterrupted one exactly (same seeds, same device). A larger
    ``config.total_env_steps`` than the saved run's extends it, a finished run too (not for stages
    whose plug-ins follow schedules scaled by the budget: :attr:`Stage.extendable`).
  save_every: env steps between saves of the resumable state ``out/state`` (whole TrainState and
    history, written atomically, with ``metrics.csv`` so far); default about every 10% of training;
    always saved at the end.
  overwrite: replace an existing run in ``out`` as a whole (without it, an existing run is refused;
    a directory that is not an hdt run is always refused, see :mod:`hdt.transfer.rundir`).
  progress: progress(total, quiet, label) -> fn(env_steps, metrics), called after every chunk;
    default :func:`hdt.progress.run_progress` (a live bar on a terminal, a line per chunk in a log).
  """

  seeds: int | Sequence[int] = 1
  out: str | Path | None = None
  quiet: bool = False
  resume: bool | str | Path = False
  save_every: int | None = None
  overwrite: bool = False
  progress: Callable[[int, bool, str], Callable[[int, dict], None]] | None = None


def run_stage(stage: Stage, options: RunOptions = RunOptions()) -> RunResult:
  """Trains ``stage`` as ``options`` say, saving the resumable state to ``out/state`` every
  ``save_every`` env steps and at the end, then writes the run directory. Every argument is checked
  before anything is written, and ``out`` is claimed (hdt.transfer.rundir: owned by hdt, locked,
  replaced whole with ``overwrite``) before anything is compiled."""
  return run_points(stage, [({}, options.out)], options)[0]


def finished_run(stage: Stage, options: RunOptions = RunOptions()) -> RunResult | None:
  """The run in ``options.out`` as :func:`run_stage` returned it, when it is a finished run of
  exactly ``stage`` and ``options.seeds`` (nothing is trained or written); None when ``out`` holds
  no finished run: nothing, or an interrupted run or a smaller budget (continue it with
  ``resume=True``). A run of other settings is refused with a CheckpointError naming the difference,
  as resuming it would be."""
  out = options.out
  if out is None or not ckpt.has_state(out):
    return None
  seeds = sac_train.seed_list(options.seeds)
  info = dict(config=dataclasses.asdict(stage.config), meta=stage.card.to_json(), seeds=seeds)
  _check_resumable(Path(out), info, **_resume_rules(stage))
  # meta.json is written last (_write_run): without it the run stopped before its outputs were complete
  if ckpt.load_state_info(out).get("env_steps") != stage.config.total_env_steps or not (Path(out) / "meta.json").is_file():
    return None
  _, history, best = _resume(Path(out), sac_train.make_train(stage.env, stage.config, plugins=stage.plugins), info)
  params, _ = ckpt.load_all(out, "final")
  return RunResult(Path(out), params, history, stage.card.replace(source=str(out)), best)


def run_points(stage: Stage, points: list, options: RunOptions = RunOptions()) -> list[RunResult]:
  """:func:`run_stage` for grid points ``[(hyper, out)]`` (hyper: values of SWEEPABLE fields replacing
  ``stage.config``'s, and of the stage's plug-ins' hyper, e.g. ``kl_weight``, recorded in the point's
  card by ``stage.point_card``; ``options.out`` is not used) trained together as one vmapped program
  (``hdt.agents.train.run(hyper=...)``); each point writes its own run directory as if trained
  alone. Only a single point can resume."""
  env, config, card = stage.env, stage.config, stage.card
  resume, overwrite = options.resume, options.overwrite
  grid = {k: [h[k] for h, _ in points] for k in points[0][0]}
  configs = [dataclasses.replace(config, **{k: v for k, v in h.items() if k in SWEEPABLE}) for h, _ in points]
  plugin_values = [{k: float(v) for k, v in h.items() if k not in SWEEPABLE} for h, _ in points]
  point_card = stage.point_card or (lambda card, values: card.replace(extra=dict(card.extra, **values)))
  cards = [point_card(card, v) if v else card for v in plugin_values]
  cards = [c.replace(extra=dict(c.extra, sac=dataclasses.asdict(cfg))) if grid else c
           for c, cfg in zip(cards, configs)]
  meta = card.to_json()
  check_train_memory(env, config, options.seeds, len(points))
  seeds = sac_train.seed_list(options.seeds)
  if resume is not False and len(points) > 1:
    raise ValueError("resume continues one run: resume the grid points one at a time")
  reads = card.inputs()
  outputs = [_outputs(out, resume, overwrite, reads) for _, out in points]
  written = [os.path.realpath(d) for d, _ in outputs if d is not None]
  if len(set(written)) < len(written):
    twice = next(d for d in written if written.count(d) > 1)
    raise ValueError(f"two grid points would write the same directory {twice} (are two of their values "
                     f"equal?); give each point its own out")
  source = outputs[0][1]
  save_steps = _save_steps(config, options.save_every)
  # Compiled programs are saved and reloaded (hdt.cache.compiled_all) when the key below names all they
  # depend on: not with plug-ins (functions no key can name).
  backend = sac_train.physics_backend(env)
  cache_key = None if stage.plugins or not backend else json.dumps(
      dict(env=type(env).__name__, backend=backend, meta=meta, config=dataclasses.asdict(config)),
      sort_keys=True, default=str)
  trainer = sac_train.make_train(env, config, plugins=stage.plugins)
  infos = [dict(config=dataclasses.asdict(cfg), meta=c.to_json(), seeds=seeds) for cfg, c in zip(configs, cards)]
  if source is not None:
    _check_resumable(source, infos[0], **_resume_rules(stage))
  S = len(seeds)
  part = (lambda tree, p: tree) if len(points) == 1 else (
      lambda tree, p: jax.tree.map(lambda x: x[p * S:(p + 1) * S], tree))
  with contextlib.ExitStack() as claims:
    for run_dir, _ in outputs:
      if run_dir is not None:
        claims.enter_context(rundir.claim(run_dir, resume=source is not None and _same(source, run_dir),
                                          overwrite=overwrite, reads=reads))
    run_dir = outputs[0][0]
    ts = history = best = None
    if run_dir is not None and source is not None and _same(source, run_dir):
      sharding.on_writer(lambda: ckpt.settle_state(run_dir), f"settling {run_dir}")  # before any reads it
    if source is not None:
      ts, history, best = _resume(source, trainer, infos[0])

    def on_chunk(step, ts, hist, best):
      # Ctrl-C or SIGTERM during the chunk: it is saved, then the run stops (one process: a save is collective)
      stop = interrupt.pressed() and not sharding.several_processes()
      due = step // save_steps > (step - config.env_steps_per_chunk) // save_steps or step == config.total_env_steps
      if any(d is not None for d, _ in outputs) and (due or stop):
        hist = {k: np.stack(v, axis=1) for k, v in hist.items()}
        ts = sharding.gathered(ts)  # the seeds of every process, for process 0 to save

        def save():
          for p, (run_dir, _) in enumerate(outputs):
            if run_dir is not None:
              ckpt.save_state(run_dir, part(ts, p), part(hist, p),
                              dict(infos[p], env_steps=step, extendable=stage.extendable),
                              None if best is None else part(best, p))
              write_metrics_csv(run_dir / "metrics.csv", part(hist, p), seeds)  # curves while it runs
        with interrupt.deferred():
          sharding.on_writer(save, f"saving the training state at env step {step}")
      interrupt.raise_if_interrupted()

    interrupt.raise_if_interrupted()
    start = 0 if ts is None else int(np.max(jax.device_get(ts.env_steps)))
    quiet = options.quiet or not sharding.writes()  # several processes: process 0 reports
    if not quiet:
      _device_hint(len(points) * S, stage.label)
    if sharding.several_processes() and not options.quiet:  # each process says what it trains
      print(f"{stage.label}: process {jax.process_index()} of {jax.process_count()} trains "
            f"{_runs_text(sharding.local_runs(len(points) * S), seeds, len(points))}", file=sys.stderr, flush=True)
    progress = (options.progress or functools.partial(run_progress, start=start))(
        config.total_env_steps, quiet, stage.label)
    try:
      with counted_mujoco_warnings(options.quiet) as warned, interrupt.graceful():
        res = sac_train.run(env, config, seeds, progress_fn=progress, trainer=trainer, initial_state=ts,
                            initial_history=history, initial_best=best, eval_at_start=history is None,
                            on_chunk=on_chunk, cache_key=cache_key, **({"hyper": grid} if grid else {}))
    except sac_train.TrainingDiverged as e:
      kept = [d for d, _ in outputs if d is not None and ckpt.has_state(d)]
      note = (f" The last good training state is kept in {ckpt.state_dir(kept[0])}." if len(kept) == 1 else
              " The last good training states are kept in each run directory's state/." if kept else "")
      note += f" MuJoCo reported {len(warned)} simulation warning(s) before." if warned else ""
      raise sac_train.TrainingDiverged(str(e) + note, e.term, e.env_step, e.seeds) from None
    finally:
      getattr(progress, "close", lambda: None)()  # a live bar ends however training does
    params = sharding.gathered(dict(res.params, **(stage.save_extra(res.state) if stage.save_extra else {})))
    diverged = np.asarray(sharding.gathered(res.state.diverged_at)).reshape(-1)
    results = []
    for p, (run_dir, _) in enumerate(outputs):
      res_p = sac_train.RunResult(part(params, p), part(res.history, p), None,  # the state is not written
                                  None if res.best is None else part(res.best, p))
      if run_dir is not None:
        with interrupt.deferred():  # a Ctrl-C here would leave some seeds unwritten
          sharding.on_writer(lambda: _write_run(run_dir, configs[p], infos[p]["meta"], seeds, res_p.params, res_p,
                                                part(diverged, p)),
                             f"writing {run_dir}")
      source = None if run_dir is None else str(run_dir)
      results.append(RunResult(run_dir, res_p.params, res_p.history, cards[p].replace(source=source), res_p.best))
  return results


def _device_hint(runs: int, label: str) -> None:
  """One line when the runs cannot use every device (e.g. 3 seeds on a 2-core CPU's 2 devices)."""
  all_devices = jax.devices()
  devices, used = len(all_devices), sharding.seed_devices(runs)
  processes = jax.process_count()
  if processes > 1 and used == 1:
    print(f"{label}: {runs} runs do not split evenly over the {processes} processes, so every process trains "
          f"all of them (the same); a multiple of {processes} runs splits them")
    return
  if runs > 1 and used < devices:
    lo = runs - runs % devices
    other = " or ".join(str(n) for n in (lo, lo + devices) if n > 0)
    cpu = (f" (or set JAX_NUM_CPU_DEVICES={runs}: faster for small-network LLs, slower for HLs; BENCHMARKS.md)"
           if all_devices[0].platform == "cpu" else "")
    print(f"{label}: {runs} runs split over {used} of the {devices} devices; {other} runs would use all of them{cpu}")


def _runs_text(runs: list[int], seeds: list, points: int) -> str:
  """``runs`` (indices point-major over grid points x seeds) as "seeds 0, 1" or "grid point 0 seeds 0, 1; ..."."""
  S = len(seeds)
  if points == 1:
    return "seeds " + ", ".join(str(seeds[r]) for r in runs)
  by_point: dict[int, list] = {}
  for r in runs:
    by_point.setdefault(r // S, []).append(seeds[r % S])
  return "; ".join(f"grid point {p} seeds {', '.join(map(str, s))}" for p, s in by_point.items())


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


def _write_run(run_dir: Path, config: SACConfig, meta: dict, seeds: list, params, res,
               diverged: np.ndarray) -> None:
  """The run's outputs; meta.json last, so a run directory with meta.json is complete. ``diverged``:
  each seed's TrainState.diverged_at; a seed that diverged records it as ``diverged_at_env_step``
  (its parameters are its last finite ones)."""
  rundir.check_held(run_dir)
  unit = "HL decisions" if meta.get("level") == "high" else "env steps"  # what total_env_steps counts
  ckpt.write_json_atomic(run_dir / "config.json", dict(dataclasses.asdict(config), budget_unit=unit))
  for i, s in enumerate(seeds):
    at = int(diverged[i])
    ckpt.save(run_dir, i, jax.tree.map(lambda x: x[i], params),
              dict(meta, seed=s, **({"diverged_at_env_step": at} if at >= 0 else {})), best=_seed_best(res.best, i, config))
  write_metrics_csv(run_dir / "metrics.csv", res.history, seeds)
  write_tensorboard(run_dir / "tb", res.history, seeds)
  hashes = [ckpt.content_hash(run_dir, i) for i in range(len(seeds))]  # checked on every load
  ckpt.write_json_atomic(run_dir / "meta.json", dict(meta, seeds=seeds, **{ckpt.SEED_HASHES: hashes}))


def _same(a: Path, b: Path) -> bool:
  return Path(os.path.abspath(a)) == Path(os.path.abspath(b))


def _seed_best(best: dict | None, i: int, config: SACConfig) -> tuple[dict, dict] | None:
  """(params, info) of seed ``i``'s best evaluation for :func:`ckpt.save`, None if it has none."""
  if best is None or best["env_steps"][i] < 0:
    return None
  criterion = sac_train.best_criterion(config)
  info = {"env_steps": int(best["env_steps"][i]), criterion.replace("/", "_"): float(best["score"][i]),
          "criterion": f"highest mean {criterion} over the periodic evaluations"}
  return {k: jax.tree.map(lambda x: x[i], v) for k, v in best.items() if k not in ("score", "env_steps")}, info



def _outputs(out, resume, overwrite=False, reads=()) -> tuple[Path | None, Path | None]:
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
    reads = dict(reads, **({"resumed": str(source)} if source is not None and not same else {}))
    out = rundir.check_claimable(out, resume=same, overwrite=overwrite, reads=reads)
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


def _resume_rules(stage: Stage) -> dict:
  return dict(extendable=stage.extendable, legacy_meta=stage.legacy_meta, budget_meta=stage.budget_meta)


def _check_resumable(source: Path, info: dict, extendable: bool = False, legacy_meta: dict | None = None,
                     budget_meta: Sequence[str] = ()) -> None:
  """Refuses (reading only) to resume ``source`` if its run was started with another configuration,
  run metadata or seeds than ``info`` describes, or a checkpoint it depends on changed since.

  ``extendable`` (:attr:`Stage.extendable`): a larger ``total_env_steps`` continues the run past its end
  (a finished run too), exactly as an uninterrupted run of the larger budget; not with plug-ins whose
  schedules (discriminator weight and lr, KL weight) are fractions of the budget. ``legacy_meta``:
  :attr:`Stage.legacy_meta`; ``budget_meta``: :attr:`Stage.budget_meta`."""
  saved = ckpt.load_state_info(source)
  for key, kind in (("config", dict), ("meta", dict), ("seeds", list)):
    if not isinstance(saved.get(key), kind):
      raise ckpt.CheckpointError(f"the training state in {source} has {key}={saved.get(key)!r}: state.json was "
                                 f"edited or damaged; restore it, or start over with --overwrite")
  budget = lambda d: (d.get("config") or {}).get("total_env_steps")
  if budget(saved) != budget(info):
    done = saved.get("env_steps") if isinstance(saved.get("env_steps"), int) else 0
    if not extendable:
      raise ckpt.CheckpointError(
          f"cannot resume {source} with total_env_steps={budget(info)} (saved {budget(saved)}): its plug-ins' "
          f"schedules (discriminator, KL) are fractions of the budget; resume with --total-env-steps "
          f"{budget(saved)}")
    if not isinstance(budget(info), int) or budget(info) < done:
      raise ckpt.CheckpointError(
          f"cannot resume {source} with total_env_steps={budget(info)}: it has already trained {done} env "
          f"steps; give --total-env-steps >= {done}")
    now = info.get("meta") or {}
    saved = dict(saved, config=dict(saved["config"], total_env_steps=budget(info)),
                 meta=dict(saved["meta"], **{k: now[k] for k in budget_meta if k in now}))
  saved = _same_low_as_slim_copy(_with_legacy_fields(saved, legacy_meta or {}, info.get("config") or {}), info)
  # meta["sac"] repeats the config; a state saved before the card format was recorded has format 1
  no_sac = lambda d: {k: ({m: v for m, v in d[k].items() if m not in ("sac", FORMAT_KEY)} if k == "meta"
                          else d.get(k)) for k in info}
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


def _with_legacy_fields(saved: dict, legacy_meta: dict[str, dict], requested_config: dict) -> dict:
  """``saved`` with the meta fields added since it was written (``legacy_meta``, see
  :attr:`Stage.legacy_meta`) set to the values it ran with, and so the SACConfig fields added since
  (:data:`hdt.agents.sac.ADDED_FIELDS`)."""
  meta = dict(saved.get("meta") or {})
  for key, fields in legacy_meta.items():
    if isinstance(meta.get(key), dict):
      meta[key] = {**fields, **meta[key]}
  config = saved.get("config")
  if isinstance(config, dict):
    config = {**{k: v for k, v in SAC_ADDED_FIELDS.items() if k in requested_config}, **config}
  return dict(saved, meta=meta, config=config)


def _same_low_as_slim_copy(saved: dict, info: dict) -> dict:
  """``saved`` with the hashes of ``info`` where a checkpoint it recorded (the HL's ``low``, the aligned
  LL's imitated ``aligned_to``, a finetuned HL's A ``finetuned_from``, all of whose seeds it hashes) is
  now a re-slimmed zoo copy of the same parameters (:func:`hdt.transfer.names.hash_aliases`):
  slimming an entry is not retraining it."""
  meta = dict(saved.get("meta") or {})
  for key in ("low", "aligned_to", "finetuned_from"):
    old, now = meta.get(key), (info.get("meta") or {}).get(key)
    seed = None if key == "finetuned_from" else int((now or {}).get("seed_index", 0))
    if (isinstance(old, dict) and isinstance(now, dict) and old.get("sha256") != now.get("sha256")
        and old.get("path") == now.get("path") and isinstance(now.get("path"), str)
        and old.get("sha256") in names.hash_aliases(now["path"], seed)):
      meta[key] = dict(old, sha256=now["sha256"])
  return dict(saved, meta=meta)


def _resume(source: Path, trainer, info: dict):
  """The saved TrainState (device arrays), history and best record of ``source``."""
  seeds = info["seeds"]
  template = jax.eval_shape(sac_train.vmapped(trainer).init, sac_train.seed_keys(seeds),
                            sac_train.seed_indices(len(seeds)))
  # a state saved before best-of-evaluation selection has no best record: it restarts empty
  best_template = sac_train.empty_best(sac_train.saved_params(template.agent))
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
  with atomic.open_atomic(path, "w", newline="") as f:
    w = csv.DictWriter(f, fieldnames=keys)
    w.writeheader()
    w.writerows(rows)


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

