"""The hand-off card: what one trained policy promises to whoever loads it.

A :class:`PolicyCard` is frozen and typed: level, agent, task, family and goal space, the goal
dimension, k and delta_max, the observation sizes and the HL observation layout, the network and
normaliser spec, the env / task options it was trained with, and its provenance: the runs it was
trained from, each a typed record (:class:`LowRef` an HL's LL, :class:`AlignedTo` an aligned LL's A,
:class:`FinetunedFrom` a finetuned HL's A). ``meta.json`` (top level and per seed) is its JSON
serialisation (:meth:`PolicyCard.to_json`); what the card does not type (the SAC config, the seed and
checkpoint fields, a stage's own settings) is kept verbatim in ``extra`` so that a round trip writes the
same file.

Each hand-off between levels has its check, which words its errors: :meth:`PolicyCard.low_box` (an LL
for an HL), :meth:`PolicyCard.compose_box` (an HL over an LL), :meth:`PolicyCard.check_finetunes_to` (A's
HL as the start of B's) and :meth:`PolicyCard.check_imitated_by` (B's LL aligned to A's). The card builds
its env (:meth:`PolicyCard.make_env`, :meth:`PolicyCard.high_env`) and its deterministic policy function
(:meth:`PolicyCard.policy_fn`), which applies the observation statistics saved beside the policy's
parameters (``params["obs_norm"]``, if it was trained with them).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from types import MappingProxyType
from typing import Callable, Mapping

import numpy as np

from hdt.agents import networks as nets
from hdt.envs import make
from hdt.envs.robot import check_recorded, robot_record
from hdt.envs.spec import AgentSpec
from hdt.envs.tasks import TASKS
from hdt.transfer import checkpoint as ckpt
from hdt.transfer.hierarchy import HighLevelEnv

# Version of the card's JSON layout. Runs written before the field existed have this layout (1).
CARD_FORMAT = 1
FORMAT_KEY = "card_format"

GOAL_DIM = 2  # both families' goal spaces are planar (torso / end-effector xy)
GOAL_SPACE_NAMES = {"nav": "navigation (torso xy)", "manip": "manipulation (end-effector xy)"}

# What a policy's card must hold to be run (checked, so an edited file is one clear line).
REQUIRED = {"level": str, "agent": str, "task": str, "family": str, "obs_size": int, "action_size": int,
            "hidden_sizes": list, "delta_max": (int, float), "k": int}
# The keys the card types; everything else of meta.json goes to ``extra`` untouched.
_TYPED = ("level", "agent", "task", "family", "goal_space", "k", "delta_max", "obs_size", "action_size",
          "obs_lo_size", "obs_hi_size", "hidden_sizes", "hl_obs", "hl_horizon", "env_overrides",
          "task_overrides", "low", "aligned_to", "finetuned_from")
# Which parameters of an LL an HL runs over: the authors compose with the LL's best model
# (HighLevelEnv: load_from_name(policy, best=True)).
LOW_PARAMS = "best"


@dataclasses.dataclass(frozen=True)
class ObsLayout:
  """How the HL policy observes obs_hi (:class:`hdt.envs.tasks.Task` ``hl_relative`` / ``hl_absolute``)."""

  hl_relative: tuple[int, ...] = ()
  hl_absolute: bool = True

  def task_options(self) -> dict:
    return {"hl_relative": self.hl_relative, "hl_absolute": self.hl_absolute}

  def to_json(self) -> dict:
    return {"hl_relative": [int(i) for i in self.hl_relative], "hl_absolute": bool(self.hl_absolute)}

  @classmethod
  def from_json(cls, d: Mapping | None) -> "ObsLayout":
    d = d or {}  # runs that predate the field observed plain obs_hi
    return cls(tuple(int(i) for i in d.get("hl_relative", ())), bool(d.get("hl_absolute", True)))


class Record:
  """A provenance record of a card (a frozen dataclass whose first field is the ``path`` of the run it
  names): its JSON leaves out what it does not know (None), so that a record written before a field
  existed reads and writes back the same."""

  def __post_init__(self):
    if isinstance(self.path, os.PathLike):
      object.__setattr__(self, "path", os.fspath(self.path))

  def to_json(self) -> dict:
    return {f.name: list(v) if isinstance(v, tuple) else v
            for f in dataclasses.fields(self) if (v := getattr(self, f.name)) is not None}

  @classmethod
  def from_json(cls, d: Mapping) -> "Record":
    known = {f.name for f in dataclasses.fields(cls)}
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items() if k in known})


@dataclasses.dataclass(frozen=True)
class LowRef(Record):
  """The frozen LL an HL runs over: its run directory (or ``zoo:NAME``), the seed that drives every HL
  seed, and which of its parameters ("best", as the authors compose, or "final"). An HL's card records
  it as ``low`` with what was loaded: the parameters' env steps and the seed's content hash."""

  path: str
  seed_index: int = 0
  params: str | None = LOW_PARAMS  # None: a record written before it was kept
  params_env_steps: int | None = None
  sha256: str | None = None

  def __post_init__(self):
    super().__post_init__()
    if self.params is not None:
      ckpt.check_which(self.params, "params")

  @classmethod
  def of(cls, low) -> "LowRef":
    """``low`` as a LowRef: itself, or a run directory's seed 0 and best parameters."""
    if isinstance(low, LowRef):
      return low
    if not isinstance(low, (str, os.PathLike)):
      raise ValueError(f"low={low!r}: give the LL's run directory (or zoo:NAME), or a LowRef")
    return cls(os.fspath(low))

  @classmethod
  def from_json(cls, d: Mapping) -> "LowRef":
    return super().from_json({"params": None} | dict(d))


