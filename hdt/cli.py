"""hdt: hierarchically decoupled morphological transfer, from the shell.

  hdt train low --agent point                     goal-reaching LL of an agent
  hdt train low --agent path/to/robot.xml         ... of your own robot (one MJCF file, ROBOTS.md)
  hdt train high --task waypoint --low RUN        HL SAC over a frozen LL
  hdt train full --agent ant --task maze          flat SAC baseline
  hdt align --agent arm3 --imitate RUN            LL aligned to another agent's LL (discriminator)
  hdt finetune --high RUN --low RUN --task push1 --kl-weight 1.0
  hdt eval --high RUN --low RUN --task waypoint   (repeat --high/--low NAME=RUN for a matrix)
  hdt sweep low --agent point --grid actor_lr=1e-4,3e-4
  hdt sweep finetune --high RUN --low RUN --task waypoint --grid kl_weight=0,1,10
  hdt reproduce table1 --preset paper             a paper table/figure: zoo, runs in --out, what is missing
  hdt report RUN                                  Markdown + PNGs of a run directory
  hdt render --policy zoo:arm3/low --out arm3.mp4 video of a policy (or --high RUN --low RUN --task T)
  hdt quickstart                                  minutes-scale tour on a CPU

All but zoo and render take --seeds N, --preset smoke|cpu|paper, --out DIR and --quiet.
"""

from __future__ import annotations

import os
import signal
import sys

# As the `hdt` command this module loads first: a Ctrl-C while it and its imports load is held and
# reported by main() (elsewhere it is a traceback from an import).
_EARLY_SIGINT: list = []
if (__name__ == "__main__" or os.path.basename(sys.argv[0] if sys.argv else "") == "hdt") \
    and signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:  # a background job (nohup) keeps ignoring it
  signal.signal(signal.SIGINT, lambda *a: _EARLY_SIGINT.append(a))

import argparse
import ast
import contextlib
import dataclasses
import itertools
import json
import time
import types
import typing
from pathlib import Path

# JAX, MuJoCo and hdt's modules take seconds to import: main() imports them (_import_hdt) once it
# handles Ctrl-C, so that an interrupt in the first instant exits cleanly too.
DiscConfig = SACConfig = configs = None


def _import_hdt() -> None:
  global DiscConfig, SACConfig, configs
  if configs is None:
    from hdt.agents.discriminator import DiscConfig
    from hdt.agents.sac import SACConfig
    from hdt.transfer import configs


def __getattr__(name):
  if name == "PRESETS":  # the --preset choices: hdt.transfer.configs.PRESETS
    _import_hdt()
    return tuple(configs.PRESETS)
  raise AttributeError(name)


AGENT_HELP = ("point, ant, ant3, ant2, quadruped, arm_point, arm2, arm3, arm4, or the path of a robot "
              "MJCF file that follows ROBOTS.md (e.g. examples/robots/hexapod.xml)")


class CLIError(Exception):
  """A usage problem: printed as one line, exit status 2."""


class _Help(argparse.RawDescriptionHelpFormatter):
  """Shows each option's default unless it is None (then the help text says where it comes from)."""

  def _get_help_string(self, action):
    h = action.help or ""
    if "%(default)" not in h and action.default not in (None, argparse.SUPPRESS, False) and action.option_strings:
      h += " (default: %(default)s)"
    return h


class _Parser(argparse.ArgumentParser):
  def error(self, message):  # one line, not argparse's usage dump
    raise CLIError(f"{self.prog}: {message} (see `{self.prog} --help`)")


# ------------------------------------------------------------------------------------------------
# Options generated from the config dataclasses, so --help always lists every field with its default.

def _bool(text: str) -> bool:
  t = text.strip().lower()
  if t in ("true", "1", "yes", "on", "false", "0", "no", "off"):
    return t in ("true", "1", "yes", "on")
  raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")


def _field_type(cls, f: dataclasses.Field) -> dict:
  """argparse's ``type`` (and ``nargs``) of a config field, from its annotation: ``X | None`` as X, a
  bool as true/false, ``tuple[X, ...]`` as one X or more, else the type itself."""
  hint = typing.get_type_hints(cls)[f.name]
  if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
    hint = next(a for a in typing.get_args(hint) if a is not type(None))
  if hint is bool:
    return dict(type=_bool)
  if typing.get_origin(hint) is tuple:
    return dict(type=typing.get_args(hint)[0], nargs="+")
  return dict(type=hint)


def _add_dataclass_options(p, cls, prefix: str, title: str, note: str):
  g = p.add_argument_group(title, note)
  for f in dataclasses.fields(cls):
    default = f.default if f.default is not dataclasses.MISSING else None
    g.add_argument(f"--{prefix}{f.name.replace('_', '-')}", dest=f"{prefix.replace('-', '_')}{f.name}",
                   default=None, metavar=f.name.upper(), **_field_type(cls, f),
                   help=f"default: from the agent/level and --preset (class default {default})" if prefix == ""
                   else f"default: by A's agent, the paper's table (class default {default})")


def _overrides(args, cls, prefix: str) -> dict:
  out = {}
  for f in dataclasses.fields(cls):
    v = getattr(args, f"{prefix}{f.name}", None)
    if v is not None:
      out[f.name] = tuple(v) if isinstance(v, list) else v
  return out


def _disc(args, agent_a: str) -> DiscConfig:
  """The discriminator of an alignment to ``agent_a``: its paper values, then the --disc-* options."""
  return configs.disc_config(agent_a, **_overrides(args, DiscConfig, "disc_"))


def _parse_value(text: str):
  try:
    return ast.literal_eval(text)
  except (ValueError, SyntaxError):
    return text


def _key_values(items, what: str) -> dict:
  out = {}
  for it in items or []:
    if "=" not in it:
      raise CLIError(f"{what} {it!r}: expected KEY=VALUE")
    k, v = it.split("=", 1)
    out[k.strip()] = _parse_value(v)
  return out


def _out_arg(text: str) -> Path:
  if not text.strip():
    raise argparse.ArgumentTypeError("--out is empty, which would write into the current directory; give a "
                                     "directory name, e.g. runs/my-run")
  return Path(text)


def _common(p, out_help="run directory (default: runs/<what>)"):
  p.add_argument("--seeds", type=int, default=None, help="number of seeds, vmapped in one process "
                 "(default: 1 for training, all seeds of a run for eval)")
  p.add_argument("--preset", choices=tuple(configs.PRESETS), default="cpu",
                 help="budget: smoke (seconds), cpu (this machine, minutes), paper (the authors' setup and "
                      "budgets). Budgets (--total-env-steps) count LL env steps for LLs and Full, HL "
                      f"decisions for HLs (the paper's units); paper: {configs.describe_paper_budgets()} "
                      "(default: %(default)s)")
  p.add_argument("--out", type=_out_arg, default=None, help=out_help)
  p.add_argument("--quiet", action="store_true", help="no progress output (CI)")


