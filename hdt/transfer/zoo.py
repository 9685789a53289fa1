"""The model zoo: trained policies committed under ``zoo/`` and named ``zoo:NAME`` wherever a run
directory is accepted (``hdt eval --high zoo:arm_point/push1 --low zoo:arm_point/low``).

An entry is a policy-only copy of a run directory (``meta.json``, ``config.json``, ``seed_*/``; no
resumable ``state/``) plus ``zoo.json``: the command that trained it, its budget, its evaluation numbers,
the content hash of each seed's checkpoint (checked whenever the entry is loaded; an HL's also of the
LL seed it composes with) and a small deterministic re-evaluation (``check``) that tests replay within
noise (:func:`within_noise`: float differences between CPUs can flip a contact-rich episode). Names
are names, not paths: one or two parts of ``[a-z0-9_]``, and ``zoo:NAME`` never leaves ``zoo/``.
Each seed keeps one set of parameters, packed into one file: an LL the policy (and observation
statistics) of its best periodic evaluation, which HLs compose with and alignment imitates (or, exported
with ``low_params="final"``, its final one); an HL the
final policy its numbers are of. An HL that finetuning starts from is exported with ``keep_sac``: its
whole final SAC (the authors' finetune_high_level_kl.py loads A's whole model) and the policy of its
best evaluation, which the KL ties to.
"""

from __future__ import annotations

import contextlib
import csv
import datetime
import io
import json
import shutil
import sys
from pathlib import Path

import numpy as np

from hdt import atomic
from hdt.numfmt import number
from hdt.agents import normalizer
from hdt.envs.robot import agent_spec
from hdt.transfer import checkpoint as ckpt
from hdt.transfer import evaluate as ev
from hdt.transfer import names, rundir
from hdt.transfer.names import PREFIX, ZooError, check_name, entry_names, resolve
from hdt.version import __version__

CHECK_EPISODES, CHECK_KEY = 8, 7  # per seed; the test suite replays every entry's check
CHECK_EPISODES_LEGGED_HL = 4  # an HL over a legged LL: its episodes are thousands of RK4 steps of a legged robot


def entries() -> list[dict]:
  return [json.loads((names.ZOO_DIR / n / "zoo.json").read_text()) for n in entry_names()]


def _evaluate(run: str, low: str | None, task: str, episodes: int, key: int, **task_kw) -> dict:
  policy = ev.compose(run, low) if low else ev.load_policy(run)
  return _plain(ev.evaluate(policy, task, episodes=episodes, key=key, **task_kw))


def _plain(x):
  """JSON-able copy (arrays -> lists) of an evaluation result."""
  if isinstance(x, dict):
    return {k: _plain(v) for k, v in x.items()}
  if isinstance(x, (list, tuple)):
    return [_plain(v) for v in x]
  return x.tolist() if hasattr(x, "tolist") else x


def check_episodes(meta: dict) -> int:
  """Episodes per seed of the check of an entry with checkpoint metadata ``meta``."""
  legged_hl = meta.get("level") == "high" and agent_spec(meta["agent"]).legged
  return CHECK_EPISODES_LEGGED_HL if legged_hl else CHECK_EPISODES


def _check(entry: str, low: str | None, task: str, task_kw: dict) -> dict:
  """The check of ``entry`` (zoo:NAME, or an entry's directory): its episodes, key and result."""
  episodes = check_episodes(ckpt.load_meta(Path(resolve(str(entry)))))
  result = _evaluate(entry, low, task, episodes, CHECK_KEY, **task_kw)
  return dict(episodes=episodes, key=CHECK_KEY, result=result)


def _numbers(entry: str, low: str | None, task: str, episodes: int, task_kw: dict) -> tuple[dict, dict]:
  """(evaluation over ``episodes`` per seed, the check) of ``entry`` (zoo:NAME or a directory)."""
  return _evaluate(entry, low, task, episodes, 1234, **task_kw), _check(entry, low, task, task_kw)


