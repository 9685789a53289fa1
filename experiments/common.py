"""Shared code of the experiment modules (table1, table2, table3, fig5, fig6).

Every experiment module has the same interface, used by ``hdt reproduce NAME --preset P``::

    PRESETS: dict[str, dict]            # "smoke", "cpu", "paper"
    run(preset="cpu", out=Path("runs/NAME"), seeds=None, quiet=False) -> dict
    markdown(result) -> str
    main(argv=None) -> int

An experiment's preset names what is its own (seeds, evaluation episodes, rows, ``ft`` = HL
decisions of each finetuning method, ``evals`` = evaluations over such a run); every SAC config and
budget comes from the one table, :func:`hdt.transfer.configs.config` at the configs preset ``sac``
(default: the experiment preset's name), exactly as ``hdt train --preset`` builds it.

Run directories are reused when their config, seeds and key metadata match (so a killed long run
can be restarted and only redoes what is missing); delete a run directory to retrain it.
"""

from __future__ import annotations

import argparse
import csv
import io
import dataclasses
import json
import os
import shutil
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

# Compiled XLA programs are cached across runs (as in tests/conftest.py): re-runs compile nothing.
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", os.path.expanduser("~/.cache/hdt/jax"))
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "1")

from hdt import atomic
from hdt.transfer import checkpoint as ckpt
from hdt.transfer import rundir
from hdt.transfer import configs
from hdt.transfer.evaluate import compose, evaluate, load_policy
from hdt.transfer.align import AlignSpec
from hdt.transfer.card import PolicyCard
from hdt.transfer.finetune import FinetuneSpec, finetune_high
from hdt.transfer.pipeline import train_full, train_high, train_low
from hdt.transfer.runner import RunOptions, RunResult

RESULTS = Path(__file__).resolve().parent / "results"


# -- budgets: the one table (hdt.transfer.configs) ------------------------------------------------
def experiment_preset(presets: dict, name: str) -> dict:
  """Experiment preset ``name`` with ``sac``, the configs preset its SAC configs come from."""
  return {"sac": name} | presets[name]


def low_cfg(agent: str, pr: dict):
  return configs.config("low", pr["sac"], agent=agent)


def _budget(cfg, steps: int | None, pr: dict):
  """``cfg`` with ``steps`` (if given) split into ``pr["evals"]`` evaluation chunks."""
  if steps is None:
    return cfg
  return configs.replace(cfg, total_env_steps=steps,
                         steps_per_chunk=configs.chunk_for(steps, cfg.num_envs, pr.get("evals", 5)))


def high_cfg(task: str, steps: int | None, pr: dict):
  return _budget(configs.config("high", pr["sac"], task=task), steps, pr)


def full_cfg(agent: str, task: str, env_steps: int, pr: dict):
  return _budget(configs.config("full", pr["sac"], agent=agent, task=task), env_steps, pr)


# -- runs, reused when they match -----------------------------------------------------------------
def _json(x):
  return json.loads(json.dumps(x, default=ckpt.jsonable))


def read_history(metrics_csv: Path, seeds: list[int]) -> dict[str, np.ndarray]:
  """The ``eval/...`` part of a run's history, (seeds, evaluations) arrays, from its metrics.csv."""
  with open(metrics_csv, newline="") as f:
    rows = [r for r in csv.DictReader(f) if r["kind"] == "eval"]
  keys = [k for k in rows[0] if k.startswith("eval/")] if rows else []
  per = [[r for r in rows if int(float(r["seed"])) == s] for s in seeds]
  return {k: np.array([[float(r[k]) if r[k] != "" else np.nan for r in p] for p in per]) for k in keys}