def _training(p, env_opts=True, fast=False):
  _common(p)
  if fast:
    _fast_option(p)
  p.add_argument("--backend", choices=("auto", "native", "mjx"), default="auto",
                 help="physics backend: auto = native MuJoCo on CPU, MJX on accelerators (default: %(default)s)")
  p.add_argument("--resume", action="store_true",
                 help="continue the run in --out from its last saved training state; with a larger "
                      "--total-env-steps, also a finished run (not align/finetune)")
  p.add_argument("--overwrite", action="store_true",
                 help="replace an existing hdt run in --out as a whole (never a directory hdt did not write)")
  if env_opts:
    p.add_argument("--set", action="append", metavar="KEY=VALUE", default=[],
                   help="agent/task option, e.g. --set goal=end (maze), --set terrain=steps (or insert), "
                        "--set delta_max=2.0 (repeatable)")
  _add_dataclass_options(p, SACConfig, "", "SAC hyper-parameters",
                         "Default: the paper's value for the agent/level (SPEC 4), then --preset's budget.")


def _fast_option(p):
  p.add_argument("--fast", action="store_true",
                 help="hdt's fast setting of a legged LL, that of the zoo's legged LLs (LL levels only): "
                      + " ".join(f"--{k.replace('_', '-')} {_flag_text(v)}" for k, v in configs.FAST_LOW.items())
                      + " (SAC options given win over it)")


def _flag_text(v) -> str:
  return " ".join(map(str, v)) if isinstance(v, tuple) else str(v).lower() if isinstance(v, bool) else f"{v:g}"


def _low_params(p):
  p.add_argument("--low-params", choices=("best", "final"), default="best",
                 help="the LL's parameters: those of its best periodic evaluation (as the authors compose "
                      "an HL over an LL; final if it has none), or its final ones")


def build_parser() -> argparse.ArgumentParser:
  _import_hdt()
  p = _Parser(prog="hdt", description=__doc__, formatter_class=_Help)
  sub = p.add_subparsers(dest="cmd", required=True, metavar="COMMAND", parser_class=_Parser)
  fmt = _Help

  t = sub.add_parser("train", help="train a low level, a high level or the flat Full baseline", formatter_class=_Help)
  tsub = t.add_subparsers(dest="level", required=True, metavar="LEVEL", parser_class=_Parser)
  lo = tsub.add_parser("low", help="goal-reaching LL of --agent on its reach task", formatter_class=fmt)
  lo.add_argument("--agent", required=True, help=AGENT_HELP)
  _training(lo, fast=True)
  hi = tsub.add_parser("high", help="HL SAC on --task over the frozen LL in --low", formatter_class=fmt)
  hi.add_argument("--task", required=True, help="waypoint, maze, steps, push1, push2, insert")
  hi.add_argument("--low", required=True, type=Path, help="LL run directory (from `hdt train low`)")
  hi.add_argument("--low-seed", type=int, default=0, help="seed of --low that drives every HL seed")
  hi.add_argument("--k", type=int, default=None, help="LL steps per HL action (default: the LL's)")
  _low_params(hi)
  _training(hi)
  fu = tsub.add_parser("full", help="flat SAC on --task with --agent's torques", formatter_class=fmt)
  fu.add_argument("--agent", required=True, help=AGENT_HELP)
  fu.add_argument("--task", required=True)
  _training(fu)

  al = sub.add_parser("align", help="LL of --agent aligned to the LL in --imitate (Algorithm 1)",
                      formatter_class=fmt)
  al.add_argument("--agent", required=True, help=AGENT_HELP)
  al.add_argument("--imitate", required=True, type=Path, help="LL run directory of agent A")
  al.add_argument("--n-offline", type=int, default=20_000, help="A transitions in the fixed set (--disc-data fixed)")
  al.add_argument("--imitate-params", choices=("best", "final"), default="best",
                  help="A's parameters to imitate: its best periodic evaluation's (as the authors; final "
                       "if it has none), or its final ones")
  _training(al, fast=True)
  _add_dataclass_options(al, DiscConfig, "disc-", "discriminator", "Algorithm 1's discriminator (SPEC 4).")

  ft = sub.add_parser("finetune", help="finetune the HL in --high on the LL in --low, KL-tied to it",
                      formatter_class=fmt)
  ft.add_argument("--high", required=True, type=Path, help="HL run directory of agent A")
  ft.add_argument("--low", required=True, type=Path, help="LL run directory of agent B")
  ft.add_argument("--task", required=True)
  ft.add_argument("--kl-weight", "--kl", type=float, default=None, dest="kl_weight",
                  help="initial weight of the KL term (the paper's beta); 0 = plain finetuning (default: the "
                       "task's, as the paper: 1 for Waypoint and manipulation, 0.01 for Maze and Steps)")
  ft.add_argument("--anneal-frac", type=float, default=0.5, help="the KL weight reaches 0 after this fraction")
  ft.add_argument("--mode", choices=("forward", "reverse"), default="forward", help="KL direction")
  ft.add_argument("--mean-only", action="store_true", help="tie only the means: the squared distance of the pre-tanh means (the authors' kl_type=mean)")
  ft.add_argument("--lr", type=float, default=None,
                  help="all learning rates (default, as the paper: the task's, 0.01 for Waypoint and "
                       "manipulation, 0.001 for Maze and Steps; with --kl-weight 0, A's own; unless "
                       "--actor-lr/--critic-lr/--alpha-lr set them)")
  ft.add_argument("--low-seed", type=int, default=0)
  ft.add_argument("--reference-params", choices=("best", "final"), default="best",
                  help="A's parameters the KL ties to: its best periodic evaluation's (as the authors; "
                       "final if it has none), or its final ones; finetuning starts from A's final SAC")
  _low_params(ft)
  _training(ft)

  ev = sub.add_parser("eval", help="evaluate HL+LL pairs (or a flat --policy); a matrix with NAME=RUN",
                      formatter_class=fmt)
  ev.add_argument("--high", action="append", default=[], help="HL run, or NAME=RUN (repeat for a matrix)")
  ev.add_argument("--low", action="append", default=[], help="LL run, or NAME=RUN (repeat for a matrix)")
  ev.add_argument("--policy", type=Path, default=None, help="a flat policy run (LL on reach, or Full)")
  ev.add_argument("--task", default=None, help="task (default: the HL's)")
  ev.add_argument("--episodes", type=int, default=100, help="deterministic episodes per seed")
  ev.add_argument("--box", choices=("refuse", "scale", "keep"), default="refuse",
                  help="what to do when the HL's and LL's goal boxes differ")
  ev.add_argument("--set", action="append", metavar="KEY=VALUE", default=[], help="task option, e.g. goal=end")
  ev.add_argument("--backend", choices=("auto", "native", "mjx"), default="auto")
  ev.add_argument("--params", choices=("final", "best"), default="final",
                  help="the HL's (or --policy's) final parameters, or those of its best periodic evaluation")
  _low_params(ev)
  _common(ev, "where eval.json (and a heatmap) go (default: runs/eval)")

  sw = sub.add_parser("sweep", help="seeds x a hyper-parameter grid (seeds and same-shape grid points vmapped)",
                      formatter_class=fmt)
  sw.add_argument("level", choices=("low", "high", "full", "finetune", "align"))
  sw.add_argument("--agent", default=None)
  sw.add_argument("--task", default=None)
  sw.add_argument("--low", type=Path, default=None, help="LL run (levels high, finetune)")
  sw.add_argument("--high", type=Path, default=None, help="HL run of agent A (level finetune)")
  sw.add_argument("--imitate", type=Path, default=None, help="LL run of agent A (level align)")
  sw.add_argument("--grid", action="append", default=[], metavar="FIELD=V1,V2,...",
                  help="SAC field (or kl_weight for finetune, disc_weight for align) and its values "
                       "(repeatable; the grid is their product)")
  sw.add_argument("--anneal-frac", type=float, default=0.5,
                  help="finetune: the KL weight reaches 0 after this fraction")
  sw.add_argument("--mode", choices=("forward", "reverse"), default="forward", help="finetune: KL direction")
  sw.add_argument("--mean-only", action="store_true", help="finetune: tie only the means")
  sw.add_argument("--reference-params", choices=("best", "final"), default="best",
                  help="finetune: A's parameters the KL ties to (as `hdt finetune`)")
  sw.add_argument("--low-seed", type=int, default=0, help="high, finetune: seed of --low that drives every HL seed")
  _low_params(sw)
  sw.add_argument("--n-offline", type=int, default=20_000, help="align: A transitions in the fixed set (--disc-data fixed)")
  sw.add_argument("--imitate-params", choices=("best", "final"), default="best",
                  help="align: A's parameters to imitate (as `hdt align`)")
  _add_dataclass_options(sw, DiscConfig, "disc-", "discriminator (align)", "Algorithm 1's discriminator (SPEC 4).")
  sw.add_argument("--set", action="append", metavar="KEY=VALUE", default=[])
  sw.add_argument("--backend", choices=("auto", "native", "mjx"), default="auto")
  _fast_option(sw)
  _add_dataclass_options(sw, SACConfig, "", "SAC hyper-parameters (every grid point)",
                         "Default: as `hdt train` (the paper's value for the agent/level, then --preset's budget).")
  _common(sw, "sweep directory, one run per grid point (default: runs/sweep-<level>)")
  sw.add_argument("--overwrite", action="store_true", help="replace an existing sweep in --out as a whole")

  from hdt.paper import NAMES
  rp = sub.add_parser("reproduce", help="a paper table or figure: zoo entries (paper preset) and the runs in --out "
                      "reused, what is missing trained, NAME_PRESET.md/.json/.png written", formatter_class=fmt)
  rp.add_argument("name", choices=NAMES)
  rp.add_argument("--only", action="append", default=None, metavar="PATTERN",
                  help="cells to run, by id (part/row/column, e.g. 'waypoint/pm/*', or a part's name; repeatable); "
                       "the others keep their earlier numbers, or show as not selected")
  rp.add_argument("--max-env-steps", type=_env_steps_limit, default="preset", metavar="N|all",
                  help="train a missing run only if it costs at most N env steps of its robot (an HL: decisions "
                       "times k); the others are listed as not run, with the command that trains them (default: "
                       "%(default)s, the preset's limit: none at smoke and cpu, 1000000 at paper)")
  rp.add_argument("--dry-run", action="store_true", help="print the plan (zoo, reuse, train, not run) and stop")
  _common(rp, "directory of the table's runs, its NAME_PRESET.md, .json and .png (default: runs/NAME-PRESET)")

  rep = sub.add_parser("report", help="Markdown summary, learning curves and a trajectory of a run",
                       formatter_class=fmt)
  rep.add_argument("run", type=Path, nargs="+", help="run directories")
  rep.add_argument("--no-trajectory", action="store_true", help="skip the trajectory plot")
  rep.add_argument("--no-video", action="store_true", help="skip the clip of the policy (hdt render)")
  _common(rep, "unused (reports go to RUN/report/)")

  zo = sub.add_parser("zoo", help="list the model zoo (zoo:NAME works wherever a run directory does), "
                      "or export a run into it", formatter_class=fmt)
  zo.add_argument("action", nargs="?", choices=["list", "export"], default="list")
  zo.add_argument("run", nargs="?", help="export: the run directory to copy (policy only)")
  zo.add_argument("--name", help="export: entry name, e.g. arm_point/push1")
  zo.add_argument("--low", help="export of an HL: its LL as a zoo name (zoo:...), exported first")
  zo.add_argument("--task", help="export: task to evaluate on (default the run's own)")
  zo.add_argument("--command", default="", help="export: the command that trained the run (recorded)")
  zo.add_argument("--episodes", type=int, default=100, help="export: evaluation episodes per seed")
  zo.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="export: task options")
  zo.add_argument("--overwrite", action="store_true", help="export: replace an existing entry")
  zo.add_argument("--keep-sac", action="store_true",
                  help="export of an HL that finetuning starts from: keep its whole final SAC, not its policy only")
  zo.add_argument("--params", choices=("best", "final"), default="best",
                  help="export of an LL: keep the parameters of its best periodic evaluation (what HLs compose "
                       "with) or its final ones")

  q = sub.add_parser("quickstart", help="PM LL + HL on Waypoint in minutes, then zero-shot transfer tables with zoo policies",
                     formatter_class=fmt)
  _common(q, "root of the quickstart's runs (default: runs/quickstart)")
  q.add_argument("--overwrite", action="store_true", help="replace an existing quickstart in --out as a whole")
  _render_parser(sub, fmt)
  return p