@dataclasses.dataclass(frozen=True)
class AlignedTo(Record):
  """The LL an aligned LL imitated (``hdt.transfer.align``): A's run, agent, seed and parameters, the
  fixed data set's size and key (``n_offline`` 0 when A ran alongside), the input scale and A's hash."""

  path: str
  agent: str | None = None
  seed_index: int = 0
  params: str | None = None
  params_env_steps: int | None = None
  n_offline: int | None = None
  offline_seed: int | None = None
  tau_scale: float | None = None
  sha256: str | None = None


@dataclasses.dataclass(frozen=True)
class FinetunedFrom(Record):
  """The HL a finetuned HL started from (``hdt.transfer.finetune``): A's run, agent, task and
  parameters, its hash and its number of seeds (the seed of index i started from A's seed i % seeds;
  runs before that rule list ``init_seed_indices``), and the KL reference (seed, parameters and their
  env steps; None without a KL term)."""

  path: str
  agent: str | None = None
  task: str | None = None
  params: str | None = None
  sha256: str | None = None
  seeds: int | None = None
  init_seed_indices: tuple[int, ...] | None = None
  reference_seed: int | None = None
  reference_params: str | None = None
  reference_params_env_steps: int | None = None


PROVENANCE = {"low": LowRef, "aligned_to": AlignedTo, "finetuned_from": FinetunedFrom}  # card field -> record


def low_policy_fn(hidden_sizes, obs_size: int, action_size: int, obs_norm=None) -> Callable:
  """``fn(params, obs)``: deterministic action of a saved SAC policy, tanh of the pre-tanh mean, with
  the observation statistics ``obs_norm`` it was trained with (None: raw observations), as brax's
  ``make_inference_fn``."""
  net = nets.make_sac_networks(obs_size, action_size, tuple(hidden_sizes))
  return lambda params, obs: nets.deterministic_action(net.policy_apply(params, obs, obs_norm)[0])


def _frozen(d: Mapping | None) -> Mapping:
  return MappingProxyType(dict(d or {}))


