"""The model zoo: trained policies committed under ``zoo/`` and named ``zoo:NAME`` wherever a run
directory is accepted (``hdt eval --high zoo:arm_point/push1 --low zoo:arm_point/low``).

An entry is a policy-only copy of a run directory (``meta.json``, ``config.json``, ``seed_*/``; no
resumable ``state/``) plus ``zoo.json``: the command that trained it, its budget, its evaluation numbers,
the content hash of each seed's checkpoint (checked whenever the entry is loaded; an HL's also of the
LL seed it composes with) and a small deterministic re-evaluation (``check``) that tests replay within
noise (:func:`within_noise`: float differences between CPUs can flip a contact-rich episode). Names
are names, not paths: one or two parts of ``[a-z0-9_]``, and ``zoo:NAME`` never leaves ``zoo/``. An LL entry keeps only the policy
(and observation statistics) of its best periodic evaluation: what HLs compose with and alignment
imitates (nothing loads an LL's critics; ``hdt eval --policy`` of a zoo LL loads these too). An HL
entry keeps its whole final SAC, which KL finetuning starts from (the authors'
finetune_high_level_kl.py), and the policy of its best evaluation, which the KL ties to.
"""

from __future__ import annotations

import contextlib
import csv
import datetime
import io
import json
import shutil
from pathlib import Path

import numpy as np
import orbax.checkpoint as ocp

from hdt import atomic
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
           episodes: int = 100, overwrite: bool = False, **task_kw) -> Path:
  """Copies the policy of ``run`` into ``zoo/NAME`` and records its numbers. An HL needs ``low`` (a zoo
  name, which its metadata then points to) and is evaluated on ``task`` (default: its own). Every
  argument is checked before anything is written; the entry is built in a hidden directory and moved
  into place in one rename (hdt.transfer.rundir.install), so a failed export leaves no trace."""
  check_name(name)
  if isinstance(episodes, bool) or not isinstance(episodes, (int, np.integer)) or episodes <= 0:
    raise ZooError(f"episodes={episodes!r}: the evaluation recorded with the entry needs a positive number of "
                   f"episodes per seed, e.g. 100")
  run = Path(resolve(str(run)))
  meta = ckpt.load_meta(run)  # a readable checkpoint of this hdt's format
  if meta.get("level") == "high":
    if not (isinstance(low, str) and low.startswith(PREFIX)):
      raise ZooError(f"{run} is a high level: export its LL first and pass it as low='zoo:NAME' (CLI: --low zoo:NAME)")
    resolve(low)
  dest = names.ZOO_DIR / name
  if dest.exists() and not overwrite:
    raise ZooError(f"zoo entry {name!r} exists; pass overwrite=True (--overwrite) to replace it")
  rundir.check_claimable(dest, overwrite=overwrite, what="name", reads={"exported": run}, zoo_ok=True)
  task = task or meta["task"]
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
    slimmed = _slim(tmp, meta["level"])
    ckpt.record_seed_hashes(tmp)
    (tmp / "zoo.json").write_text("{}")  # an entry for the evaluations below (as ckpt.load sees it)
    full, check = _numbers(str(tmp), low, task, episodes, task_kw)
    _write_entry(tmp, meta, name, task, task_kw, low, command, full, check, slimmed, low_hash)
    return rundir.install(tmp, dest, overwrite=overwrite, reads={"exported": run}, zoo_ok=True, what="name")
  except BaseException:
    atomic.remove(tmp)  # nothing half-written is left in zoo/
    if not parent_existed:
      with contextlib.suppress(OSError):
        dest.parent.rmdir()
    raise


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


POLICY_KEYS = ("policy", normalizer.KEY)  # what an LL entry keeps, and an HL entry of its best (the KL reference)


def _slim(entry: Path, level: str) -> list[dict]:
  """Drops from the copy ``entry`` (in place) what nothing loads from a zoo entry: an LL's final
  parameters when it has best ones, and all but ``POLICY_KEYS`` of an LL's and of any best. Returns per
  seed the content hash before and after, so that an HL trained over the full LL still composes with
  the slim copy (:func:`hdt.transfer.names.hash_aliases`)."""
  out = []
  for seed in ckpt.list_seeds(entry):
    before = ckpt.content_hash(entry, seed)
    d = ckpt.seed_dir(entry, seed)
    best = d / "best" / "params"
    if level == "low" and best.is_dir() and (d / "params").is_dir():
      shutil.rmtree(d / "params")
    for path in (d / "params", best):
      if path.is_dir() and (level == "low" or path == best):
        params = ocp.PyTreeCheckpointer().restore(path.resolve())
        if set(params) <= set(POLICY_KEYS):
          continue
        new = path.with_name(path.name + ".slim")
        ckpt.orbax_save(new.resolve(), {k: v for k, v in params.items() if k in POLICY_KEYS})
        shutil.rmtree(path)
        new.rename(path)
    _scrub_markers(d)
    out.append({"seed": seed, "source_sha256": before, "sha256": ckpt.content_hash(entry, seed)})
  return out


def _scrub_markers(d: Path) -> bool:
  return any([names.scrub_marker(m.parent) for m in sorted(d.rglob(names.ORBAX_MARKER))])