def reuse_or_train(run_dir: Path, config, seeds: int, train: Callable[[], RunResult],
                   expect: dict | None = None) -> RunResult:
  """``train()`` unless ``run_dir`` already holds a finished run with this config, these seeds and
  the ``expect``-ed metadata; then that run (params not loaded, eval history from metrics.csv)."""
  run_dir = Path(run_dir)
  try:
    meta = json.loads((run_dir / "meta.json").read_text())
    saved = {k: v for k, v in json.loads((run_dir / "config.json").read_text()).items() if k != "budget_unit"}
    same = (saved == _json(dataclasses.asdict(config))
            and meta.get("seeds") == list(range(seeds))
            and ckpt.list_seeds(run_dir) == list(range(seeds))
            and all(_json(meta.get(k)) == _json(v) for k, v in (expect or {}).items()))
  except (OSError, json.JSONDecodeError):
    same = False
  if same:
    print(f"reusing {run_dir}", file=sys.stderr, flush=True)
    return RunResult(run_dir, None, read_history(run_dir / "metrics.csv", meta["seeds"]),
                     PolicyCard.from_json(meta, run_dir))
  if run_dir.exists():
    rundir.discard(run_dir)  # a stale hdt run with other settings (anything else is refused)
  return train()


def low(agent: str, pr: dict, out: Path, seeds: int, quiet: bool, name: str | None = None,
        imitate: RunResult | None = None, **env_overrides) -> RunResult:
  """B's or A's LL on reach; ``imitate=A's LL run`` aligns it to A with A's discriminator config."""
  cfg = low_cfg(agent, pr)
  name = name or f"{agent}_low" + (f"_aligned_{imitate.card.agent}" if imitate else "")
  kw, expect = dict(env_overrides), {"env_overrides": env_overrides}
  if imitate is not None:
    disc = configs.disc_config(imitate.card.agent)
    kw |= dict(imitate=AlignSpec(imitate.run_dir, disc))
    expect |= {"discriminator": dataclasses.asdict(disc)}
  return reuse_or_train(out / name, cfg, seeds, expect=expect, train=lambda: train_low(
      agent, cfg, options=RunOptions(seeds=seeds, out=out / name, quiet=quiet), **kw))


def high(task: str, low_run: RunResult, pr: dict, out: Path, seeds: int, quiet: bool,
         steps: int | None = None, name: str | None = None, **task_kw) -> RunResult:
  """A's HL on ``task`` over ``low_run``: the preset's HL budget, or ``steps`` HL decisions."""
  task_kw = configs.task_options(pr["sac"], task) | task_kw  # paper: the authors' task setup
  cfg = high_cfg(task, steps, pr)
  name = name or f"{low_run.card.agent}_high_{task}"
  return reuse_or_train(out / name, cfg, seeds, expect={"task_overrides": task_kw}, train=lambda: train_high(
      task, low_run.run_dir, cfg, options=RunOptions(seeds=seeds, out=out / name, quiet=quiet), **task_kw))


def score(ev: dict) -> dict:
  """The table entry of an evaluation: the task's headline metric (``Task.headline``)."""
  metric = ev["metric"]
  return dict(metric=metric, mean=ev[f"{metric}_mean"], std=ev[f"{metric}_std"],
              per_seed=np.asarray(ev["per_seed"][metric]).tolist(), episodes=ev["episodes"])


def eval_hl(high_run: RunResult, low_run: RunResult, task: str, episodes: int, **eval_kw) -> dict:
  """HL of ``high_run`` (its seeds) over the LL of ``low_run`` (paired seed by seed)."""
  return score(evaluate(compose(high_run.run_dir, low_run.run_dir), task, episodes=episodes, **eval_kw))


# -- curves ---------------------------------------------------------------------------------------
def curve(res: RunResult, x_scale: int = 1) -> dict[str, np.ndarray]:
  """(seeds, evaluations) arrays ``env_steps`` (x ``x_scale``: k for HL runs), ``success`` (NaN when
  the task has none) and ``return`` from a run's evaluation history."""
  h = res.history
  ret = np.asarray(h["eval/return"], float)
  succ = np.asarray(h.get("eval/success_max", np.full_like(ret, np.nan)), float)
  return {"env_steps": np.asarray(h["eval/env_steps"], float) * x_scale, "success": succ, "return": ret}


def write_curve_csvs(directory: Path, method: str, c: dict[str, np.ndarray]) -> list[str]:
  """``<directory>/<method>_seed<i>.csv`` with columns env_steps, success, return."""
  directory.mkdir(parents=True, exist_ok=True)
  paths = []
  for i in range(c["env_steps"].shape[0]):
    p = directory / f"{method}_seed{i}.csv"
    rows = zip(*(c[k][i] for k in ("env_steps", "success", "return")))
    write_text_atomic(p, "env_steps,success,return\n" + "".join(f"{x:g},{s:g},{r:g}\n" for x, s, r in rows))
    paths.append(str(p))
  return paths