# ------------------------------------------------------------------------------------------------
# Sub-commands.

def _seeds(args, default=1) -> int:
  n = default if args.seeds is None else args.seeds
  if n <= 0:
    raise CLIError(f"--seeds {n}: give a positive number of seeds")
  return n


def _out_dir(args, name: str, kind: str = "run", reuse: bool = False, reads=(), legacy=None) -> Path:
  """--out (default runs/<name>), checked before anything is loaded or compiled (hdt.transfer.rundir);
  ``reads``: {option: run} of the runs the command reads, which it never writes over."""
  from hdt.transfer import checkpoint as ckpt
  from hdt.transfer import rundir
  out = args.out if args.out is not None else Path("runs") / name
  resume, overwrite = getattr(args, "resume", False), getattr(args, "overwrite", False)
  if resume and overwrite:
    raise CLIError("--resume continues the run in --out, --overwrite replaces it: pass one of them")
  rundir.check_claimable(out, kind, resume=resume, overwrite=overwrite, reuse=reuse, what="--out",
                         reads={f"--{k}": v for k, v in dict(reads).items()}, legacy=legacy)
  if resume and not ckpt.has_state(out):
    raise CLIError(f"--resume: {out} holds no saved training state to continue (a run killed before its first "
                   f"save); start it again with --overwrite, or pass the run's --out")
  return out


def _options(args, out: Path, seeds: int):
  """The RunOptions of a training command (hdt.transfer.runner)."""
  from hdt.transfer.runner import RunOptions
  return RunOptions(seeds=seeds, out=out, quiet=args.quiet, resume=bool(args.resume), overwrite=bool(args.overwrite))


def sac_config(args, level: str, agent=None, task=None, **extra) -> SACConfig:
  """The SACConfig a parsed training command (``build_parser().parse_args(...)``) asks for: the
  ``--preset``'s config of ``level`` for ``agent`` / ``task`` (``paper`` with MJX on a GPU: the
  accelerator throughput of the defaults table), with ``extra`` and the command's SAC options applied."""
  _import_hdt()
  fast = configs.FAST_LOW if getattr(args, "fast", False) else {}
  if fast and level != "low":
    raise CLIError(f"--fast is the setting of a legged LL (train low, align, sweep low|align), not of a {level} "
                   f"run: drop --fast, or give the SAC options one by one")
  return configs.config(level, args.preset, agent=agent, task=task, backend=getattr(args, "backend", None),
                        **(extra | fast | _overrides(args, SACConfig, "")))


