"""A paper table or figure as data, and :func:`reproduce`.

A :class:`Table` is a function of the preset giving its :class:`Part` s (one matrix, group of bars or
panel of curves each), whose :class:`Cell` s name the runs they evaluate as recipes
(:mod:`hdt.paper.runs`). :func:`reproduce` resolves every run once (zoo entry, run in ``out``, or
trained there), evaluates each cell, and writes ``NAME_PRESET.md``, ``.json`` and ``.png`` into
``out``. An evaluation is kept in the JSON with the content hash of each run it used, and reused
while they are unchanged, so a second invocation neither trains nor evaluates again.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import json
import math
import re
import shlex
import sys
import time
from pathlib import Path
from types import MappingProxyType
from typing import Callable, Mapping

from hdt import atomic
from hdt.envs.robot import agent_spec
from hdt.envs.tasks import get_task
from hdt.paper.runs import PRESETS, Finetune, Full, High, Low, Options, Preset, Runs, describe
from hdt.transfer import configs
from hdt.transfer import checkpoint as ckpt
from hdt.transfer import names, rundir
from hdt.transfer.evaluate import compose, evaluate, load_policy
from hdt.version import __version__

KINDS = ("matrix", "bars", "curves")  # drawn as a heatmap, grouped bars, learning curves


@dataclasses.dataclass(frozen=True)
class Cell:
  """One number of a table: the HL ``high`` over the LL ``low``, or the flat policy ``flat``, evaluated
  on its part's task; ``paper``: the paper's number ("603 ± 34") or what it says; ``curve``: draw the
  learning curve of its trained run (``high`` or ``flat``)."""

  row: str
  col: str
  high: High | Finetune | None = None
  low: Low | None = None
  flat: Full | None = None
  paper: str = ""
  curve: bool = False

  def __post_init__(self):
    if (self.flat is None) == (self.high is None or self.low is None):
      raise ValueError(f"cell {self.row}/{self.col}: give high= and low=, or flat=")

  @property
  def runs(self) -> dict:
    return {k: v for k, v in (("high", self.high), ("low", self.low), ("flat", self.flat)) if v is not None}


@dataclasses.dataclass(frozen=True)
class Part:
  """Cells evaluated on one task with the same evaluation ``options``, shown as one table and one
  panel of the figure (``kind``: one of KINDS); ``corner`` heads its rows."""

  name: str
  title: str
  task: str
  cells: tuple[Cell, ...]
  options: Options = ()
  kind: str = "matrix"
  corner: str = "LL \\ HL"

  def __post_init__(self):
    if self.kind not in KINDS:
      raise ValueError(f"part {self.name}: kind={self.kind!r}, use one of {', '.join(KINDS)}")

  @property
  def rows(self) -> list[str]:
    return list(dict.fromkeys(c.row for c in self.cells))

  @property
  def cols(self) -> list[str]:
    return list(dict.fromkeys(c.col for c in self.cells))

  def cell_id(self, cell: Cell) -> str:
    return f"{self.name}/{_slug(cell.row)}/{_slug(cell.col)}"


@dataclasses.dataclass(frozen=True)
class Table:
  """A paper table or figure: ``parts(preset)`` builds its parts at a :class:`Preset`."""

  name: str
  title: str
  parts: Callable[[Preset], tuple[Part, ...]]
  presets: Mapping[str, Preset] = dataclasses.field(default_factory=lambda: MappingProxyType(PRESETS))
  note: str = ""  # what the reader should know about hdt's cells (one paragraph)


METHODS = {"finetune_kl": "finetune KL", "finetune": "finetune", "scratch": "HL scratch", "full": "Full"}


def finetune_part(name: str, title: str, a_high: High, b_low: Low, task: str, pr: Preset, options: Options = (),
                  methods=tuple(METHODS), paper: Mapping[str, str] = MappingProxyType({}),
                  zoo: Mapping[str, str] = MappingProxyType({})) -> Part:
  """A's HL transferred to B's LL on ``task`` (task ``options`` in training and evaluation), then trained
  on B by each of ``methods`` for the same env steps of B: KL finetuning at the task's weight and
  learning rate, plain finetuning, B's HL from scratch (``pr.ft`` HL decisions each, None: the task's
  budget) and Full (flat SAC for those decisions times B's k); rows are methods, each with its curve,
  and the zero-shot level. ``paper`` / ``zoo``: per method (and "zero_shot") the paper's words and the
  zoo entry standing in for its run."""
  steps = pr.ft or configs.hl_budget(task)
  recipes = {"finetune_kl": Finetune(a_high, b_low, task, True, options, zoo=zoo.get("finetune_kl")),
             "finetune": Finetune(a_high, b_low, task, False, options, zoo=zoo.get("finetune")),
             "scratch": High(task, b_low, options, steps=pr.ft, zoo=zoo.get("scratch")),
             "full": Full(b_low.agent, task, options, steps=steps * agent_spec(b_low.agent).k, zoo=zoo.get("full"))}
  cells = [Cell("zero-shot", "final", high=a_high, low=b_low, paper=paper.get("zero_shot", ""))]
  cells += [Cell(METHODS[m], "final", flat=recipes[m], paper=paper.get(m, ""), curve=True) if m == "full" else
            Cell(METHODS[m], "final", high=recipes[m], low=b_low, paper=paper.get(m, ""), curve=True) for m in methods]
  return Part(name, title, task, tuple(cells), options=options, kind="curves", corner="method")


@dataclasses.dataclass(frozen=True)
class Reproduced:
  """What :func:`reproduce` made: the table's JSON (None for a dry run), its Markdown, the files written."""

  result: dict | None
  markdown: str
  files: tuple[Path, ...]


def _slug(text: str) -> str:
  return re.sub(r"[^a-z0-9]+", "_", text.lower()).strip("_")


def _paper_number(text: str) -> float | None:
  m = re.match(r"\s*(-?\d*\.?\d+)", text or "")
  return float(m.group(1)) if m else None


def fmt_cell(entry: dict) -> str:
  """hdt's number of a cell entry (mean ± std over seeds), or why it has none."""
  if entry.get("status") != "done":
    return {"not selected": "—"}.get(entry.get("status"), entry.get("status", "—"))
  f = "{:.2f}" if entry["metric"] == "success" else "{:.0f}"
  return f"{f.format(entry['mean'])} ± {f.format(entry['std'])}"


def _key(part: Part, sources: dict, episodes: int) -> dict:
  """What an evaluation depends on: task, options, episodes, and each run with its content hash."""
  runs = {role: dict(path=s.path, sha256=names.content_hash(s.path)) for role, s in sources.items()}
  return json.loads(json.dumps(dict(task=part.task, options=dict(part.options), episodes=episodes, runs=runs)))


def _still_valid(entry: dict | None) -> bool:
  """Whether a previous cell entry's runs are unchanged on disk."""
  if not entry or entry.get("status") != "done":
    return False
  try:
    return all(r["sha256"] in names.hash_aliases(r["path"], None) for r in entry["key"]["runs"].values())
  except (ValueError, OSError, KeyError, TypeError):
    return False


def _evaluate(part: Part, cell: Cell, sources: dict, episodes: int) -> dict:
  if cell.flat is not None:
    policy = load_policy(sources["flat"].path)
  else:
    policy = compose(sources["high"].path, sources["low"].path)
  ev = evaluate(policy, part.task, episodes=episodes, **dict(part.options))
  metric = ev["metric"]
  return dict(metric=metric, mean=ev[f"{metric}_mean"], std=ev[f"{metric}_std"],
              per_seed=[float(x) for x in ev["per_seed"][metric]], episodes=episodes, params=ev["params"],
              low_params=ev.get("low_params"))


def _curve(part: Part, cell: Cell, sources: dict) -> dict | None:
  """The learning curve of the cell's trained run: x in env steps of its robot (an HL's decisions
  times its k), y per seed; None for a run without them (a zoo entry exported before entries kept
  their curves.csv)."""
  from hdt.report import read_eval_curves  # reports and plots only where a figure is drawn
  source = sources["flat" if cell.flat is not None else "high"]
  path = Path(names.resolve(source.path))
  try:
    x, y = read_eval_curves(path)[get_task(part.task).headline_column]
  except FileNotFoundError:
    return None
  k = 1 if cell.flat is not None else int(ckpt.load_meta(path)["k"])
  return dict(x=[float(v) * k for v in x], y=[[float(v) for v in row] for row in y])


def _previous(path: Path) -> dict:
  """The cells of the table's earlier JSON in ``out`` by id ({} if there is none or it is unreadable)."""
  try:
    old = json.loads(path.read_text())
    return {c["id"]: c for p in old["parts"] for c in p["cells"]}
  except (OSError, ValueError, KeyError, TypeError):
    return {}


def _selector(only, ids: list[str]):
  patterns = [p.strip().strip("/") for p in only or ()]
  match = lambda i, p: fnmatch.fnmatch(i, p) or fnmatch.fnmatch(i, p + "/*")
  unknown = [p for p in patterns if not any(match(i, p) for i in ids)]
  if unknown:
    raise ValueError(f"--only {unknown[0]!r} selects no cell; cells: {', '.join(ids)}")
  return lambda i: not patterns or any(match(i, p) for p in patterns)


def legacy(name: str) -> Callable[[Path], bool]:
  """Whether a directory without hdt's marker is table ``name``'s, written before the marker existed:
  hdt runs and the table's own files only (:func:`hdt.transfer.rundir.holds_only_runs`)."""
  return lambda path: rundir.holds_only_runs(path, lambda entry: entry.startswith(f"{name}_"))


def command(name: str, preset: str, out: Path, seeds=None, only=(), max_env_steps="preset") -> str:
  """The ``hdt reproduce`` command of these arguments."""
  limit = [] if max_env_steps == "preset" else [
      "--max-env-steps", "all" if max_env_steps is None else str(max_env_steps)]
  return shlex.join(["hdt", "reproduce", name, "--preset", preset, "--out", str(out),
                     *(["--seeds", str(seeds)] if seeds is not None else []),
                     *(a for p in only or () for a in ("--only", p)), *limit])


def reproduce(table: Table, preset: str = "cpu", out=None, *, seeds: int | None = None, only=(),
              max_env_steps="preset", quiet: bool = False, dry_run: bool = False) -> Reproduced:
  """Reproduces ``table`` at ``preset`` into ``out`` (default ``runs/NAME-PRESET``): the cells
  selected by ``only`` (patterns of cell ids such as ``waypoint/pm/*``, or part names; default all),
  trained with ``seeds`` (default the preset's); a missing run costing more than ``max_env_steps``
  env steps ("preset": the preset's limit; None: none) is reported as not run with its command.
  ``dry_run``: only the plan (the returned Markdown), nothing trained or written."""
  if preset not in table.presets:
    raise ValueError(f"{table.name} has no preset {preset!r}; presets: {', '.join(table.presets)}")
  pr = table.presets[preset]
  pr = dataclasses.replace(pr, seeds=pr.seeds if seeds is None else seeds,
                           max_env_steps=pr.max_env_steps if max_env_steps == "preset" else max_env_steps)
  out = Path(out) if out is not None else Path("runs") / f"{table.name}-{preset}"
  parts = table.parts(pr)
  ids = [p.cell_id(c) for p in parts for c in p.cells]
  if len(set(ids)) < len(ids):
    raise ValueError(f"{table.name}: two cells share the id {next(i for i in ids if ids.count(i) > 1)}")
  selected = _selector(only, ids)
  runs = Runs(out, preset, pr, quiet)
  previous = _previous(out / f"{table.name}_{preset}.json")
  for part in parts:
    for cell in part.cells:
      cid = part.cell_id(cell)
      if selected(cid) or _still_valid(previous.get(cid)):  # a kept number lists its runs too
        for r in cell.runs.values():
          runs.plan(r)
  plan = _plan_markdown(runs)
  if dry_run:
    return Reproduced(None, plan, ())
  if not quiet:
    print(plan, file=sys.stderr, flush=True)
  stem = f"{table.name}_{preset}"
  t0 = time.time()
  with rundir.claim(out, "experiment", reuse=True, legacy=legacy(table.name)):
    evaluated: dict[str, dict] = {}  # one evaluation per (task, options, runs) in this invocation
    result = dict(table=table.name, title=table.title, preset=preset, note=table.note, hdt_version=__version__,
                  command=command(table.name, preset, out, seeds, only, max_env_steps),
                  preset_settings=dataclasses.asdict(pr), parts=[], runs={})
    for part in parts:
      entries = []
      result["parts"].append(dict(name=part.name, title=part.title, kind=part.kind, task=part.task,
                                  options=dict(part.options), metric=get_task(part.task).headline,
                                  corner=part.corner, rows=part.rows, cols=part.cols, cells=entries))
      for cell in part.cells:
        entries.append(_cell(part, cell, selected, runs, pr.episodes, previous, evaluated, quiet))
        _write_json(out / f"{stem}.json", result, runs)  # a killed table keeps its evaluated cells
    result["minutes"] = (time.time() - t0) / 60
    result["runs"] = _run_entries(runs)
    atomic.write_json(out / f"{stem}.json", result)
    text = markdown(result)
    atomic.write_text(out / f"{stem}.md", text)
    png = plot(result, out / f"{stem}.png")
  return Reproduced(result, text, (out / f"{stem}.md", out / f"{stem}.json", png))


def _cell(part, cell, selected, runs: Runs, episodes: int, previous: dict, evaluated: dict, quiet: bool) -> dict:
  cid = part.cell_id(cell)
  entry = dict(id=cid, row=cell.row, col=cell.col, paper=cell.paper, runs={k: r.name for k, r in cell.runs.items()})
  if not selected(cid):
    old = previous.get(cid)
    return dict(old, paper=cell.paper) if _still_valid(old) else dict(entry, status="not selected")
  sources = {role: runs.get(r) for role, r in cell.runs.items()}
  missing = [s for s in sources.values() if not s.usable]
  if missing:
    return dict(entry, status="not run", reason="; ".join(f"{s.recipe.name}: {s.status}, {s.reason}" for s in missing))
  try:
    key = _key(part, sources, episodes)
    old = previous.get(cid)
    seen = json.dumps(key, sort_keys=True)
    if old and old.get("status") == "done" and old.get("key") == key:
      evaluated[seen] = {k: old[k] for k in ("metric", "mean", "std", "per_seed", "episodes", "params", "low_params")}
    if seen not in evaluated:
      evaluated[seen] = _evaluate(part, cell, sources, episodes)
    numbers = evaluated[seen]
    curve = _curve(part, cell, sources) if cell.curve else None
  except (ValueError, OSError) as e:  # e.g. goal boxes that differ, a changed checkpoint
    return dict(entry, status="failed", reason=" ".join(str(e).split()))
  entry = dict(entry, status="done", **numbers, key=key, **({"curve": curve} if cell.curve else {}))
  if not quiet:
    print(f"{cid}: {fmt_cell(entry)}" + (f" (paper {cell.paper})" if cell.paper else ""), file=sys.stderr, flush=True)
  return entry


def _run_entries(runs: Runs) -> dict:
  out = {}
  for recipe, s in runs.sources().items():
    out[recipe.name] = dict(what=recipe.label, status=s.status, path=s.path, reason=s.reason, command=s.command,
                            **describe(s))
  return out


def _write_json(path: Path, result: dict, runs: Runs) -> None:
  atomic.write_json(path, dict(result, runs=_run_entries(runs)))


def _table_rows(part: dict) -> list[str]:
  cells = {(c["row"], c["col"]): c for c in part["cells"]}
  lines = ["| " + " | ".join([part["corner"], *part["cols"]]) + " |", "|" + "---|" * (len(part["cols"]) + 1)]
  for r in part["rows"]:
    texts = []
    for c in part["cols"]:
      e = cells.get((r, c))
      texts.append("" if e is None else fmt_cell(e) + (f" ({e['paper']})" if e.get("paper") else ""))
    lines.append("| " + " | ".join([r, *texts]) + " |")
  return lines


def markdown(result: dict) -> str:
  """The table as Markdown: each part (hdt, the paper's number in parentheses), its runs, and the
  command of every run that was not run."""
  s = result["preset_settings"]
  lines = [f"# {result['title']} (preset {result['preset']})", "",
           f"hdt: mean ± std over seeds of {s['episodes']} deterministic episodes per seed; the paper's number in "
           f"parentheses. Seeds of the runs trained here: {s['seeds']} (of the others: under Runs)."]
  if result.get("note"):
    lines += ["", result["note"]]
  for part in result["parts"]:
    lines += ["", f"## {part['title']}", "", *_table_rows(part)]
  runs = result.get("runs", {})
  lines += ["", "## Runs", "", "| run | what | source | budget | seeds |", "|---|---|---|---|---|"]
  for name, r in runs.items():
    source = {"zoo": r["path"], "reuse": f"in {r['path']} (kept cells)", "not run": f"not run ({r['reason']})",
              "failed": f"failed ({r['reason']})"}.get(r["status"], f"{r['status']}: {r['path']}")
    lines.append(f"| {name} | {r['what']} | {source} | {r.get('budget', '—')} | {r.get('seeds', '—')} |")
  todo = {n: r for n, r in runs.items() if r["status"] in ("not run", "failed") and r["command"]}
  if todo:
    lines += ["", "## Not run", "", "Train these (in this order; each continues with `--resume` if stopped), then run "
              "the command below again:", ""]
    lines += [f"- `{n}` ({r['reason']}): `{r['command']}`" for n, r in todo.items()]
  failed = [c for p in result["parts"] for c in p["cells"] if c["status"] == "failed"]
  lines += [f"- cell `{c['id']}` failed: {c['reason']}" for c in failed]
  lines += ["", f"Command: `{result['command']}`"]
  return "\n".join(lines) + "\n"


def _plan_markdown(runs: Runs) -> str:
  lines = ["| run | plan | env steps to train | |", "|---|---|---|---|"]
  for r, s in runs.sources().items():
    lines.append(f"| {r.name} | {s.status} | {s.env_steps:,} | {s.reason or (s.path if s.status == 'zoo' else '')} |")
  return "Plan:\n" + "\n".join(lines)


def plot(result: dict, path: Path) -> Path:
  """One panel per part: a heatmap of a matrix, grouped bars, or learning curves with the zero-shot
  level dashed; a cell without a number is shown as not run."""
  from hdt import plots  # matplotlib only where a figure is drawn
  panels = []
  for part in result["parts"]:
    done = [c for c in part["cells"] if c["status"] == "done"]
    metric = part["metric"]
    if part["kind"] == "matrix":
      nan = (math.nan, math.nan, metric)  # drawn as not run
      cells = {(c["row"], c["col"]): (c["mean"], c["std"], metric) if c["status"] == "done" else nan
               for c in part["cells"]}
      matrix = dict(task=part["task"], rows=part["rows"], cols=part["cols"], cells=cells,
                    paper={(c["row"], c["col"]): c["paper"] for c in part["cells"]})
      panels.append(("heatmap", dict(matrix=matrix, title=part["title"], xlabel="HL", ylabel="LL")))
    elif part["kind"] == "bars":
      bars = [dict(group=c["row"], method=c["col"], mean=c["mean"], std=c["std"], paper=_paper_number(c["paper"]))
              for c in done]
      panels.append(("bars", dict(bars=bars, title=part["title"], ylabel=metric)))
    else:
      series = {c["row"]: (c["curve"]["x"], c["curve"]["y"]) for c in done if c.get("curve")}
      hline = {c["row"]: c["mean"] for c in done if "curve" not in c}
      panels.append(("curves", dict(series=series, hline=hline, title=part["title"], ylabel=metric,
                                    xlabel="env steps of B", ylim=(-0.02, 1.02) if metric == "success" else None)))
  return plots.panels(panels, path, title=f"{result['title']} (preset {result['preset']})")
