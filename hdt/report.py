"""Reports of run directories: a Markdown summary (final evaluation mean ± std over seeds), learning
curves with seed bands and, for high levels, a top-down trajectory over the task's scene."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from hdt import atomic
from hdt.numfmt import mean_std, number
from hdt.transfer import checkpoint as ckpt

# Evaluation metrics worth a curve, in the order they are shown; (csv column, label).
CURVE_METRICS = (("eval/success_max", "success"), ("eval/return", "return"), ("eval/goal_dist", "final goal distance"))


def markdown_table(header: list[str], rows: list[list]) -> str:
  lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
  lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
  return "\n".join(lines)


def write_csv(path, fieldnames, rows) -> Path:
  """``rows`` (dicts) as a CSV with header ``fieldnames``, written atomically."""
  with atomic.open_atomic(atomic.make_dirs(Path(path).parent) / Path(path).name, "w", newline="") as f:
    w = csv.DictWriter(f, fieldnames=list(fieldnames))
    w.writeheader()
    w.writerows(rows)
  return Path(path)


def _damaged(path: Path, what: str) -> ValueError:
  return ValueError(f"{path} is damaged ({what}): re-run training to write it again, or restore it from a backup")


def read_metrics(path: Path) -> list[dict]:
  """The rows of a run's metrics.csv, each checked: a seed, a kind ("train" or "eval") and numbers."""
  try:
    with open(path, newline="") as f:
      reader = csv.DictReader(f)
      header, rows = reader.fieldnames or [], list(reader)
  except (UnicodeDecodeError, csv.Error) as e:
    raise _damaged(path, f"not CSV text: {e}") from None
  if not {"seed", "kind"} <= set(header):
    raise _damaged(path, f"its header {', '.join(header[:4]) or 'is empty'} has no seed and kind columns")
  for line, r in enumerate(rows, start=2):
    if None in r or None in r.values():
      raise _damaged(path, f"line {line} has {'more' if None in r else 'fewer'} fields than the header")
    if r["kind"] not in ("train", "eval"):
      raise _damaged(path, f"line {line} has kind {r['kind']!r}, not train or eval")
    for k, v in r.items():
      if k != "kind" and v != "":
        try:
          float(v)
        except ValueError:
          raise _damaged(path, f"line {line} has {k}={v!r}, not a number") from None
  return rows