def export(run: str | Path, name: str, command: str, low: str | None = None, task: str | None = None,
           episodes: int = 100, overwrite: bool = False, keep_sac: bool = False, low_params: str = "best",
           **task_kw) -> Path:
  """Copies the policy of ``run`` into ``zoo/NAME`` and records its numbers. An HL needs ``low`` (a zoo
  name, which its metadata then points to) and is evaluated on ``task`` (default: its own); with
  ``keep_sac`` it keeps its whole final SAC, for finetuning to start from (:func:`_slim`). An LL keeps
  the policy of its best evaluation, or with ``low_params="final"`` its final one (e.g. a policy
  average, whose best record an early tie can hold at a fraction of the budget). Every
  argument is checked before anything is written; the entry is built in a hidden directory and moved
  into place in one rename (hdt.transfer.rundir.install), so a failed export leaves no trace."""
  check_name(name)
  if isinstance(episodes, bool) or not isinstance(episodes, (int, np.integer)) or episodes <= 0:
    raise ZooError(f"episodes={episodes!r}: the evaluation recorded with the entry needs a positive number of "
                   f"episodes per seed, e.g. 100")
  run = Path(resolve(str(run)))
  meta = ckpt.load_meta(run)  # a readable checkpoint of this hdt's format
  if keep_sac and meta.get("level") != "high":
    what = "a flat (Full) policy" if meta.get("level") == "full" else "a low level"
    raise ZooError(f"{run} is {what}: keep_sac (--keep-sac) is for an HL that finetuning starts from; "
                   f"export it without --keep-sac (its entry keeps its policy)")
  ckpt.check_which(low_params, "low_params")
  if low_params != "best" and meta.get("level") != "low":
    raise ZooError(f"{run} is not a low level: low_params (--params) picks what an LL entry keeps; an HL entry "
                   f"keeps its final policy")
  if meta.get("level") == "high":
    if not (isinstance(low, str) and low.startswith(PREFIX)):
      raise ZooError(f"{run} is a high level: export its LL first and pass it as low='zoo:NAME' (CLI: --low zoo:NAME)")
    resolve(low)
  dest = names.ZOO_DIR / name
  if dest.exists() and not overwrite:
    raise ZooError(f"zoo entry {name!r} exists; pass overwrite=True (--overwrite) to replace it")
  rundir.check_claimable(dest, overwrite=overwrite, what="name", reads={"exported": run}, zoo_ok=True)
  task = task or meta["task"]
  diverged = _diverged_seeds(run)
  if diverged:
    print(f"warning: {run}: seed{'s' if len(diverged) > 1 else ''} "
          + ", ".join(f"{s} (from env step {at})" for s, at in diverged.items())
          + " stopped training when its loss went NaN/inf; the entry keeps each at its last finite state and "
          f"records it under 'diverged'", file=sys.stderr, flush=True)
  parent_existed = dest.parent.exists()
  atomic.make_dirs(dest.parent)
  tmp = atomic.temp_dir(dest.parent, dest.name)
  try:
    shutil.copytree(run, tmp, dirs_exist_ok=True,
                    ignore=shutil.ignore_patterns("state", "state.old", "tb", "report", "metrics.csv", ".*"))
    _keep_eval_rows(run / "metrics.csv", tmp / ckpt.CURVES_CSV)
    low_hash = None
    if low:  # the HL's hand-off metadata names the zoo LL (and its hash), not a local run directory
      seed = int((meta.get("low") or {}).get("seed_index", 0))
      low_hash = ckpt.content_hash(low, seed)
      for mp in [tmp / "meta.json", *tmp.glob("seed_*/meta.json")]:
        m = json.loads(mp.read_text())
        if isinstance(m.get("low"), dict):
          m["low"] = dict(m["low"], path=low, sha256=m["low"].get("sha256") or low_hash)
          ckpt.write_json_atomic(mp, m)
    slimmed = _slim(tmp, meta["level"], keep_sac, low_params)
    ckpt.record_seed_hashes(tmp)
    (tmp / "zoo.json").write_text("{}")  # an entry for the evaluations below (as ckpt.load sees it)
    full, check = _numbers(str(tmp), low, task, episodes, task_kw)
    _write_entry(tmp, meta, name, task, task_kw, low, command, full, check, slimmed, low_hash, keep_sac, diverged,
                 low_params)
    return rundir.install(tmp, dest, overwrite=overwrite, reads={"exported": run}, zoo_ok=True, what="name")
  except BaseException:
    atomic.remove(tmp)  # nothing half-written is left in zoo/
    if not parent_existed:
      with contextlib.suppress(OSError):
        dest.parent.rmdir()
    raise