@dataclasses.dataclass(frozen=True)
class PolicyCard:
  """One trained policy's hand-off contract (see the module docstring)."""

  level: str  # "low", "high" or "full"
  agent: str  # registry name, or the path of a robot file
  task: str
  family: str  # "nav" or "manip"
  goal_space: str | None
  k: int  # LL steps per HL decision
  delta_max: float  # half-width of the sub-goal box (goal-space units)
  obs_size: int
  action_size: int
  hidden_sizes: tuple[int, ...]
  obs_lo_size: int | None = None
  obs_hi_size: int | None = None
  hl_obs: ObsLayout | None = None  # set for an HL
  hl_horizon: int | None = None
  env_overrides: Mapping | None = None
  task_overrides: Mapping | None = None
  low: LowRef | None = None  # an HL's LL
  aligned_to: AlignedTo | None = None  # an aligned LL's A
  finetuned_from: FinetunedFrom | None = None  # a finetuned HL's A
  extra: Mapping = dataclasses.field(default_factory=dict)  # verbatim rest of meta.json
  source: str | None = dataclasses.field(default=None, compare=False)  # where it was read, for messages

  def __post_init__(self):
    for name in ("env_overrides", "task_overrides"):
      if getattr(self, name) is not None:
        object.__setattr__(self, name, _frozen(getattr(self, name)))
    object.__setattr__(self, "extra", _frozen(self.extra))
    object.__setattr__(self, "hidden_sizes", tuple(int(h) for h in self.hidden_sizes))

  # --- what readers need ------------------------------------------------------------------------
  @property
  def goal_dim(self) -> int:
    return GOAL_DIM

  @property
  def sac(self) -> dict:
    return dict(self.extra.get("sac") or {})

  @property
  def normalize_observations(self) -> bool:
    return bool(self.sac.get("normalize_observations", False))

  @property
  def loaded(self) -> str:
    """Which parameters were loaded with this card (:func:`hdt.transfer.checkpoint.load`): "final",
    "best", or a per-seed mix."""
    return self.extra.get("params", "final")

  @property
  def loaded_env_steps(self) -> int | None:
    """After how many env steps the loaded parameters were saved."""
    return self.extra.get("params_env_steps")

  @property
  def obs_layout(self) -> ObsLayout:
    return self.hl_obs or ObsLayout()

  @property
  def morphology(self) -> dict:
    """The env options that change the robot (they carry over to any task the LL is used on)."""
    agent_fields = {f.name for f in dataclasses.fields(AgentSpec)}
    return {k: v for k, v in (self.env_overrides or {}).items() if k in agent_fields}

  # --- JSON -------------------------------------------------------------------------------------
  def to_json(self) -> dict:
    """``meta.json``: the typed fields, the verbatim ``extra`` and the card format."""
    out = dict(self.extra)
    for name in _TYPED:
      v = getattr(self, name)
      if v is None:  # absent from the file it came from
        continue
      if isinstance(v, (ObsLayout, Record)):
        v = v.to_json()
      elif name == "hidden_sizes":
        v = list(v)
      elif isinstance(v, Mapping):
        v = dict(v)
      out[name] = v
    return out | {FORMAT_KEY: CARD_FORMAT}

  @classmethod
  def from_json(cls, meta: Mapping, source: str | Path | None = None) -> "PolicyCard":
    """The card of ``meta`` (a meta.json's content); refuses another card format or missing fields
    with one line naming ``source``."""
    where = source if source is not None else "the run metadata"
    fmt = meta.get(FORMAT_KEY, CARD_FORMAT)  # runs before the field have format 1
    if fmt != CARD_FORMAT:
      fix = ("upgrade hdt to read it" if isinstance(fmt, int) and not isinstance(fmt, bool) and fmt > CARD_FORMAT
             else "re-train it, or restore the file from a backup")
      raise ckpt.CheckpointError(f"checkpoint metadata in {where} has card format {fmt!r} but this hdt reads "
                                 f"card format {CARD_FORMAT}: {fix}")
    ckpt.require(dict(meta), REQUIRED, where)
    check_fields(meta, where)
    extra = {k: v for k, v in meta.items() if k not in _TYPED and k != FORMAT_KEY}
    get = meta.get
    return cls(level=meta["level"], agent=meta["agent"], task=meta["task"], family=meta["family"],
               goal_space=get("goal_space"), k=meta["k"], delta_max=meta["delta_max"],
               obs_size=meta["obs_size"], action_size=meta["action_size"], hidden_sizes=meta["hidden_sizes"],
               obs_lo_size=get("obs_lo_size"), obs_hi_size=get("obs_hi_size"),
               hl_obs=None if get("hl_obs") is None else ObsLayout.from_json(get("hl_obs")),
               hl_horizon=get("hl_horizon"), env_overrides=get("env_overrides"),
               task_overrides=get("task_overrides"), extra=extra,
               **{k: record.from_json(meta[k]) for k, record in PROVENANCE.items() if meta.get(k) is not None},
               source=None if source is None else str(source))

  @classmethod
  def from_env(cls, env, level: str, config, **extra) -> "PolicyCard":
    """The card of a policy about to be trained on ``env`` (an agent-task env or an HL env) with the
    SAC ``config``; ``extra``: provenance records (low=LowRef(...), ...), options (env_overrides, ...)
    and a stage's settings (kept in ``extra``)."""
    inner = env.env if isinstance(env, HighLevelEnv) else env
    agent, task = inner.agent, inner.task
    meta = dict(level=level, agent=agent.name, task=task.name, family=agent.family,
                goal_space=f"{agent.family}:{task.point_sensor}", delta_max=agent.delta_max, k=agent.k,
                obs_size=int(env.observation_size), action_size=int(env.action_size),
                obs_lo_size=int(env.obs_lo_size), obs_hi_size=int(env.obs_hi_size),
                hidden_sizes=list(config.hidden_sizes), sac=dataclasses.asdict(config))
    if isinstance(env, HighLevelEnv):
      meta |= dict(k=env.k, hl_horizon=env.horizon, delta_max=env.delta_max,
                   hl_obs=ObsLayout(tuple(task.hl_relative), task.hl_absolute).to_json())
    # a robot file: its path is the agent, and its sha256
    records = {k: v.to_json() for k, v in extra.items() if isinstance(v, Record)}
    return cls.from_json(meta | robot_record(agent) | extra | records)

  def replace(self, **kw) -> "PolicyCard":
    return dataclasses.replace(self, **kw)

  # --- what it builds ---------------------------------------------------------------------------
  def policy_fn(self, obs_norm=None) -> Callable:
    """``fn(params, obs) -> action``: the deterministic action of this card's policy network;
    ``obs_norm``: the statistics saved beside its parameters (``params.get("obs_norm")``)."""
    return low_policy_fn(self.hidden_sizes, self.obs_size, self.action_size, obs_norm)

  def make_env(self, task: str | None = None, backend: str = "auto", **overrides):
    """The env of a flat policy (an LL on reach, or a Full policy) on ``task`` (default: its own),
    with the options it was trained with."""
    check_recorded(self.to_json())
    return make(self.agent, task or self.task, backend=backend, **dict(self.env_overrides or {}) | overrides)

  def high_env(self, low_params, task: str, backend="auto", k=None, hl_horizon=None, record=False,
               delta_max=None, low_obs_norm=None, **task_overrides) -> HighLevelEnv:
    """The HL env of ``task`` over this LL (``low_params``: its policy parameters, ``low_obs_norm``:
    the observation statistics saved beside them, if any). The inner env's
    own time limit is disabled: the HL env counts HL steps. Only the LL's morphology options carry
    over; its reach-task options (terrain=...) do not belong to the HL task."""
    if task not in TASKS:
      raise ValueError(f"unknown task {task!r}; valid tasks: {', '.join(TASKS)}")
    # hl_horizon may come as a task override too; it never reaches the inner env
    overridden = task_overrides.pop("hl_horizon", None)
    hl_horizon = next((h for h in (hl_horizon, overridden) if h is not None), TASKS[task]().hl_horizon)
    check_recorded(self.to_json())  # a robot file must still be there, unchanged
    need = TASKS[task]().ll_terrain
    got = (self.env_overrides or {}).get("terrain", "plane")
    if need and self.task == "reach" and got != need:
      raise ckpt.CheckpointError(
          f"the LL in {self.source} was trained on reach with terrain={got!r}, but {task}'s HL needs an LL "
          f"trained on its scene: train one with `hdt train low --agent {self.agent} --set terrain={need}`")
    inner = make(self.agent, task, backend=backend, hl_horizon=10**6, **self.morphology | task_overrides)
    if inner.obs_lo_size + self.goal_dim * inner.task.ll_points != self.obs_size:
      raise ckpt.CheckpointError(
          f"the LL observes {self.obs_size} numbers but {self.agent} on {task} gives "
          f"{inner.obs_lo_size} + {self.goal_dim * inner.task.ll_points}: was it trained with other options (e.g. rangefinders for steps)?")
    return HighLevelEnv(inner, self.policy_fn(low_obs_norm), low_params, k=self.k if k is None else k,
                        hl_horizon=hl_horizon, record=record,
                        delta_max=self.delta_max if delta_max is None else delta_max)

  # --- hand-off checks: each raises the one-line error of the first mismatch -------------------
  def low_box(self) -> float:
    """This card as the LL an HL runs over: a low level with positive k and sub-goal box; returns the box."""
    check_level(self.level, self.source, "low")
    if self.k <= 0 or not np.isfinite(self.delta_max) or self.delta_max <= 0:
      raise ckpt.CheckpointError(f"the LL in {self.source} was trained with k={self.k}, delta_max={self.delta_max}; "
                                 f"an HL needs both positive: retrain the LL without such --set values")
    return float(self.delta_max)

  def compose_box(self, low: "PolicyCard", box: str = "refuse") -> float:
    """This HL over the LL ``low``: same goal space; goal boxes that differ are refused, or with
    ``box`` "scale" the HL's [-1, 1] actions span the LL's box, "keep" the HL's box in metres. Returns
    the sub-goal box to use."""
    check_level(self.level, self.source, "high", "compose")
    if low.level != "low":
      raise ckpt.CheckpointError(f"{low.source} holds a {low.level!r}-level policy; compose needs an LL "
                                 f"(from `hdt train low`) as low=")
    if self.family != low.family:
      raise ValueError(
          f"goal spaces do not match: the HL in {self.source} emits {GOAL_SPACE_NAMES[self.family]} sub-goals, "
          f"the LL in {low.source} ({low.agent}) reaches {GOAL_SPACE_NAMES[low.family]} goals; pair an HL and "
          f"an LL of the same family")
    if np.isclose(self.delta_max, low.delta_max) or box == "keep":
      return self.delta_max
    if box == "scale":
      return float(low.delta_max)
    raise ValueError(f"goal boxes differ: HL sub-goals span +-{self.delta_max} but the LL was trained on "
                     f"+-{low.delta_max}; pass box='scale' to map the HL's box onto the LL's, or box='keep' to "
                     f"keep the HL's box in metres")

  def check_finetunes_to(self, b: "PolicyCard") -> None:
    """This HL (A's) as the start of the finetuning run whose card is ``b`` (B's HL, built from its
    env and config): same family, observation and action sizes, normaliser and architecture."""
    me = self.source
    check_level(self.level, me, "high", "finetune_high")
    if self.family != b.family:
      raise ValueError(f"goal spaces do not match: the HL in {me} was trained for the {self.family!r} family, "
                       f"the LL in {b.source} belongs to {b.family!r}; finetune an HL of the same family")
    if self.obs_size != b.obs_size or self.action_size != b.action_size:
      raise ckpt.CheckpointError(
          f"the HL in {me} maps {self.obs_size} observations to {self.action_size} actions but the HL env of "
          f"{b.task} over {b.source} has {b.obs_size} observations and {b.action_size} actions (was A's HL "
          f"trained on another task or with other task options?)")
    if b.normalize_observations != self.normalize_observations:
      raise ValueError(f"config.normalize_observations={b.normalize_observations} but the HL in {me} was "
                       f"trained {'with' if self.normalize_observations else 'without'} an observation "
                       f"normaliser; the finetuned policy must have A's layout")
    if b.hidden_sizes != self.hidden_sizes:
      raise ValueError(f"config.hidden_sizes={b.hidden_sizes} but the HL in {me} has hidden sizes "
                       f"{self.hidden_sizes}; the finetuned policy must have A's architecture")

  def check_imitated_by(self, b: "PolicyCard") -> None:
    """This LL (A's) as what the LL ``b`` (B's) is aligned to: the same goal space."""
    if self.family != b.family or self.goal_space != b.goal_space:
      raise ValueError(f"cannot align {b.agent!r} to the LL in {self.source} ({self.agent!r}): goal spaces "
                       f"differ ({b.goal_space} vs {self.goal_space}); A and B must both be nav or both manip "
                       f"agents")
    if b.obs_size < self.goal_dim or self.obs_size < self.goal_dim:
      raise ckpt.CheckpointError(f"LL observations must end with the {self.goal_dim} goal-space entries g - s")

  def inputs(self) -> dict[str, str]:
    """{record: run directory} of the runs this card's policy was trained from (its provenance)."""
    return {k: getattr(self, k).path for k in PROVENANCE if getattr(self, k) is not None}

  def check_params(self, params) -> None:
    """Refuses (one line) saved parameters whose policy network is not this card's: its layer widths,
    observation and action sizes (a leading seed axis is allowed)."""
    dims = [self.obs_size, *self.hidden_sizes, 2 * self.action_size]
    want = list(zip(dims[:-1], dims[1:]))
    try:
      mlp = params["policy"]["params"]["mlp"]
      names = [f"hidden_{i}" for i in range(len(mlp) - 1)] + ["out"]
      got = [tuple(int(d) for d in np.shape(mlp[n]["kernel"])[-2:]) for n in names]
    except (KeyError, TypeError, IndexError):
      got = None
    if got != want:
      sizes = " x ".join(str(w[1]) for w in got[:-1]) if got else "unreadable"
      raise ckpt.CheckpointError(
          f"the checkpoint of {self.source or 'this policy'} does not match its metadata (hidden_sizes="
          f"{list(self.hidden_sizes)}, obs_size={self.obs_size}, action_size={self.action_size}; the saved "
          f"policy's layers: {sizes}): meta.json was edited or belongs to another run; restore it from a backup "
          f"or re-train")

  def check_env(self, env, task: str) -> None:
    """Refuses an env whose observation does not fit this policy (evaluation on another task)."""
    if env.observation_size == self.obs_size:
      return
    if self.level == "high":
      raise ValueError(f"the HL observes {self.obs_size} numbers but {task} gives "
                       f"{env.observation_size} (was the HL trained on another task?)")
    raise ValueError(f"the policy observes {self.obs_size} numbers, {self.agent} "
                     f"on {task} gives {env.observation_size}")