# -- results --------------------------------------------------------------------------------------
def write_text_atomic(path: Path, text: str) -> None:
  atomic.write_text(atomic.make_dirs(Path(path).parent) / Path(path).name, text)


def write_csv_atomic(path: Path, fieldnames, rows) -> None:
  """``rows`` (dicts) as a CSV with header ``fieldnames``, written atomically."""
  text = io.StringIO()
  w = csv.DictWriter(text, fieldnames=list(fieldnames))
  w.writeheader()
  w.writerows(rows)
  write_text_atomic(path, text.getvalue())


def write_result(name: str, preset: str, result: dict) -> Path:
  """``experiments/results/<name>_<preset>.json``, written atomically (keys in insertion order)."""
  path = RESULTS / f"{name}_{preset}.json"
  write_text_atomic(path, json.dumps(result, indent=1, default=ckpt.jsonable))
  return path


def publish(name: str, preset: str, out: Path, text: str) -> list[Path]:
  """Writes the table of ``name`` at ``preset`` (``.md`` from ``text``, ``.json``) and its figures
  (``.png``, per-seed curve CSVs) into ``out``, next to the runs; the JSON and figures are also kept
  in experiments/results/ (the record RESULTS.md links to). Returns the paths written to ``out``."""
  out = Path(out)
  stem = f"{name}_{preset}"
  md = out / f"{stem}.md"
  write_text_atomic(md, text.rstrip() + "\n")
  written = [md]
  for src in [*sorted(RESULTS.glob(f"{stem}.*")), RESULTS / stem]:
    if src.is_dir():
      shutil.copytree(src, out / src.name, dirs_exist_ok=True)
    elif src.is_file():
      shutil.copy2(src, out / src.name)
    else:
      continue
    written.append(out / src.name)
  return written


def command(name: str, preset: str) -> str:
  return f"hdt reproduce {name} --preset {preset}  (or: PYTHONPATH=. python experiments/{name}.py --preset {preset})"


def cell(r: dict | None) -> str:
  """``mean ± std`` of a result entry, with 2 significant digits for success rates."""
  if not r:
    return "—"
  f = "{:.2f}" if r.get("metric", "success") == "success" else "{:.0f}"
  return f"{f.format(r['mean'])} ± {f.format(r['std'])}"


def timed(minutes: dict, key: str, fn: Callable[[], Any]) -> Any:
  t0 = time.time()
  out = fn()
  minutes[key] = minutes.get(key, 0.0) + (time.time() - t0) / 60
  return out


def claim_out(out: Path, name: str):
  """Claims ``out`` for experiment ``name`` (hdt.transfer.rundir: new, empty, or this experiment's
  own directory, also one written before the marker existed), held while it runs."""
  legacy = lambda path: rundir.holds_only_runs(path, lambda entry: entry.startswith(f"{name}_"))
  return rundir.claim(out, "experiment", reuse=True, legacy=legacy)


def make_main(name: str, presets: dict, run: Callable, markdown: Callable, doc: str | None = None,
              extra: Callable[[argparse.ArgumentParser], None] | None = None) -> Callable:
  """The ``main(argv=None) -> int`` of an experiment module: parse, run, print the Markdown table.
  ``extra(parser)`` may add module-specific options; they are passed to ``run`` by name."""

  def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog=f"experiments/{name}.py", description=doc,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--preset", choices=list(presets), default="cpu")
    p.add_argument("--out", type=Path, default=Path("runs") / name)
    p.add_argument("--seeds", type=int, default=None, help="seeds (default: the preset's)")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    if extra:
      extra(p)
    a = vars(p.parse_args(argv))
    with claim_out(a["out"], name):
      text = markdown(run(**a))
      print(text)
      print("written: " + " ".join(map(str, publish(name, a["preset"], a["out"], text))))
    return 0

  return main


