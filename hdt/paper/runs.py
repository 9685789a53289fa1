"""The runs behind the paper's cells, as recipes: an LL (:class:`Low`, aligned with ``imitate``), an HL
over an LL (:class:`High`), A's HL finetuned on B's LL (:class:`Finetune`) and the flat baseline
(:class:`Full`). :class:`Runs` turns each recipe into a run, once: its zoo entry at the paper preset,
else the run of that name in the table's directory (a finished one is reused, an interrupted one
resumed, through :mod:`hdt.transfer.runner`), else trains it there, unless it costs more env steps
than the preset allows: then it is "not run", with the command that trains it.
"""

from __future__ import annotations

import dataclasses
import shlex
from pathlib import Path
from typing import Any, Union

from hdt.agents.sac import SACConfig
from hdt.envs.robot import agent_spec
from hdt.transfer import checkpoint as ckpt
from hdt.transfer import configs, finetune, names, runner
from hdt.transfer.align import align_stage
from hdt.transfer.card import PolicyCard
from hdt.transfer.finetune import FinetuneSpec, finetune_stage
from hdt.transfer.pipeline import full_stage, high_stage, low_stage

Options = tuple[tuple[str, Any], ...]  # task or env options, hashable: (("goal", "end"),)


@dataclasses.dataclass(frozen=True)
class Preset:
  """How a table runs at one ``--preset`` (the SAC configs and budgets are the configs table's).

  seeds: seeds of each run it trains. episodes: evaluation episodes per seed. ft: HL decisions of each
  finetuning method (None: the task's HL budget). evals: evaluations over a run with such an explicit
  budget (the points of its learning curve). max_env_steps: a missing run costing more env steps of
  its robot (an HL: its decisions times k) is not run (None: no limit). zoo: zoo entries stand in for
  the runs they name (at the paper preset: the entries are the paper's cells, some at a smaller budget).
  """

  seeds: int
  episodes: int
  ft: int | None
  evals: int
  max_env_steps: int | None
  zoo: bool

  def __post_init__(self):
    for name in ("seeds", "episodes", "evals"):
      if not isinstance(getattr(self, name), int) or getattr(self, name) <= 0:
        raise ValueError(f"{name}={getattr(self, name)!r}: give a positive integer")
    if self.max_env_steps is not None and (not isinstance(self.max_env_steps, int) or self.max_env_steps < 0):
      raise ValueError(f"max_env_steps={self.max_env_steps!r}: give a number of env steps >= 0, or None for no limit")


PRESETS = {
    "smoke": Preset(seeds=1, episodes=2, ft=96, evals=2, max_env_steps=None, zoo=False),
    "cpu": Preset(seeds=2, episodes=20, ft=1480, evals=5, max_env_steps=None, zoo=False),
    # 1M env steps: the point mass's runs and nothing legged (days on a CPU); --max-env-steps all trains all
    "paper": Preset(seeds=5, episodes=100, ft=None, evals=20, max_env_steps=1_000_000, zoo=True),
}


def _suffix(options: Options) -> str:
  return "".join(f"_{k}_{v}" for k, v in options)


def _sets(options) -> list[str]:
  return [a for k, v in dict(options).items() for a in ("--set", f"{k}={v}")]


def _flags(cfg: SACConfig, base: SACConfig) -> list[str]:
  """The SAC options that turn the CLI's config ``base`` into ``cfg``."""
  out = []
  for f in dataclasses.fields(SACConfig):
    v = getattr(cfg, f.name)
    if v != getattr(base, f.name):
      values = v if isinstance(v, tuple) else (v,)
      out += [f"--{f.name.replace('_', '-')}", *(str(x).lower() if isinstance(x, bool) else str(x) for x in values)]
  return out


def _config(level: str, preset: str, pr: Preset, steps: int | None, **kw) -> tuple[SACConfig, SACConfig]:
  """(the config of a run of ``steps``, split into ``pr.evals`` evaluations, or of the preset's
  budget; the config the CLI builds without budget options). The stages run on the "auto" backend,
  as the printed commands do (the paper preset's throughput follows it: configs.ACCELERATOR)."""
  base = configs.config(level, preset, backend="auto", **kw)
  if steps is None:
    return base, base
  chunk = configs.chunk_for(steps, base.num_envs, pr.evals)
  return configs.config(level, preset, backend="auto", **kw, total_env_steps=steps, steps_per_chunk=chunk), base