_OPTIONAL = {"goal_space": str, "obs_lo_size": int, "obs_hi_size": int, "hl_horizon": int, "hl_obs": dict,
             "env_overrides": dict, "task_overrides": dict, "sac": dict, "seeds": list, "low": dict,
             "aligned_to": dict, "finetuned_from": dict, "best": dict, "discriminator": dict}


def check_fields(meta: Mapping, where) -> None:
  """Every field the card reads has its type and range (:data:`REQUIRED`, and the optional ones when
  present), so an edited or damaged meta.json is refused in one line naming the field."""
  def bad(key, expected):
    raise ckpt.CheckpointError(f"checkpoint metadata in {where} has {key}={meta[key]!r}, expected {expected}: "
                               f"the file was edited or damaged; re-run training, or restore it from a backup")

  is_int = lambda v: isinstance(v, int) and not isinstance(v, bool)
  if meta["level"] not in ("low", "high", "full"):
    bad("level", "'low', 'high' or 'full'")
  if meta["family"] not in GOAL_SPACE_NAMES:
    bad("family", " or ".join(repr(f) for f in GOAL_SPACE_NAMES))
  for key in ("obs_size", "action_size"):
    if meta[key] <= 0:
      bad(key, "a positive integer")
  if not meta["hidden_sizes"] or not all(is_int(h) and h > 0 for h in meta["hidden_sizes"]):
    bad("hidden_sizes", "a list of positive integers, e.g. [64, 64]")
  for key, kind in _OPTIONAL.items():
    v = meta.get(key)
    if v is not None and not (is_int(v) if kind is int else isinstance(v, kind)):
      bad(key, f"{'an' if kind is int else 'a'} {dict(str='string', int='integer', dict='JSON object', list='list')[kind.__name__]} or null")
  hl_obs = meta.get("hl_obs") or {}
  if not (all(is_int(i) for i in hl_obs.get("hl_relative", [])) and isinstance(hl_obs.get("hl_relative", []), list)
          and isinstance(hl_obs.get("hl_absolute", True), bool)):
    bad("hl_obs", '{"hl_relative": [integers], "hl_absolute": true or false}')
  for key in PROVENANCE:
    if meta.get(key) is not None and not isinstance(meta[key].get("path"), str):
      bad(key, 'a record of the run it names, {"path": "...", ...}')