# -- finetuning studies (fig5, fig6, table3) ------------------------------------------------------
# PM A -> ant B studies (fig6, table3). The ant is expensive: at the cpu preset its LL gets 100k of the
# paper's 2.5M env steps (configs.CPU_LOW_STEPS), so these numbers say little about the paper's.
NAV_PM_TO_ANT_PRESETS = {
    "smoke": dict(ft=96, seeds=1, episodes=2, evals=2),
    "cpu": dict(ft=1480, seeds=2, episodes=20, evals=5),
    "paper": dict(ft=None, seeds=5, episodes=100, evals=20),
}
METHODS = {"finetune_kl": "finetune KL", "finetune": "finetune", "scratch": "HL scratch", "full": "Full"}


@dataclasses.dataclass(frozen=True)
class FinetuneStudy:
  """A's HL transferred to B's LL on ``task``, then trained further on B by each of ``methods``:
  ``finetune_kl`` (``finetune_high`` at the task's KL weight and lr, :func:`configs.finetune_params`),
  ``finetune`` (kl_weight=0), ``scratch`` (``train_high`` on B's LL) and ``full`` (flat SAC on B)."""

  name: str  # experiment name: results/<name>_<preset>.json, .png and the CSV directory
  a: str  # A's agent
  b: str  # B's agent
  task: str
  methods: tuple[str, ...] = tuple(METHODS)
  b_low: tuple[tuple[str, Any], ...] = ()  # B's LL pretraining options (e.g. terrain="steps")
  task_kw: tuple[tuple[str, Any], ...] = ()  # task options for training and evaluation
  title: str = ""


def finetune_study(st: FinetuneStudy, preset: str, pr: dict, out: Path, seeds: int,
                   quiet: bool) -> dict:
  """Trains A's LL and HL and B's LL, evaluates zero-shot, runs every method for the same number
  of B's env samples (HL steps x k for hierarchical methods, env steps for Full), writes one CSV per
  method and seed plus a PNG of mean ± std curves, and returns the result dict (final evaluations
  with ``episodes`` deterministic episodes per seed)."""
  task, minutes = st.task, {}
  tkw = configs.task_options(pr["sac"], task) | dict(st.task_kw)
  a_low = timed(minutes, "A low", lambda: low(st.a, pr, out, seeds, quiet))
  a_high = timed(minutes, "A high", lambda: high(task, a_low, pr, out, seeds, quiet, **tkw))
  b_low = timed(minutes, "B low", lambda: low(st.b, pr, out, seeds, quiet, **dict(st.b_low)))
  k = b_low.card.k
  zero = eval_hl(a_high, b_low, task, pr["episodes"], **tkw)
  hp = configs.finetune_params(task)
  ft_cfg = configs.replace(high_cfg(task, pr["ft"] or configs.hl_budget(task), pr), actor_lr=hp["lr"],
                           critic_lr=hp["lr"], alpha_lr=hp["lr"])

  def finetuned(kl):
    name = f"{st.b}_ft{'_kl' if kl else ''}_{task}"
    return reuse_or_train(out / name, ft_cfg, seeds, expect={"kl_weight": kl, "task_overrides": tkw},
                          train=lambda: finetune_high(a_high.run_dir, b_low.run_dir, task, ft_cfg,
                                                      spec=FinetuneSpec(kl_weight=kl),
                                                      options=RunOptions(seeds=seeds, out=out / name, quiet=quiet),
                                                      **tkw))

  def full():
    cfg = full_cfg(st.b, task, ft_cfg.total_env_steps * k, pr)  # as many B samples as the HL methods
    name = f"{st.b}_full_{task}"
    return reuse_or_train(out / name, cfg, seeds, expect={"env_overrides": tkw}, train=lambda: train_full(
        st.b, task, cfg, options=RunOptions(seeds=seeds, out=out / name, quiet=quiet), **tkw))

  train = {"finetune_kl": lambda: finetuned(hp["kl_weight"]), "finetune": lambda: finetuned(0.0),
           "scratch": lambda: high(task, b_low, pr, out, seeds, quiet, steps=ft_cfg.total_env_steps,
                                   name=f"{st.b}_scratch_{task}", **tkw),
           "full": full}
  csv_dir = RESULTS / f"{st.name}_{preset}"
  methods, series = {}, {}
  for m in st.methods:
    res = timed(minutes, m, train[m])
    if m == "full":
      final = score(evaluate(load_policy(res.run_dir), task, episodes=pr["episodes"], **tkw))
    else:
      final = eval_hl(res, b_low, task, pr["episodes"], **tkw)
    c = curve(res, 1 if m == "full" else k)
    methods[m] = dict(final, csv=write_curve_csvs(csv_dir, m, c), run=str(res.run_dir))
    series[METHODS[m]] = (c["env_steps"], c[zero["metric"]])
  from hdt.plots import learning_curves  # matplotlib only when plotting
  png = learning_curves(series, RESULTS / f"{st.name}_{preset}.png", hline={"zero-shot": zero["mean"]},
                        title=st.title or f"{st.a} HL -> {st.b} {task} ({preset} preset)",
                        xlabel=f"env steps of B ({st.b})", ylabel=zero["metric"])
  return dict(experiment=st.name, preset=preset, command=command(st.name, preset), seeds=seeds,
              a=st.a, b=st.b, task=task, task_kw=tkw, k=k, budget=pr, kl=hp["kl_weight"], lr=hp["lr"],
              hl_steps=ft_cfg.total_env_steps, b_env_steps=ft_cfg.total_env_steps * k,
              zero_shot=zero, methods=methods, png=str(png), minutes=minutes)