def _common(preset: str, seeds: int, out: Path) -> list[str]:
  return ["--preset", preset, "--seeds", str(seeds), "--out", str(out)]


class _Recipe:
  """What a recipe answers (defaults of a run that reads no other run and trains with k = 1): its run's
  ``name`` in the table's directory, ``label``, ``inputs`` ({role: recipe}), ``paper_budget()``,
  ``k()`` (env steps of its robot per budget unit), ``configs(preset, pr, paths)`` (its SACConfig and
  the CLI's without budget options), ``stage(cfg, paths, preset)`` and ``command(paths, preset)``."""

  @property
  def inputs(self) -> dict:
    return {}

  def paper_budget(self) -> int | None:
    return None

  def k(self) -> int:
    return 1


@dataclasses.dataclass(frozen=True)
class Low(_Recipe):
  """An agent's LL on ``reach`` (``terrain``: its scene), aligned to A's LL ``imitate`` if given (A's
  discriminator settings, :func:`configs.disc_config`). ``zoo``: the entry standing in for it."""

  agent: str
  terrain: str = "plane"
  imitate: "Low | None" = None
  zoo: str | None = None

  @property
  def name(self) -> str:
    return (f"{self.agent}_low" + (f"_{self.terrain}" if self.terrain != "plane" else "")
            + (f"_aligned_{self.imitate.agent}" if self.imitate else ""))

  @property
  def label(self) -> str:
    return f"{self.agent} LL" + (f" ({self.terrain})" if self.terrain != "plane" else "") + (
        f" aligned to the {self.imitate.agent} LL" if self.imitate else "")

  @property
  def inputs(self) -> dict:
    return {"imitate": self.imitate} if self.imitate else {}

  @property
  def options(self) -> dict:
    return {} if self.terrain == "plane" else {"terrain": self.terrain}

  def paper_budget(self) -> int | None:
    return agent_spec(self.agent).ll_budget

  def configs(self, preset, pr, paths):
    return _config("low", preset, pr, None, agent=self.agent)

  def stage(self, cfg, paths, preset):
    if self.imitate:  # AlignSpec's discriminator default is A's paper values, as `hdt align`'s
      return align_stage(self.agent, paths["imitate"], cfg, **self.options)
    return low_stage(self.agent, cfg, **self.options)

  def command(self, paths, preset) -> list[str]:
    if self.imitate:
      return ["hdt", "align", "--agent", self.agent, "--imitate", paths["imitate"], *_sets(self.options)]
    return ["hdt", "train", "low", "--agent", self.agent, *_sets(self.options)]


@dataclasses.dataclass(frozen=True)
class High(_Recipe):
  """An HL on ``task`` over the LL ``low`` (its seed 0's best parameters, as ``hdt train high``),
  trained with task ``options`` for ``steps`` HL decisions (None: the preset's budget)."""

  task: str
  low: Low
  options: Options = ()
  steps: int | None = None
  zoo: str | None = None

  @property
  def name(self) -> str:
    return f"{self.low.agent}_high_{self.task}{_suffix(self.options)}" + (f"_{self.steps}" if self.steps else "")

  @property
  def label(self) -> str:
    return f"{self.low.agent} HL on {self.task}{_suffix(self.options).replace('_', ' ')}"

  @property
  def inputs(self) -> dict:
    return {"low": self.low}

  def paper_budget(self) -> int | None:
    return configs.hl_budget(self.task)

  def k(self) -> int:
    return agent_spec(self.low.agent).k

  def configs(self, preset, pr, paths):
    return _config("high", preset, pr, self.steps, task=self.task)

  def stage(self, cfg, paths, preset):
    return high_stage(self.task, paths["low"], cfg, **(configs.task_options(preset, self.task) | dict(self.options)))

  def command(self, paths, preset) -> list[str]:
    return ["hdt", "train", "high", "--task", self.task, "--low", paths["low"], *_sets(self.options)]


def start_fields(high, task: str, kl_weight: float | None) -> dict:
  """What finetuning takes from A's HL (as ``hdt finetune``, :func:`hdt.transfer.finetune.start_fields`);
  {} before A exists."""
  try:
    meta = ckpt.load_meta(high)
  except ckpt.CheckpointError:
    return {}
  return finetune.start_fields(PolicyCard.from_json(meta, high), task, kl_weight)