def read_eval_curves(run_dir: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
  """``{column: (env_steps[T], values[S, T])}`` of the evaluation rows of a run's metrics.csv (a zoo
  entry: of the :data:`~hdt.transfer.checkpoint.CURVES_CSV` its export kept)."""
  path = Path(run_dir) / "metrics.csv"
  if not path.exists() and (Path(run_dir) / ckpt.CURVES_CSV).exists():
    path = Path(run_dir) / ckpt.CURVES_CSV
  if not path.exists():
    raise FileNotFoundError(f"{path} not found: is {run_dir} a run directory written by hdt?")
  rows = [r for r in read_metrics(path) if r["kind"] == "eval"]
  if not rows:
    raise ValueError(f"{path} holds no evaluation rows: re-run training to write it again")
  if "env_steps" not in rows[0]:
    raise _damaged(path, "no env_steps column")
  seeds = sorted({r["seed"] for r in rows}, key=float)
  out = {}
  for col in rows[0]:
    if not col.startswith("eval/") or col == "eval/env_steps":
      continue
    per = [[float(r[col]) if r[col] != "" else np.nan for r in rows if r["seed"] == s] for s in seeds]
    steps = np.array([float(r["env_steps"]) for r in rows if r["seed"] == seeds[0]])
    t = min(len(p) for p in per)
    out[col] = (steps[:t], np.array([p[:t] for p in per]))
  return out


def run_report(run_dir: str | Path, trajectory: bool = True, episodes: int = 10, video: bool = True) -> Path:
  """Writes ``RUN/report/report.md`` with PNGs next to it and returns the Markdown path (only into a
  run hdt wrote, checked as every write is: hdt.transfer.rundir). ``video``: a short clip of the policy
  when rendering works here (hdt.render)."""
  from hdt.transfer import rundir
  run_dir = Path(run_dir)
  meta_path = run_dir / "meta.json"
  if not meta_path.exists():
    raise FileNotFoundError(f"{meta_path} not found: `hdt report` takes a run directory written by "
                            f"`hdt train/align/finetune` (it holds config.json, meta.json, metrics.csv)")
  rundir.check_claimable(run_dir, "run", reuse=True, what="run")  # writes report/ into hdt's own runs only
  try:
    meta = json.loads(meta_path.read_text())
  except (OSError, ValueError) as e:
    raise _damaged(meta_path, f"not JSON: {e}") from None
  if not isinstance(meta, dict) or not isinstance(meta.get("sac", {}), dict):
    raise _damaged(meta_path, "not a JSON object" if not isinstance(meta, dict) else "its sac is not an object")
  out = run_dir / "report"
  curves = read_eval_curves(run_dir)
  with rundir.claim(run_dir, "run", reuse=True):
    return _write_report(run_dir, meta, curves, out, trajectory, video)


def _write_report(run_dir: Path, meta: dict, curves: dict, out: Path, trajectory: bool, video: bool = True) -> Path:
  from hdt import plots
  what = f"{meta.get('level')} level, {meta.get('agent')} on {meta.get('task')}"
  lines = [f"# Report: {run_dir.name}", "", f"{what}; seeds {meta.get('seeds')}; "
           f"{meta.get('sac', {}).get('total_env_steps', '?')} env steps per seed.", ""]
  rows = []
  for col, label in CURVE_METRICS:
    if col not in curves:
      continue
    steps, y = curves[col]
    final = y[:, -1]
    rows.append([label, mean_std(final.mean(), final.std()), ", ".join(number(v) for v in final),
                 number(y[:, 0].mean())])
    png = plots.learning_curves({meta.get("level", "run"): (steps, y)}, out / f"curve_{label.replace(' ', '_')}.png",
                                title=what, xlabel="env steps" + (" (HL decisions)" if meta.get("level") == "high" else ""),
                                ylabel=label)
    lines.append(f"![{label}]({png.name})")
  lines[4:4] = [markdown_table(["metric", "final (mean ± std over seeds)", "per seed", "at start"], rows), ""]
  if trajectory and meta.get("level") == "high" and meta.get("low"):
    lines += ["", _trajectory_section(run_dir, meta, out)]
  out.mkdir(parents=True, exist_ok=True)
  if video:
    lines += ["", _video_section(run_dir, meta, out)]
  return atomic.write_text(out / "report.md", "\n".join(lines) + "\n")


def _trajectory_section(run_dir: Path, meta: dict, out: Path) -> str:
  from hdt import plots
  from hdt.envs import make
  from hdt.transfer.evaluate import compose, trajectory

  low = meta["low"]["path"]
  try:
    ckpt.load_meta(low)
  except (FileNotFoundError, ckpt.CheckpointError) as e:
    return f"(no trajectory: the low level {low} is not loadable: {e})"
  policy = compose(run_dir, low)
  overrides = meta.get("task_overrides") or {}
  traj = trajectory(policy, meta["task"], **overrides)
  lc = policy.low_card
  model = make(lc.agent, meta["task"], **dict(lc.env_overrides or {}) | overrides).mj_model
  png = plots.trajectory(traj, model, out / "trajectory.png",
                         title=f"{meta['task']}: HL seed 0 driving {lc.agent}'s LL")
  ret = float(np.sum(traj["rewards"]))
  return f"One deterministic episode (return {number(ret)}):\n\n![trajectory]({png.name})"


VIDEOS = ("clip.mp4", "clip.gif")  # a report's clip: MP4, or GIF where no MP4 encoder works
VIDEO_STEPS = 100  # LL steps in the clip: a few seconds of motion, rendered in seconds


def video_path(report_dir: Path) -> Path | None:
  """The clip of a report directory, if it has one."""
  return next((report_dir / n for n in VIDEOS if (report_dir / n).exists()), None)


def _video_section(run_dir: Path, meta: dict, out: Path) -> str:
  """A short clip of the run's policy (seed 0), or one line saying why there is none: a failure to
  render never fails the report."""
  import sys

  from hdt import render
  from hdt.transfer.evaluate import compose, load_policy
  for name in VIDEOS:  # never a clip of an earlier report beside this one
    (out / name).unlink(missing_ok=True)
  try:
    high = meta.get("level") == "high" and isinstance(meta.get("low"), dict)
    policy = compose(run_dir, meta["low"]["path"]) if high else load_policy(run_dir)
    path = render.render(policy, out / VIDEOS[0], config=render.RenderConfig(width=320, height=240,
                                                                              max_steps=VIDEO_STEPS))
  except Exception as e:  # noqa: BLE001 (whatever stops the video, the report goes on without it)
    why = " ".join(str(e).split()) or type(e).__name__
    print(f"report: no video ({why})", file=sys.stderr)
    return f"(no video: {why})"
  what = f"Seed 0 acting deterministically ({VIDEO_STEPS} LL steps at most; the sub-goal in yellow)"
  return f"{what}:\n\n![rollout]({path.name})" if path.suffix == ".gif" else f"{what}: [video]({path.name})"