def _check_agent_task(agent=None, task=None):
  from hdt.envs.agents import AGENTS
  from hdt.envs.robot import is_robot_path, load_robot
  from hdt.envs.tasks import TASKS
  if agent is not None and is_robot_path(agent):
    load_robot(agent)  # validated now: a RobotError is one line naming what the file misses
  elif agent is not None and agent not in AGENTS:
    raise CLIError(f"unknown agent {agent!r}; choose one of {', '.join(AGENTS)}, or give the path of "
                   f"a robot MJCF file (ROBOTS.md)")
  if task is not None and task not in TASKS:
    raise CLIError(f"unknown task {task!r}; choose one of {', '.join(TASKS)}")


def _label(agent: str) -> str:
  """An agent's name in a default run directory: a robot file's stem."""
  from hdt.envs.robot import short_name
  return short_name(agent)


def _finish(res, args):
  import numpy as np

  from hdt.numfmt import mean_std, number
  ev = {k: v for k, v in res.history.items() if k in ("eval/return", "eval/success_max", "eval/goal_dist")}
  summary = ", ".join(f"{k[5:]} {mean_std(np.mean(v[:, -1]), np.std(v[:, -1]))}" for k, v in ev.items())
  print(f"{res.run_dir}: final evaluation {summary}")
  if res.best is not None:  # kept beside the final parameters (seed_<i>/best/, `hdt eval --params best`)
    best = ", ".join(f"{number(r)} at {s}" for r, s in zip(res.best["score"], res.best["env_steps"]))
    by = res.card.sac.get("best_by", "return")
    print(f"{res.run_dir}: best evaluation per seed ({by} at env step) {best}")
  return 0


def cmd_train(args) -> int:
  from hdt.transfer import pipeline
  from hdt.transfer.card import LowRef
  overrides = _key_values(args.set, "--set")
  pipeline.check_env_overrides(overrides, getattr(args, "agent", None), getattr(args, "task", None) or "reach")
  seeds = _seeds(args)
  if args.level == "low":
    _check_agent_task(args.agent)
    cfg = sac_config(args, "low", args.agent)
    out = _out_dir(args, f"low-{_label(args.agent)}")
    res = pipeline.train_low(args.agent, cfg, backend=args.backend, options=_options(args, out, seeds), **overrides)
  elif args.level == "high":
    _check_agent_task(task=args.task)
    low_card = pipeline.load_low(args.low, args.low_seed)[1]  # checked to be a usable LL
    if args.k is not None and args.k <= 0:
      raise CLIError(f"--k {args.k}: give a positive number of LL steps per HL action")
    overrides = configs.task_options(args.preset, args.task) | overrides
    cfg = sac_config(args, "high", task=args.task)
    out = _out_dir(args, f"high-{args.task}-{_label(low_card.agent)}", reads={"low": args.low})
    res = pipeline.train_high(args.task, LowRef(args.low, args.low_seed, args.low_params), cfg, k=args.k,
                              backend=args.backend, options=_options(args, out, seeds), **overrides)
  else:
    _check_agent_task(args.agent, args.task)
    cfg = sac_config(args, "full", args.agent, args.task)
    out = _out_dir(args, f"full-{_label(args.agent)}-{args.task}")
    res = pipeline.train_full(args.agent, args.task, cfg, backend=args.backend, options=_options(args, out, seeds),
                              **overrides)
  return _finish(res, args)


def cmd_align(args) -> int:
  from hdt.transfer.align import AlignSpec, align_low
  _check_agent_task(args.agent)
  from hdt.transfer.pipeline import check_env_overrides, load_low
  imitate = load_low(args.imitate)[1]  # fails early, with the checkpoint's own message
  check_env_overrides(_key_values(args.set, "--set"), args.agent, "reach")
  disc = _disc(args, imitate.agent)
  cfg = sac_config(args, "low", args.agent)
  out = _out_dir(args, f"align-{_label(args.agent)}-to-{_label(imitate.agent)}",
                 reads={"imitate": args.imitate})
  spec = AlignSpec(args.imitate, disc, n_offline=args.n_offline, imitate_params=args.imitate_params)
  res = align_low(args.agent, spec, cfg, backend=args.backend, options=_options(args, out, _seeds(args)),
                  **_key_values(args.set, "--set"))
  return _finish(res, args)


def _finetune_spec(args):
  """The FinetuneSpec of `hdt finetune` / `hdt sweep finetune` (checked field by field when made)."""
  from hdt.transfer.finetune import FinetuneSpec
  return FinetuneSpec(kl_weight=getattr(args, "kl_weight", None), anneal_frac=args.anneal_frac, mode=args.mode,
                      mean_only=args.mean_only, lr=getattr(args, "lr", None), reference_params=args.reference_params,
                      learning_starts=None if args.learning_starts is not None else 0,  # the authors': 0
                      ).for_task(args.task)  # the paper's KL weight of the task unless given


def cmd_finetune(args) -> int:
  from hdt.transfer import checkpoint as ckpt
  from hdt.transfer.card import LowRef, PolicyCard
  from hdt.transfer.finetune import finetune_high, start_fields
  from hdt.transfer.pipeline import check_env_overrides, load_low
  _check_agent_task(task=args.task)
  spec = _finetune_spec(args)
  check_env_overrides(_key_values(args.set, "--set"), task=args.task)
  a = PolicyCard.from_json(ckpt.load_meta(args.high), args.high)  # every field of its type, before it is used
  b = load_low(args.low, args.low_seed)[1]
  # A's network and SAC kind; the task's finetuning lr (plain finetuning: A's own) unless set
  cfg = sac_config(args, "finetune", task=args.task, **start_fields(a, args.task, spec.kl_weight))
  out = _out_dir(args, f"finetune-{args.task}-{_label(a.agent)}-to-{_label(b.agent)}-kl{spec.kl_weight:g}",
                 reads={"high": args.high, "low": args.low})
  res = finetune_high(args.high, LowRef(args.low, args.low_seed, args.low_params), args.task, cfg, spec=spec,
                      backend=args.backend, options=_options(args, out, _seeds(args)),
                      **(configs.task_options(args.preset, args.task) | _key_values(args.set, "--set")))
  return _finish(res, args)


def named_runs(items) -> dict[str, Path]:
  """``{name: run directory}`` of ``--high`` / ``--low`` arguments, each RUN (named by its directory)
  or NAME=RUN; an existing path is always a RUN (sweep run directories contain '='), and NAME ends at
  the first '='."""
  out = {}
  for it in items:
    name, sep, run = it.partition("=")
    if not sep or Path(it).exists() or "/" in name:
      name, run = "", it
    name = name or Path(run).name
    if name in out:
      raise CLIError(f"two runs are named {name!r} ({out[name]} and {run}): name each once, e.g. "
                     f"--high {name}_a={out[name]} --high {name}_b={run}")
    out[name] = Path(run)
  return out