@dataclasses.dataclass(frozen=True)
class Finetune(_Recipe):
  """A's HL ``high`` finetuned on B's LL ``low`` on ``task`` (with ``options``) for the preset's ``ft``
  HL decisions: KL-tied to A at the task's weight (``kl``), or plain (weight 0)."""

  high: High
  low: Low
  task: str
  kl: bool = True
  options: Options = ()
  zoo: str | None = None

  @property
  def name(self) -> str:
    kl = "_kl" if self.kl else ""
    return f"{self.low.agent}_finetune{kl}_{self.task}{_suffix(self.options)}_from_{self.high.low.agent}"

  @property
  def label(self) -> str:
    return f"{self.high.low.agent} HL finetuned{' with KL' if self.kl else ''} on the {self.low.agent} LL"

  @property
  def inputs(self) -> dict:
    return {"high": self.high, "low": self.low}

  def k(self) -> int:
    return agent_spec(self.low.agent).k

  def configs(self, preset, pr, paths):
    return _config("finetune", preset, pr, pr.ft, task=self.task,
                   **start_fields(paths["high"], self.task, self.spec.kl_weight))

  @property
  def spec(self) -> FinetuneSpec:
    return FinetuneSpec(kl_weight=None if self.kl else 0.0)  # None: the task's (the paper's), as the CLI

  def stage(self, cfg, paths, preset):
    return finetune_stage(paths["high"], paths["low"], self.task, cfg, self.spec,
                          **(configs.task_options(preset, self.task) | dict(self.options)))

  def command(self, paths, preset) -> list[str]:
    return ["hdt", "finetune", "--high", paths["high"], "--low", paths["low"], "--task", self.task,
            *([] if self.kl else ["--kl-weight", "0"]), *_sets(self.options)]


@dataclasses.dataclass(frozen=True)
class Full(_Recipe):
  """Flat SAC on ``task`` with the agent's own torques for ``steps`` env steps (None: the preset's)."""

  agent: str
  task: str
  options: Options = ()
  steps: int | None = None
  zoo: str | None = None

  @property
  def name(self) -> str:
    return f"{self.agent}_full_{self.task}{_suffix(self.options)}" + (f"_{self.steps}" if self.steps else "")

  @property
  def label(self) -> str:
    return f"Full {self.agent} on {self.task}{_suffix(self.options).replace('_', ' ')}"

  def configs(self, preset, pr, paths):
    return _config("full", preset, pr, self.steps, agent=self.agent, task=self.task)

  def stage(self, cfg, paths, preset):
    return full_stage(self.agent, self.task, cfg, **dict(self.options))

  def command(self, paths, preset) -> list[str]:
    return ["hdt", "train", "full", "--agent", self.agent, "--task", self.task, *_sets(self.options)]


Recipe = Union[Low, High, Finetune, Full]
# The zoo's legged LLs, behind every table's and figure's legged cells at the paper preset: hdt's fast
# settings (LayerNorm critics, RESULTS.md), 1.2M of the paper's 2.5M env steps (the Ant2's 600k).
LEGGED_LOW = {"ant": "ant/low_fast_1200k", "ant3": "ant3/low_fast_1200k", "quadruped": "quadruped/low_fast_1200k",
              "ant2": "ant2/low_fast_600k"}

USABLE = ("zoo", "reused", "resumed", "trained", "reuse", "resume", "train")  # executed, or planned to be


@dataclasses.dataclass(frozen=True)
class Source:
  """Where a recipe's run comes from. status: planned "zoo" / "reuse" / "resume" / "train", then
  "zoo" / "reused" / "resumed" / "trained"; or "not run" (too expensive, or an input is missing) or
  "failed" (``reason`` says why). ``path``: the run (or ``zoo:NAME``), or where it would be trained."""

  recipe: Recipe
  status: str
  path: str
  command: str = ""
  env_steps: int = 0  # what training it costs, in env steps of its robot
  reason: str = ""

  @property
  def usable(self) -> bool:
    return self.status in USABLE


def _one_line(e: BaseException) -> str:
  return " ".join(str(e).split()) or type(e).__name__