def finetune_markdown(result: dict, paper: dict[str, str]) -> str:
  """Final evaluation per method next to the paper (``paper[method or "zero_shot"]``)."""
  r = result
  lines = [f"{r['a']} HL → {r['b']} LL on {r['task']}: {r['hl_steps']} HL steps = {r['b_env_steps']} env "
           f"steps of B per method, {r['seeds']} seeds × {r['zero_shot']['episodes']} episodes, "
           f"β={r['kl']:g}, finetune lr {r['lr']:g}. Curves: `{r['png']}`.", "",
           f"| method | hdt {r['zero_shot']['metric']} (mean ± std over seeds) | paper |", "|---|---|---|",
           f"| zero-shot | {cell(r['zero_shot'])} | {paper.get('zero_shot', '—')} |"]
  lines += [f"| {METHODS[m]} | {cell(v)} | {paper.get(m, '—')} |" for m, v in r["methods"].items()]
  lines += ["", f"Command: `{r['command']}`"]
  return "\n".join(lines)


def study_interface(st: FinetuneStudy, presets: dict, paper: dict, doc: str | None = None):
  """``(run, markdown, main)`` of an experiment module that is one :class:`FinetuneStudy`."""

  def run(preset: str = "cpu", out: Path = Path("runs") / st.name, seeds: int | None = None,
          quiet: bool = False) -> dict:
    pr = experiment_preset(presets, preset)
    result = finetune_study(st, preset, pr, Path(out), seeds or pr["seeds"], quiet)
    write_result(st.name, preset, result)
    return result

  def markdown(result: dict) -> str:
    return finetune_markdown(result, paper)

  return run, markdown, make_main(st.name, presets, run, markdown, doc)


def hl_rollouts(high, low, record: Callable, episodes: int = 16, key: int = 1):
  """For each seed of ``hdt.compose(high, low)``: ``(env, arrays)``, where ``arrays`` stacks
  ``record(state, next_state)`` over ``episodes`` deterministic HL episodes (leading axes
  [episode, HL step], one full horizon each: steps after an episode's end belong to the next one)."""
  import jax
  import hdt
  from hdt.transfer.evaluate import _env_for
  p = hdt.compose(high=high, low=low)
  for i in range(p.num_seeds):
    at = lambda t: jax.tree.map(lambda x: x[i], t)
    env = _env_for(p, None, "auto", at(p.low_params), low_obs_norm=at(p.low_obs_norm))
    act, params = p.card.policy_fn(at(p.obs_norm)), at(p.params)

    def episode(k):
      def step(s, _):
        n = env.step(s, act(params, s.obs))
        return n, record(s, n)
      return jax.lax.scan(step, env.reset(k), None, length=env.horizon)[1]

    yield env, jax.tree.map(np.asarray, jax.jit(jax.vmap(episode))(jax.random.split(jax.random.PRNGKey(key), episodes)))