def cmd_eval(args) -> int:
  from hdt import plots
  from hdt.numfmt import mean_std, number
  from hdt.report import markdown_table
  from hdt.transfer import checkpoint as ckpt
  from hdt.transfer.evaluate import compose, evaluate, load_policy, zero_shot_matrix

  from hdt.transfer import rundir
  from hdt.transfer.pipeline import check_env_overrides
  overrides = _key_values(args.set, "--set")
  check_env_overrides(overrides, task=args.task)
  if args.episodes <= 0:
    raise CLIError(f"--episodes {args.episodes}: give a positive number of episodes")
  highs, lows = named_runs(args.high), named_runs(args.low)
  named = lambda opt, runs: {opt + ("" if len(runs) == 1 else f" {k}"): v for k, v in runs.items()}
  reads = named("high", highs) | named("low", lows)
  out = _out_dir(args, "eval", kind="eval", reuse=True,  # evaluations add files to an eval directory
                 reads=reads | ({"policy": args.policy} if args.policy is not None else {}))
  if args.policy is not None:
    if highs or lows:
      raise CLIError("--policy evaluates a flat policy: do not combine it with --high/--low")
    pol = load_policy(args.policy, args.params)
    task = args.task or pol.card.task
  elif len(highs) == 1 and len(lows) == 1:
    pol = compose(next(iter(highs.values())), next(iter(lows.values())), box=args.box, which=args.params,
                  low_which=args.low_params)
    task = args.task or pol.card.task
  elif highs and lows:
    first = next(iter(highs.values()))
    task = args.task or ckpt.require(ckpt.load_meta(first), {"task": str}, first)["task"]
    m = zero_shot_matrix(highs, lows, task, episodes=args.episodes, backend=args.backend, which=args.params,
                         low_which=args.low_params, **overrides)
    rows = [[r] + [mean_std(*m["cells"][(r, c)][:2]) for c in m["cols"]] for r in m["rows"]]
    table = markdown_table(["LL \\ HL"] + m["cols"], rows)
    with rundir.claim(out, "eval", reuse=True):
      png = plots.heatmap(m, out / f"matrix_{task}.png")
      _write_json(out / f"matrix_{task}.json", dict(task=task, rows=m["rows"], cols=m["cols"],
                  cells={f"{r}|{c}": v for (r, c), v in m["cells"].items()},
                  params={f"{r}|{c}": dict(zip(("params", "low_params"), v)) for (r, c), v in m["params"].items()}))
    # what was used, which differs from what was asked where an entry keeps one set (zoo --params final)
    used = sorted(set(m["params"].values()))
    shown = (f"HL {used[0][0]}, LL {used[0][1]}" if len(used) == 1 else "per cell")
    print(table + f"\n\nparameters: {shown} (see {out / f'matrix_{task}.json'})\nheatmap: {png}")
    return 0
  else:
    raise CLIError("give --high RUN and --low RUN (or several NAME=RUN of each for a matrix), or --policy RUN")
  seeds = None if args.seeds is None else list(range(_seeds(args)))
  ev = evaluate(pol, task, episodes=args.episodes, seeds=seeds, backend=args.backend, **overrides)
  rows = [[k.removesuffix("_mean"), mean_std(ev[k], ev[k.replace("_mean", "_std")]),
           ", ".join(number(x) for x in ev["per_seed"][k.removesuffix("_mean")])]
          for k in ev if k.endswith("_mean")]
  print(markdown_table(["metric", "mean ± std over seeds", "per seed"], rows))
  print("parameters: " + ", ".join(f"{k.replace('_', ' ')} {ev[k]}" for k in ("params", "low_params") if k in ev))
  with rundir.claim(out, "eval", reuse=True):
    _write_json(out / f"eval_{task}.json", {k: v for k, v in ev.items() if k != "per_seed"}
                | {"per_seed": {k: v.tolist() for k, v in ev["per_seed"].items()}, "task": task})
  print(f"written: {out / f'eval_{task}.json'}")
  return 0


def _write_json(path: Path, obj) -> None:
  from hdt.transfer.checkpoint import write_json_atomic
  path.parent.mkdir(parents=True, exist_ok=True)
  write_json_atomic(path, obj)


def _grid_value(name: str, text: str, field: dataclasses.Field):
  """One --grid value, of the SAC field's type (finite numbers; tuples are not swept); a float for a
  plug-in weight (``field`` None)."""
  import math
  want = float if field is None else _field_type(SACConfig, field).get("type")
  value = _parse_value(text.strip())
  if field is not None and _field_type(SACConfig, field).get("nargs"):
    raise CLIError(f"--grid {name}: tuple fields cannot be swept; pass --{name.replace('_', '-')} per run")
  if want is int:
    ok = isinstance(value, int) and not isinstance(value, bool)
  elif want is float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
  else:
    ok = bool(text.strip())
  if not ok:
    kind = {int: "an integer", float: "a finite number"}.get(want, "a value")
    example = 1.0 if field is None else field.default
    raise CLIError(f"--grid {name}={text!r}: expected {kind} for each comma-separated value, e.g. "
                   f"{name}={example!r},{example!r}")
  return value


def cmd_sweep(args) -> int:
  from hdt import atomic
  from hdt.agents.sharding import on_writer  # several processes: process 0 writes
  from hdt.report import markdown_table
  from hdt.transfer import pipeline, rundir, sweep
  from hdt.transfer.align import AlignSpec
  fields = {f.name: f for f in dataclasses.fields(SACConfig)}
  lv = sweep.level_of(args.level)
  weights = lv.weight_names  # the plug-in weights the level's stage lets a grid vary
  grid = {}
  for g in args.grid:
    if "=" not in g:
      raise CLIError(f"--grid {g!r}: expected FIELD=V1,V2,...")
    name, values = g.split("=", 1)
    if name not in fields and name not in weights:
      also = f" nor a weight of sweep {args.level} ({', '.join(weights)})" if weights else ""
      raise CLIError(f"--grid {name}: not a SAC field{also}; fields: {', '.join(fields)}")
    if name in grid:
      raise CLIError(f"--grid {name} is given twice: list all its values once, {name}=V1,V2,...")
    grid[name] = [_grid_value(name, v, fields.get(name)) for v in values.split(",")]
    twice = [v for i, v in enumerate(grid[name]) if v in grid[name][:i]]
    if twice:
      raise CLIError(f"--grid {name}={values} lists the value {twice[0]!r} twice: give each value once")
  if not grid:
    raise CLIError("give at least one --grid FIELD=V1,V2")
  both = sorted(set(grid) & set(_overrides(args, SACConfig, "")))
  if both:
    raise CLIError(f"{', '.join('--' + b.replace('_', '-') for b in both)} is also swept by --grid: "
                   f"give each field once, as an option or in the grid")
  missing = [n for n in lv.needs if getattr(args, n) is None]
  if missing:
    raise CLIError(f"sweep {args.level} needs {' and '.join(_NEEDS[n] for n in missing)}")
  if "high" in lv.needs:
    _check_agent_task(task=args.task)
    _finetune_spec(args)  # checked before anything is written
  _check_agent_task(args.agent, args.task)
  overrides = _key_values(args.set, "--set")
  pipeline.check_env_overrides(overrides, args.agent, args.task or "reach")
  reads = {k: getattr(args, k) for k in ("low", "high", "imitate") if getattr(args, k) is not None}
  root = _out_dir(args, f"sweep-{args.level}", kind="sweep", reads=reads)
  seeds = _seeds(args)
  if "low" in lv.needs:
    pipeline.load_low(args.low, args.low_seed)  # checked to be a usable LL before anything is written
  if "high" in lv.needs:
    from hdt.transfer.finetune import load_high
    load_high(args.high)  # checked to be an HL
  disc = _disc(args, pipeline.load_low(args.imitate)[1].agent) if "imitate" in lv.needs else None
  imitate = {"imitate": AlignSpec(args.imitate, disc)} if disc is not None else {}
  sweep.check_weights(lv, [{k: v} for k in weights if k in grid for v in grid[k]], imitate)
  with rundir.claim(root, "sweep", overwrite=args.overwrite, reads=reads):
    rows = _sweep(args, lv, grid, root, seeds, overrides, disc)
    table = markdown_table(["grid point", "metric", "final eval (mean ± std)", "run"], rows)
    on_writer(lambda: atomic.write_text(root / "sweep.md", table + "\n"), f"writing {root / 'sweep.md'}")
  print(table)
  return 0