def check_level(level, source, want: str, who: str = "") -> None:
  """A hand-off's level (checked first, so that a policy of the wrong level says so rather than what
  fields it lacks): ``want`` "low", or "high" for ``who`` (compose, finetune_high)."""
  if level == want:
    return
  if want == "low":
    raise ckpt.CheckpointError(f"{source} holds a {level!r}-level policy where a low level was expected "
                               f"(train one with `hdt train low --agent ...`)")
  raise ckpt.CheckpointError(f"{source} holds a {level!r}-level policy; {who} needs an HL (from `hdt train "
                             f"high`) as high=")


def load_low(low: str | Path, seed_index: int = 0, which: str = "final") -> tuple[dict, PolicyCard, Callable]:
  """(params, card, policy_fn) of a saved LL (policy_fn applies its saved observation statistics),
  checked to be a usable low level; ``which``: its "final" parameters or its "best" evaluation's (see
  :func:`ckpt.load`; the card's ``loaded`` says which were)."""
  params, meta = ckpt.load(low, seed_index, which)
  check_level(meta.get("level"), low, "low")
  card = PolicyCard.from_json(meta, Path(low) / f"seed_{seed_index}" / "meta.json").replace(source=str(low))
  card.low_box()
  card.check_params(params)
  check_recorded(meta)
  return params, card, card.policy_fn(params.get(ckpt.NORM))