def _diverged_seeds(run: Path) -> dict[int, int]:
  """{seed: env step} of the run's seeds that diverged (their meta's ``diverged_at_env_step``)."""
  metas = [{"seed": i} | ckpt.load_meta(run, i) for i in ckpt.list_seeds(run)]
  return {int(m["seed"]): int(m["diverged_at_env_step"]) for m in metas if "diverged_at_env_step" in m}


def _keep_eval_rows(metrics: Path, out: Path) -> None:
  """The evaluation rows of a run's metrics.csv (its learning curves, a few kB) as ``out``: what
  ``hdt reproduce`` draws a figure's curves from when its runs come from the zoo."""
  if not metrics.is_file():
    return
  with open(metrics, newline="") as f:
    reader = csv.DictReader(f)
    cols = [c for c in reader.fieldnames or [] if c in ("seed", "kind", "env_steps") or c.startswith("eval/")]
    rows = [{c: r[c] for c in cols} for r in reader if r.get("kind") == "eval"]
  if rows:
    text = io.StringIO()
    writer = csv.DictWriter(text, cols, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    atomic.write_text(out, text.getvalue())


POLICY_KEYS = ("policy", normalizer.KEY)  # what a policy-only entry keeps, and an HL entry of its best (the KL reference)


def keeps(info: dict) -> str:
  """What an entry (its zoo.json) keeps: "sac" (an HL's whole final SAC: what finetuning starts from) or
  "policy". HLs exported before the choice kept their SAC."""
  return info.get("keeps", "sac" if info.get("level") == "high" else "policy")


def _slim(entry: Path, level: str, keep_sac: bool = False, low_params: str = "best") -> list[dict]:
  """Drops from the copy ``entry`` (in place) what nothing loads from a zoo entry, and packs each
  parameter set left into one file (:func:`hdt.transfer.checkpoint.pack`). An LL keeps the policy of
  its best evaluation (of its final parameters if it has no best, or with ``low_params="final"``); an HL the policy its numbers are of
  (its final), or with ``keep_sac`` its whole final SAC and its best policy, which KL finetuning ties
  to. Returns per seed the content hash before and after, so that what recorded the full run or an
  earlier copy still composes with this one (:func:`hdt.transfer.names.hash_aliases`)."""
  out = []
  for seed in ckpt.list_seeds(entry):
    before = ckpt.content_hash(entry, seed)
    d = ckpt.seed_dir(entry, seed)
    final, best = d / "params", d / "best" / "params"
    if level == "low":
      drop = final if low_params == "best" else best.parent
    else:
      drop = None if keep_sac else best.parent
    if drop is not None and ckpt.has_params(final) and ckpt.has_params(best):
      atomic.remove(drop)
      atomic.remove(ckpt.packed(drop))
    for path in (final, best):
      if not ckpt.has_params(path):
        continue
      params = ckpt.restore_params(path)
      keep = (params if level == "high" and keep_sac and path == final
              else {k: v for k, v in params.items() if k in POLICY_KEYS})
      if path.is_dir() or set(keep) != set(params):
        ckpt.pack(path, keep)
    out.append({"seed": seed, "source_sha256": before, "sha256": ckpt.content_hash(entry, seed)})
  return out


def reslim(name: str, keep_sac: bool | None = None) -> dict:
  """Applies today's :func:`_slim` to an entry exported before it, in one swap of the whole entry
  (``keep_sac``: an HL's choice; default, what it keeps now), keeping the hashes it had as aliases,
  so that HLs and runs recorded over any earlier copy still compose and resume. Returns the new
  zoo.json; if an LL entry's default parameters changed, re-record its numbers (:func:`reevaluate`)."""
  entry, path = names.ZOO_DIR / check_name(name), names.ZOO_DIR / name / "zoo.json"
  info = json.loads(path.read_text())
  if keep_sac is None:
    keep_sac = keeps(info) == "sac"
  if keep_sac and keeps(info) != "sac":
    raise ZooError(f"zoo entry {name!r} keeps only its policy: re-export it from its run with --keep-sac")
  earlier_entry = names.hash_aliases(PREFIX + name, None)  # its hash now, and those it already stood for
  old = {s["seed"]: s for s in info.get("slim") or []}

  def rewrite(tmp: Path):
    shutil.copytree(entry, tmp, dirs_exist_ok=True)
    new = _slim(tmp, info["level"], keep_sac, info.get("params", "best"))
    for s in new:
      prev = old.get(s["seed"], {})
      earlier = {*prev.get("earlier_sha256", []), s["source_sha256"]}
      if prev.get("sha256") == s["source_sha256"]:  # unchanged since its export: what its run was is still known
        s["source_sha256"] = prev.get("source_sha256", s["source_sha256"])
      s["earlier_sha256"] = sorted(earlier - {s["source_sha256"], s["sha256"]})
    info["slim"] = new
    info["seed_sha256"] = [s["sha256"] for s in new]
    if info["level"] == "high":
      info["keeps"] = "sac" if keep_sac else "policy"
    ckpt.record_seed_hashes(tmp)
    info["entry_sha256"] = ckpt.content_hash(tmp)
    info["earlier_entry_sha256"] = sorted(earlier_entry - {info["entry_sha256"]})
    ckpt.write_json_atomic(tmp / "zoo.json", info)

  atomic.replace_dir(entry, rewrite)
  return info


def _write_entry(tmp, meta, name, task, task_kw, low, command, full, check, slimmed, low_hash=None,
                 keep_sac=False, diverged=None, low_params="best"):
  sac, slimmed = meta.get("sac", {}), sorted(slimmed, key=lambda s: s["seed"])
  info = dict(name=name, level=meta["level"], agent=meta["agent"], task=task, task_options=task_kw,
              low=low, command=command,
              budget=dict(total=sac.get("total_env_steps"),
                          unit="HL decisions" if meta["level"] == "high" else "env steps"),
              seeds=[s["seed"] for s in slimmed], evaluation=full, check=check,
              hdt_version=__version__, exported=datetime.date.today().isoformat(),
              seed_sha256=[s["sha256"] for s in slimmed])
  info["slim"] = slimmed
  if meta["level"] == "high":
    info["keeps"] = "sac" if keep_sac else "policy"
  if low_params != "best":  # an LL entry's parameters: its best unless said
    info["params"] = low_params
  if low_hash is not None:
    info["low_sha256"] = low_hash
  if diverged:  # {seed: env step}: these seeds' policies stopped there
    info["diverged"] = {str(s): at for s, at in diverged.items()}
  info["entry_sha256"] = ckpt.content_hash(tmp)
  atomic.write_text(tmp / "zoo.json", json.dumps(info, indent=1))


def reevaluate(name: str, reason: str, episodes: int = 100, check_only: bool = False) -> dict:
  """Re-runs an entry's evaluation and check after a deliberate change of its env (``reason``), keeping
  the previous numbers under ``reevaluated``; ``check_only``: the check alone (e.g. after a change of
  ``CHECK_EPISODES``). Returns the new zoo.json."""
  path = names.ZOO_DIR / check_name(name) / "zoo.json"
  info = json.loads(path.read_text())
  old = {k: info[k] for k in (("check",) if check_only else ("evaluation", "check"))}
  info["reevaluated"] = info.get("reevaluated", []) + [dict(date=datetime.date.today().isoformat(), reason=reason,
                                                            hdt_version=__version__, previous=old)]
  if check_only:
    info["check"] = _check(PREFIX + name, info["low"], info["task"], info["task_options"])
  else:
    info["evaluation"], info["check"] = _numbers(PREFIX + name, info["low"], info["task"], episodes,
                                                 info["task_options"])
  ckpt.write_json_atomic(path, info)
  return info


def recheck(name: str) -> tuple[dict, dict]:
  """(recorded, fresh) results of the entry's deterministic check evaluation."""
  info = json.loads((names.ZOO_DIR / check_name(name) / "zoo.json").read_text())
  c = info["check"]
  fresh = _evaluate(PREFIX + name, info["low"], info["task"], c["episodes"], c["key"], **info["task_options"])
  return c["result"], fresh


def within_noise(recorded: dict, fresh: dict, z: float = 4.0) -> list[str]:
  """What differs between two evaluations of the same episodes by more than sampling noise: the mean
  over all episodes of the return and of the success rate, within ``z`` standard errors (the recorded
  spread across episodes; a Bernoulli one for success), plus one episode's worth. Same-machine replays
  are exact; on another CPU a chaotic episode may end otherwise (one success more or fewer, one return
  moved across the range seen in either evaluation), while a broken checkpoint moves many."""
  n = len(recorded["seeds"]) * recorded["episodes"]
  out = []
  ret, ret_new = recorded["return_mean"], fresh["return_mean"]
  sd = float(np.mean(recorded.get("episode_return_std", [0.0])))
  tol = z * sd / np.sqrt(n) + _episode_range(recorded, fresh) / n + 1e-3 * abs(ret) + 1e-3
  if abs(ret_new - ret) > tol:
    out.append(f"return {ret_new:.4g} vs recorded {ret:.4g} (tolerance {tol:.3g})")
  if "success_mean" in recorded:
    p, p_new = recorded["success_mean"], fresh["success_mean"]
    tol = z * np.sqrt(p * (1 - p) / n) + 1.0 / n + 1e-6  # the margin: means of float32 successes
    if abs(p_new - p) > tol:
      out.append(f"success {p_new:.3f} vs recorded {p:.3f} (tolerance {tol:.3f})")
  return out


def _episode_range(*results: dict) -> float:
  """The largest minus the smallest episode return in any of ``results`` (checks recorded before
  evaluations kept each seed's extremes contribute none)."""
  lo = [v for r in results for v in r.get("episode_return_min", [])]
  hi = [v for r in results for v in r.get("episode_return_max", [])]
  return float(max(hi) - min(lo)) if lo and hi else 0.0


def table() -> str:
  """One line per entry: name, level, agent/task, budget, the parameters its numbers are of (an HL's:
  over its LL's best), headline numbers (mean ± std over seeds), and what it keeps (:func:`keeps`: "sac"
  can be finetuned from)."""
  rows = ["name | level | agent | task | budget | params | return | success | seeds | keeps",
          "---|---|---|---|---|---|---|---|---|---"]
  for e in entries():
    ev = e["evaluation"]
    succ = f"{ev['success_mean']:.2f} ± {ev['success_std']:.2f}" if "success_mean" in ev else "-"
    rows.append(f"{e['name']} | {e['level']} | {e['agent']} | {e['task']} | {e['budget']['total']} "
                f"{e['budget']['unit']} | {ev.get('params', '?')} | {number(ev['return_mean'], 4)} ± {number(ev['return_std'], 2)} | "
                f"{succ} | {len(e['seeds'] or [])} | {keeps(e)}")
  return "\n".join(rows)