# what `hdt sweep` says a level needs (hdt.transfer.runner.Level.needs), and how it passes each
_NEEDS = {"agent": "--agent", "task": "--task", "low": "--low RUN", "high": "--high RUN (A's HL)",
          "imitate": "--imitate RUN (A's LL)"}


def _stage_value(args, name: str, disc):
  """The stage keyword ``name`` (one of Level.needs) from the command line."""
  from hdt.transfer.align import AlignSpec
  from hdt.transfer.card import LowRef
  if name == "low":
    return LowRef(args.low, args.low_seed, args.low_params)
  if name == "imitate":
    return AlignSpec(args.imitate, disc, n_offline=args.n_offline, imitate_params=args.imitate_params)
  return getattr(args, name)


def _sweep(args, lv, grid: dict, root: Path, seeds: int, overrides: dict, disc) -> list:
  import numpy as np
  from hdt.envs.tasks import get_task
  from hdt.numfmt import mean_std
  from hdt.transfer import checkpoint as ckpt
  from hdt.transfer import sweep
  from hdt.transfer.card import PolicyCard
  from hdt.transfer.finetune import start_fields
  from hdt.transfer.runner import RunOptions
  level = lv.sac_level or lv.name  # of the SAC config
  extra = {}
  if "high" in lv.needs:  # finetuning, as `hdt finetune`: A's SAC, and the preset's task options
    a = PolicyCard.from_json(ckpt.load_meta(args.high), args.high)
    # one learning rate for every point (the task's unless gridded), so that kl_weight=0 differs only in the KL
    extra = {k: v for k, v in start_fields(a, args.task).items() if k not in grid}
    overrides = configs.task_options(args.preset, args.task) | overrides
  names, runs = [], []
  for values in itertools.product(*grid.values()):
    point = dict(zip(grid, values))
    names.append(",".join(f"{k_}={v}" for k_, v in point.items()))
    weights = {k: float(v) for k, v in point.items() if k in lv.weight_names}
    sac = {k: v for k, v in point.items() if k not in weights}
    runs.append((sac_config(args, level, args.agent, args.task if level != "low" else None, **extra, **sac),
                 root / names[-1].replace("/", "_"), weights))
  stage = {n: _stage_value(args, n, disc) for n in lv.needs}
  if "high" in lv.needs:
    stage["spec"] = _finetune_spec(args)
  # points differing only in SWEEPABLE fields (learning rates, tau, gamma, reward scale, target entropy)
  # or the plug-in weights train as one vmapped program
  options = RunOptions(seeds=seeds, quiet=args.quiet)  # each grid point's run is new: the sweep was claimed whole
  results = sweep.sweep(args.level, runs, backend=args.backend, options=options, **stage, **overrides)
  metric = get_task(args.task if level != "low" else "reach").headline_column
  rows = []
  for name, (_, out, _), res in zip(names, runs, results):
    final = res.history[metric][:, -1]
    rows.append([name, metric[5:], mean_std(np.mean(final), np.std(final)), str(out)])
  return rows


def _env_steps_limit(text: str):
  """--max-env-steps: a number of env steps, "all" (no limit, None) or "preset"."""
  if text in ("all", "preset"):
    return None if text == "all" else text
  if not text.isdigit():
    raise argparse.ArgumentTypeError(f"expected a number of env steps or 'all', got {text!r}")
  return int(text)


def cmd_reproduce(args) -> int:
  from hdt import paper
  from hdt.paper.table import legacy
  out = _out_dir(args, f"{args.name}-{args.preset}", kind="experiment", reuse=True, legacy=legacy(args.name))
  seeds = None if args.seeds is None else _seeds(args)
  t0 = time.time()
  done = paper.reproduce(args.name, args.preset, out, seeds=seeds, only=args.only or (),
                         max_env_steps=args.max_env_steps, quiet=args.quiet, dry_run=args.dry_run)
  print(done.markdown)
  if not args.dry_run:
    print(f"{args.name} ({args.preset}) took {(time.time() - t0) / 60:.1f} min; written: "
          + ", ".join(str(p) for p in done.files))
  return 0


def cmd_zoo(args) -> int:
  from hdt.transfer import names, zoo
  if args.action == "list":
    print(zoo.table() if zoo.entry_names() else f"the zoo ({names.ZOO_DIR}) is empty")
    return 0
  if not args.run or not args.name:
    raise CLIError("hdt zoo export needs RUN and --name NAME, e.g. hdt zoo export runs/pm_low --name point/low")
  zoo.check_name(args.name)
  if args.episodes <= 0:
    raise CLIError(f"--episodes {args.episodes}: the entry's evaluation needs a positive number of episodes")
  dest = zoo.export(args.run, args.name, args.command, low=args.low, task=args.task, episodes=args.episodes,
                    overwrite=args.overwrite, keep_sac=args.keep_sac, low_params=args.params,
                    **_key_values(args.set, "--set"))
  print(f"exported {args.run} to {dest} (zoo:{args.name})")
  return 0


def cmd_report(args) -> int:
  from hdt.report import run_report
  for run in args.run:
    path = run_report(run, trajectory=not args.no_trajectory, video=not args.no_video)
    print(path.read_text())
    print(f"report: {path}")
  return 0


def cmd_quickstart(args) -> int:
  """Trains a PM hierarchy on Waypoint (minutes), then shows zero-shot transfer with zoo policies."""
  from hdt.transfer import rundir
  root = _out_dir(args, "quickstart", kind="quickstart")
  seeds, quiet = _seeds(args, 2), args.quiet
  with rundir.claim(root, "quickstart", overwrite=args.overwrite):
    return _quickstart(args, root, seeds, quiet)


def _quickstart_transfers() -> tuple:
  """Rows of the transfer table: (task, label, HL run ("here": the one trained here), LL run, uniform
  random sub-goals instead of the HL's, paper's number: Table 1's zero-shot and own-HL cells)."""
  from hdt.paper.runs import LEGGED_LOW
  ant = "zoo:" + LEGGED_LOW["ant"]
  return (
      ("push1", "3Link's own HL", "zoo:arm3/push1_500k", "zoo:arm3/low_paper", False, ".96 ± .02"),
      ("push1", "4Link HL, zero-shot", "zoo:arm4/push1_500k", "zoo:arm_point/low", False, ".26 ± .17"),
      ("push1", "PM HL, zero-shot", "zoo:arm_point/push1_1p2m", "zoo:arm3/low_paper", False, ".17 ± .08"),
      ("push1", "uniform random sub-goals", "zoo:arm3/push1_500k", "zoo:arm3/low_paper", True, "—"),
      ("waypoint", "PM HL (trained here), zero-shot", "here", ant, False, "483 ± 39"),
      ("waypoint", "uniform random sub-goals", "here", ant, True, "—"),
  )