def scrub_markers(name: str) -> dict:
  """Rewrites, in place, the commit markers of an entry exported while orbax wrote the exporting
  machine's path into them (:func:`hdt.transfer.names.scrub_marker`), keeping the hashes it had as
  aliases, so that runs and HLs recorded over it still compose and resume. Returns the zoo.json."""
  entry, path = names.ZOO_DIR / check_name(name), names.ZOO_DIR / name / "zoo.json"
  info = json.loads(path.read_text())
  seeds = ckpt.list_seeds(entry)
  old_entry, old = ckpt.content_hash(entry), {s: ckpt.content_hash(entry, s) for s in seeds}
  if not _scrub_markers(entry):
    return info
  new = {s: ckpt.content_hash(entry, s) for s in seeds}
  if info.get("slim"):
    for s in info["slim"]:
      s["earlier_sha256"] = sorted(({*s.get("earlier_sha256", []), old[s["seed"]]}
                                    - {s["source_sha256"], new[s["seed"]]}))
      s["sha256"] = new[s["seed"]]
  info["seed_sha256"] = [new[s] for s in seeds]
  info["entry_sha256"] = ckpt.content_hash(entry)
  info["earlier_entry_sha256"] = sorted({*info.get("earlier_entry_sha256", []), old_entry} - {info["entry_sha256"]})
  ckpt.record_seed_hashes(entry)
  atomic.write_text(path, json.dumps(info, indent=1))  # in its own order: a readable diff
  return info


def reslim(name: str) -> dict:
  """Applies today's :func:`_slim` to an entry exported before it (in place), keeping the hashes its
  LL had, so HLs trained over any earlier copy still compose with it. Returns the new zoo.json; an LL
  entry's numbers must then be re-recorded (:func:`reevaluate`), as its default parameters changed."""
  entry, path = names.ZOO_DIR / check_name(name), names.ZOO_DIR / name / "zoo.json"
  info = json.loads(path.read_text())
  old = {s["seed"]: s for s in info.get("slim") or []}
  new = _slim(entry, info["level"])
  if info["level"] == "low":
    for s in new:
      prev = old.get(s["seed"], {})
      earlier = [*prev.get("earlier_sha256", []), s["source_sha256"]]
      s["source_sha256"] = prev.get("source_sha256", s["source_sha256"])
      s["earlier_sha256"] = sorted(set(earlier) - {s["source_sha256"], s["sha256"]})
    info["slim"] = new
  info["seed_sha256"] = [s["sha256"] for s in new]
  ckpt.record_seed_hashes(entry)
  ckpt.write_json_atomic(path, info)
  return info


def _write_entry(tmp, meta, name, task, task_kw, low, command, full, check, slimmed, low_hash=None):
  sac, slimmed = meta.get("sac", {}), sorted(slimmed, key=lambda s: s["seed"])
  info = dict(name=name, level=meta["level"], agent=meta["agent"], task=task, task_options=task_kw,
              low=low, command=command,
              budget=dict(total=sac.get("total_env_steps"),
                          unit="HL decisions" if meta["level"] == "high" else "env steps"),
              seeds=[s["seed"] for s in slimmed], evaluation=full, check=check,
              hdt_version=__version__, exported=datetime.date.today().isoformat(),
              seed_sha256=[s["sha256"] for s in slimmed])
  if meta["level"] == "low":
    info["slim"] = slimmed
  if low_hash is not None:
    info["low_sha256"] = low_hash
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
  are exact; on another CPU a few chaotic episodes may end otherwise, a broken checkpoint moves all."""
  n = len(recorded["seeds"]) * recorded["episodes"]
  out = []
  ret, ret_new = recorded["return_mean"], fresh["return_mean"]
  sd = float(np.mean(recorded.get("episode_return_std", [0.0])))
  tol = z * sd / np.sqrt(n) + 1e-3 * abs(ret) + 1e-3
  if abs(ret_new - ret) > tol:
    out.append(f"return {ret_new:.4g} vs recorded {ret:.4g} (tolerance {tol:.3g})")
  if "success_mean" in recorded:
    p, p_new = recorded["success_mean"], fresh["success_mean"]
    tol = z * np.sqrt(p * (1 - p) / n) + 1.0 / n
    if abs(p_new - p) > tol:
      out.append(f"success {p_new:.3f} vs recorded {p:.3f} (tolerance {tol:.3f})")
  return out


def table() -> str:
  """One line per entry: name, level, agent/task, budget, the parameters its numbers are of (an HL's:
  over its LL's best), headline numbers (mean ± std over seeds)."""
  rows = ["name | level | agent | task | budget | params | return | success | seeds",
          "---|---|---|---|---|---|---|---|---"]
  for e in entries():
    ev = e["evaluation"]
    succ = f"{ev['success_mean']:.2f} ± {ev['success_std']:.2f}" if "success_mean" in ev else "-"
    rows.append(f"{e['name']} | {e['level']} | {e['agent']} | {e['task']} | {e['budget']['total']} "
                f"{e['budget']['unit']} | {ev.get('params', '?')} | {ev['return_mean']:.4g} ± {ev['return_std']:.2g} | "
                f"{succ} | {len(e['seeds'] or [])}")
  return "\n".join(rows)