class Runs:
  """Resolves recipes into runs under ``root`` at ``preset`` (:class:`Preset` ``pr``), each recipe
  once: :meth:`plan` decides without training, :meth:`get` trains what the plan says."""

  def __init__(self, root: Path, preset: str, pr: Preset, quiet: bool = False):
    self.root, self.preset, self.pr, self.quiet = Path(root), preset, pr, quiet
    self._plans: dict = {}
    self._done: dict = {}
    self._zoo = set(names.entry_names()) if pr.zoo else set()

  def plan(self, r: Recipe) -> Source:
    if r not in self._plans:
      self._plans[r] = self._plan(r)
    return self._plans[r]

  def _plan(self, r: Recipe) -> Source:
    if r.zoo and r.zoo in self._zoo:
      return Source(r, "zoo", names.PREFIX + r.zoo)
    inputs = {k: self.plan(v) for k, v in r.inputs.items()}
    paths = {k: s.path for k, s in inputs.items()}
    out = self.root / r.name
    try:
      cfg, base = r.configs(self.preset, self.pr, paths)
      done = ckpt.load_state_info(out).get("env_steps", 0) if ckpt.has_state(out) else 0
    except ValueError as e:  # a damaged state, a budget that does not split: this run's note
      return Source(r, "failed", str(out), reason=_one_line(e))
    command = shlex.join(r.command(paths, self.preset) + _common(self.preset, self.pr.seeds, out) + _flags(cfg, base))
    cost = max(0, cfg.total_env_steps - int(done)) * r.k()
    source = lambda status, reason="": Source(r, status, str(out), command, cost, reason)
    missing = [s.recipe.name for s in inputs.values() if not s.usable]
    if missing:
      return source("not run", f"needs {', '.join(missing)}")
    if (out / "meta.json").is_file() and done >= cfg.total_env_steps:
      return source("reuse")
    cap = self.pr.max_env_steps
    if cap is not None and cost > cap:
      return source("not run", f"{cost:,} env steps > --max-env-steps {cap:,}")
    return source("resume" if done else "train")

  def sources(self) -> dict:
    """Every recipe planned so far (inputs before what reads them) with its run: as got, else as planned."""
    return {r: self._done.get(r, s) for r, s in self._plans.items()}

  def get(self, r: Recipe) -> Source:
    """The run of ``r``: as planned, with what the plan trains trained (or reused, or resumed)."""
    if r not in self._done:
      self._done[r] = self._get(r)
    return self._done[r]

  def _get(self, r: Recipe) -> Source:
    plan = self.plan(r)
    if plan.status in ("zoo", "not run"):
      return plan
    inputs = {k: self.get(v) for k, v in r.inputs.items()}
    failed = [s.recipe.name for s in inputs.values() if not s.usable]
    if failed:
      return dataclasses.replace(plan, status="not run", reason=f"needs {', '.join(failed)}")
    out = Path(plan.path)
    options = runner.RunOptions(seeds=self.pr.seeds, out=out, quiet=self.quiet)
    try:
      cfg, _ = r.configs(self.preset, self.pr, {k: s.path for k, s in inputs.items()})
      stage = r.stage(cfg, {k: s.path for k, s in inputs.items()}, self.preset)
      try:
        if runner.finished_run(stage, options) is not None:
          return dataclasses.replace(plan, status="reused")
      except ckpt.CheckpointError as e:
        raise ckpt.CheckpointError(f"{out} holds a run of other settings; delete it to retrain it, or pass "
                                   f"another --out ({_one_line(e)})") from None
      resume = ckpt.has_state(out)
      runner.run_stage(stage, dataclasses.replace(options, resume=resume))
      return dataclasses.replace(plan, status="resumed" if resume else "trained")
    except (ValueError, ArithmeticError) as e:  # one run's failure (a diverged run too) is its cells' note
      return dataclasses.replace(plan, status="failed", reason=_one_line(e))


def describe(source: Source) -> dict:
  """Budget and seeds of a usable run, from its card: ``budget`` (e.g. "250k env steps of 2.5M")."""
  if source.status not in ("zoo", "reuse", "reused", "resumed", "trained"):
    return {}
  meta = ckpt.load_meta(source.path)
  total = meta.get("sac", {}).get("total_env_steps")
  unit = "HL decisions" if meta.get("level") == "high" else "env steps"
  paper = source.recipe.paper_budget()
  return dict(budget=f"{_k(total)} {unit}" + (f" of {_k(paper)}" if paper and paper != total else ""),
              seeds=len(names.list_seeds(source.path)), env_steps=total)


def _k(n) -> str:
  if not isinstance(n, int):
    return "?"
  return f"{n / 1e6:g}M" if n >= 1_000_000 else f"{n / 1e3:g}k" if n >= 1000 else str(n)