def _quickstart(args, root: Path, seeds: int, quiet: bool) -> int:
  import json

  from hdt import atomic
  from hdt.numfmt import mean_std
  from hdt.report import markdown_table, run_report
  from hdt.transfer import zoo
  from hdt.transfer.evaluate import compose, evaluate, random_actions
  from hdt.transfer.pipeline import train_high, train_low
  from hdt.transfer.runner import RunOptions
  small = args.preset == "smoke"
  pm = dict(total_env_steps=2000 if small else 20_000, num_envs=8, updates_per_step=8,
            steps_per_chunk=25 if small else 250)
  low = train_low("point", configs.low_config("point", **pm),
                  options=RunOptions(seeds=seeds, out=root / "pm_low", quiet=quiet))
  hl = dict(pm, total_env_steps=400 if small else 8000, steps_per_chunk=25 if small else 100)
  high = train_high("waypoint", low.run_dir, configs.high_config("waypoint", **hl),
                    options=RunOptions(seeds=seeds, out=root / "pm_high", quiet=quiet))
  episodes = 4 if small else 50
  own = evaluate(compose(high.run_dir, low.run_dir), "waypoint", episodes=episodes)
  print(f"\n1. Trained here: point-mass LL ({pm['total_env_steps']} steps) and Waypoint HL "
        f"({hl['total_env_steps']} decisions), {seeds} seeds x {episodes} episodes\n")
  print(markdown_table(["task", "HL", "LL", "hdt", "paper (full budget)"],
                       [["waypoint", "PM HL", "PM LL", mean_std(own["return_mean"], own["return_std"]), "1021 ± 43"]]))
  rows, table = [], []
  available = set(zoo.entry_names())
  for task, label, hl_run, ll_run, random, paper in _quickstart_transfers():
    if ll_run[len(zoo.PREFIX):] not in available:
      continue  # that LL is not in this checkout's zoo
    if hl_run.startswith(zoo.PREFIX) and not random:
      label = f"{label} ({hl_run})"
    policy = compose(high.run_dir if hl_run == "here" else hl_run, ll_run, box="scale")
    ev = evaluate(random_actions(policy) if random else policy, task, episodes=episodes)
    metric = ev["metric"]  # the task's headline (Task.headline)
    value = mean_std(ev[f"{metric}_mean"], ev[f"{metric}_std"])
    rows.append([task, metric, label, ll_run, value, paper])
    table.append(dict(task=task, metric=metric, high=label, low=ll_run, mean=ev[f"{metric}_mean"],
                      std=ev[f"{metric}_std"], episodes=episodes, seeds=len(ev["seeds"]), paper=paper))
  print(f"\n2. Transfer, HL of agent A over the LL of agent B (zoo policies trained at paper-scale budgets "
        f"here, see `hdt zoo`), {episodes} episodes per seed:\n")
  print(markdown_table(["task", "metric", "HL", "LL", "hdt", "paper"], rows))
  atomic.write_text(root / "quickstart.json", json.dumps(dict(own=dict(return_mean=own["return_mean"],
                                                                return_std=own["return_std"]),
                                                        transfer=table), indent=1))
  rep = run_report(high.run_dir)
  from hdt.report import video_path
  video = video_path(rep.parent)
  if video is not None:
    print(f"\nvideo of the PM hierarchy on Waypoint: {video}")
  print(f"\nplots and report: {rep.parent}\nrun directories: {low.run_dir} {high.run_dir}")
  return 0


def _render_parser(sub, fmt) -> None:
  r = sub.add_parser("render", help="video (MP4, or GIF) of a policy's rollout: an LL, an HL over an LL, or a zoo entry",
                     formatter_class=fmt)
  r.add_argument("--policy", default=None, help="a flat policy run or zoo:NAME (an LL on reach, or Full)")
  r.add_argument("--high", default=None, help="an HL run or zoo:NAME, driving --low")
  r.add_argument("--low", default=None, help="the LL run or zoo:NAME under --high")
  r.add_argument("--task", default=None, help="task (default: the policy's own)")
  r.add_argument("--box", choices=("refuse", "scale", "keep"), default="refuse",
                 help="what to do when the HL's and LL's goal boxes differ (as `hdt eval`)")
  r.add_argument("--out", type=Path, required=True, help="the video file: .mp4, or .gif")
  r.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
  r.add_argument("--episodes", type=int, default=1, help="rollouts, one after the other")
  r.add_argument("--max-steps", type=int, default=300, help="LL steps (frames) per rollout at most")
  r.add_argument("--fps", type=float, default=None, help="frames per second (default: real time)")
  r.add_argument("--width", type=int, default=480, help="pixels (even)")
  r.add_argument("--height", type=int, default=360, help="pixels (even)")
  r.add_argument("--seed", type=int, default=0, help="random key of the first rollout")
  r.add_argument("--seed-index", type=int, default=0, help="which trained seed of the policy acts")
  r.add_argument("--shadows", action="store_true", help="render shadows (slow in software OpenGL)")
  r.add_argument("--backend", choices=("auto", "native", "mjx"), default="auto")
  r.add_argument("--quiet", action="store_true", help="print only the file written")


def cmd_render(args) -> int:
  """A video of a policy (hdt.render): headless MuJoCo rendering of hdt's own rollouts."""
  from hdt import render
  if args.policy is None and (args.high is None or args.low is None):
    raise CLIError("hdt render needs --policy RUN, or --high RUN and --low RUN (run directories or zoo:NAME)")
  try:
    render.check_out(args.out, args.overwrite)
    cfg = render.RenderConfig(width=args.width, height=args.height, fps=args.fps, max_steps=args.max_steps,
                              episodes=args.episodes, key=args.seed, seed_index=args.seed_index,
                              shadows=args.shadows, backend=args.backend).check()
  except ValueError as e:
    raise CLIError(str(e)) from None
  try:
    if not args.quiet:
      print(f"rendering with MUJOCO_GL={render.gl_backend()}", flush=True)
    path = render.render(render.load(args.policy, args.high, args.low, box=args.box), args.out, args.task, cfg,
                         overwrite=args.overwrite)
  except render.RenderError as e:
    print(f"hdt: error: {_one_line(e)}", file=sys.stderr, flush=True)
    return 1
  print(f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB)")
  return 0


COMMANDS = {"train": cmd_train, "align": cmd_align, "finetune": cmd_finetune, "eval": cmd_eval,
            "sweep": cmd_sweep, "reproduce": cmd_reproduce, "report": cmd_report, "quickstart": cmd_quickstart,
            "zoo": cmd_zoo, "render": cmd_render}
# What several processes run together with HDT_DISTRIBUTED=1 (jax.distributed): each trains its share
# of the seeds (grid points) and process 0 writes; every other command runs as one process.
DISTRIBUTED = ("train", "align", "finetune", "sweep")


def _one_line(e: BaseException) -> str:
  return " ".join(str(e).split()) or type(e).__name__


def _last_run():
  """The run directory this process claimed last, if hdt's modules got that far."""
  rundir = sys.modules.get("hdt.transfer.rundir")
  return rundir.LAST_CLAIMED[-1] if rundir is not None and rundir.LAST_CLAIMED else None


def _resume_hint() -> str:
  """Where the run stands and how to continue it (after Ctrl-C or a failed write)."""
  run = _last_run()
  ckpt = sys.modules.get("hdt.transfer.checkpoint")
  if run is not None and ckpt is not None and ckpt.has_state(run):
    try:
      info = ckpt.load_state_info(run)
    except (ValueError, OSError):
      info = {}
    steps, meta = info.get("env_steps", "?"), info.get("meta") or {}
    # a run whose schedules do not scale with the budget (Stage.extendable) can also end at its last save;
    # a state saved before it was recorded: not offered for align and finetune runs (KL finetuning and
    # alignment have such schedules; plain finetuning has none, but meta.json alone cannot tell)
    extendable = info.get("extendable", not {"aligned_to", "finetuned_from"} & set(meta))
    end = (f", or with --resume --total-env-steps {steps} to end it there"
           if isinstance(steps, int) and steps > 0 and extendable is True else "")
    return (f"{run} keeps its last saved training state ({steps} env steps): run the same command with --resume to "
            f"continue{end}")
  rundir = sys.modules.get("hdt.transfer.rundir")
  if run is not None and run.exists() and rundir.owner_kind(run) == "run":
    return f"{run} holds no saved training state yet: run the same command with --overwrite to start again"
  return "nothing was written"


def _interrupted() -> str:
  """The Ctrl-C message."""
  hint = _resume_hint()
  return f"interrupted; {hint}" if hint != "nothing was written" else "interrupted; nothing was written"


def _os_error(e: OSError) -> str:
  """One line for a failed read or write: what, where, and the fix."""
  import errno
  where = e.filename or "the file system"
  hint = _resume_hint()
  elsewhere = "" if "--resume" in hint else " or pass an --out on another disk"
  fix = {errno.ENOSPC: f"no space left on the device of {where}: free space there{elsewhere}",
         errno.EDQUOT: f"disk quota exceeded writing {where}: free space{elsewhere}",
         errno.EROFS: f"{where} is on a read-only file system: pass an --out you can write to",
         errno.EACCES: f"permission denied: {where}: pass a path you can write to (or read, for an input)",
         errno.EPERM: f"operation not permitted: {where}: pass a path you own"}.get(e.errno)
  text = fix or f"{e.strerror or e} ({where}); check the path and free space"
  return text + ("" if hint == "nothing was written" else f"; {hint}")


def _message(e: BaseException) -> tuple[str, int]:
  """(the one line printed for ``e``, exit status)."""
  rundir = sys.modules.get("hdt.transfer.rundir")
  ckpt = sys.modules.get("hdt.transfer.checkpoint")
  sharding = sys.modules.get("hdt.agents.sharding")
  if isinstance(e, CLIError) or (rundir is not None and isinstance(e, rundir.RunDirError)):
    return f"error: {_one_line(e)}", 2
  if sharding is not None and isinstance(e, sharding.OtherProcessFailed):
    return f"hdt: error: {_one_line(e)}", 1
  if isinstance(e, (FileNotFoundError, ValueError, FloatingPointError)) or (
      ckpt is not None and isinstance(e, ckpt.CheckpointError)):
    return f"hdt: error: {_one_line(e)}", 1
  if isinstance(e, MemoryError) or (type(e).__name__ == "JaxRuntimeError" and "RESOURCE_EXHAUSTED" in str(e)):
    return "hdt: error: out of memory; lower --seeds, --episodes, --buffer-size, --num-envs or --hidden-sizes", 1
  if isinstance(e, OSError):
    return f"hdt: error: {_os_error(e)}", 1
  return (f"hdt: internal error: {type(e).__name__}: {_one_line(e)} (please report it; HDT_DEBUG=1 shows "
          f"the traceback)"), 1


def _run(argv) -> int:
  from hdt import interrupt
  with interrupt.deferred():  # a KeyboardInterrupt inside an extension module's import can crash it later
    _import_hdt()
    import hdt.transfer.evaluate  # noqa: F401 (with pipeline, checkpoint, zoo: what every command loads)
    from hdt.agents.sharding import initialize_distributed, use_cpu_cores, writes
    from hdt.cache import enable_compile_cache
  args = build_parser().parse_args(argv)
  use_cpu_cores()  # vmapped seeds on all CPU cores (before any JAX operation)
  several = args.cmd in DISTRIBUTED and initialize_distributed()  # only with HDT_DISTRIBUTED=1
  enable_compile_cache()  # a re-run of the same configuration loads its programs
  with contextlib.ExitStack() as stack:
    if several and not writes():  # process 0 reports; the others' errors still go to stderr
      stack.enter_context(contextlib.redirect_stdout(stack.enter_context(open(os.devnull, "w"))))
    code = COMMANDS[args.cmd](args)
  interrupt.raise_if_interrupted()  # a Ctrl-C that a library swallowed is not lost
  return code


def _exit_quietly(code: int) -> None:
  """Ends a failed command without the tracebacks that orbax's and asyncio's threads and finalizers
  print while the interpreter shuts down: the one line was already printed."""
  import logging
  import threading
  sys.unraisablehook = lambda *a: None
  threading.excepthook = lambda *a: None
  for name in ("absl", "asyncio"):
    logging.getLogger(name).setLevel(logging.CRITICAL + 1)
  sys.stdout.flush()
  sys.stderr.flush()
  os._exit(code)


def _is_noise(e: BaseException) -> bool:
  """What orbax's asyncio writers still report from threads and C callbacks after a failed write
  (the command's own one line says what failed)."""
  return isinstance(e, RuntimeError) and str(e) == "Event loop is closed"


def _quiet_library_noise() -> None:
  import logging
  import threading
  logging.getLogger("absl").setLevel(logging.CRITICAL)  # orbax logs each failed writer thread with a traceback
  if not getattr(sys.excepthook, "hdt", False):  # C callbacks report through the unraisable hook
    shown, in_thread, unraisable = sys.excepthook, threading.excepthook, sys.unraisablehook
    sys.excepthook = lambda kind, e, tb: None if _is_noise(e) else shown(kind, e, tb)
    threading.excepthook = lambda a: None if _is_noise(a.exc_value) else in_thread(a)
    sys.unraisablehook = lambda u: None if _is_noise(u.exc_value) else unraisable(u)
    sys.excepthook.hdt = True


def main(argv=None) -> int:
  """The ``hdt`` command; ``argv`` None: ``sys.argv``, and the process exits quietly on failure."""
  from hdt import interrupt
  interrupt.catch(bool(_EARLY_SIGINT))  # before the seconds of importing JAX: Ctrl-C is handled from the first instant
  _quiet_library_noise()
  try:
    try:
      interrupt.raise_if_interrupted()
      code = _run(argv)
    except KeyboardInterrupt:
      print(f"hdt: {_interrupted()}", file=sys.stderr, flush=True)
      code = interrupt.exit_code()
    except Exception as e:
      if interrupt.pressed():  # Ctrl-C while a module loaded makes its import fail with another error
        print(f"hdt: {_interrupted()}", file=sys.stderr, flush=True)
        return _exit(argv, 130)
      text, code = _message(e)
      if os.environ.get("HDT_DEBUG") and text.startswith("hdt: internal error"):  # a bug: show where
        raise
      print(text, file=sys.stderr, flush=True)
  except KeyboardInterrupt:  # a second Ctrl-C while the first was reported
    code = 130
  return _exit(argv, code)


def _exit(argv, code: int) -> int:
  if argv is None and code != 0:
    _exit_quietly(code)
  return code


if __name__ == "__main__":
  sys.exit(main())
