"""Figures people would rather look at than read: learning curves with seed bands, transfer-matrix
heatmaps and top-down trajectories over the task's scene. Matplotlib (Agg), PNG files, no display."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from hdt import atomic  # noqa: E402
from hdt.numfmt import number  # noqa: E402


def _save(fig, path) -> Path:
  path = Path(path)
  path.parent.mkdir(parents=True, exist_ok=True)
  try:
    with atomic.open_atomic(path, "wb") as f:  # never a half-written PNG
      fig.savefig(f, format="png", dpi=120, bbox_inches="tight")
  finally:
    plt.close(fig)
  return path


def learning_curves(series: Mapping[str, tuple[np.ndarray, np.ndarray]], path, hline: Mapping[str, float] | None = None,
                    title: str = "", xlabel: str = "env steps of B", ylabel: str = "success") -> Path:
  """One line per method: the mean over seeds with a ±1 std band. ``series[name] = (x, y)`` with x of
  shape (T,) or (S, T) and y of shape (S, T); ``hline`` draws reference levels (e.g. zero-shot)."""
  return panels([("curves", dict(series=series, hline=hline, title=title, xlabel=xlabel, ylabel=ylabel))], path)


def heatmap(matrix: dict, path, title: str = "", xlabel: str = "HL trained on", ylabel: str = "LL of") -> Path:
  """A zero-shot transfer matrix from :func:`hdt.transfer.evaluate.zero_shot_matrix` (or any matrix of
  that form; ``xlabel`` / ``ylabel`` name its columns and rows). A cell whose mean is NaN is shown as
  not run; ``matrix["paper"]`` may map a cell to the paper's number, printed under hdt's."""
  return panels([("heatmap", dict(matrix=matrix, title=title, xlabel=xlabel, ylabel=ylabel))], path)


def grouped_bars(bars: list[dict], path, title: str = "", ylabel: str = "success") -> Path:
  """Bars of ``mean`` ± ``std`` grouped by ``group``, one colour per ``method``; a black tick at
  ``paper`` where a bar has the paper's number (e.g. Table 2: plain vs aligned LL per transfer)."""
  return panels([("bars", dict(bars=bars, title=title, ylabel=ylabel))], path)


def panels(items: list[tuple[str, dict]], path, title: str = "", per_row: int = 3) -> Path:
  """Several plots in one figure, ``per_row`` to a row: each item is ("curves", ``learning_curves``'
  arguments), ("heatmap", ``heatmap``'s) or ("bars", ``grouped_bars``') without ``path``."""
  draw = {"curves": _curves, "heatmap": _heatmap, "bars": _bars}
  unknown = [kind for kind, _ in items if kind not in draw]
  if unknown or not items:
    raise ValueError(f"panels {unknown or items!r}: give one or more of {', '.join(draw)} with their arguments")
  size = [_size(kind, kw) for kind, kw in items]
  rows = [items[i:i + per_row] for i in range(0, len(items), per_row)]
  width = max(sum(w for w, _ in size[i:i + per_row]) for i in range(0, len(items), per_row))
  height = sum(max(h for _, h in size[i:i + per_row]) for i in range(0, len(items), per_row))
  fig = plt.figure(figsize=(width, height))
  grid = fig.add_gridspec(len(rows), max(len(r) for r in rows))
  for i, (kind, kw) in enumerate(items):
    draw[kind](fig, fig.add_subplot(grid[i // per_row, i % per_row]), **kw)
  if title:
    fig.suptitle(title)
  fig.tight_layout()
  return _save(fig, path)


def _size(kind: str, kw: dict) -> tuple[float, float]:
  """(width, height) in inches of one panel."""
  if kind == "heatmap":
    m = kw["matrix"]
    return 1.6 * len(m["cols"]) + 2, 1.2 * len(m["rows"]) + 1.5
  if kind == "bars":
    groups = {b["group"] for b in kw["bars"]}
    methods = {b["method"] for b in kw["bars"]}
    return 1.1 * len(groups) * len(methods) + 2, 4
  return 6, 4


def _curves(fig, ax, series, hline=None, title="", xlabel="env steps of B", ylabel="success", ylim=None):
  for name, (x, y) in series.items():
    y = np.atleast_2d(np.asarray(y, float))
    x = np.asarray(x, float)
    x = np.nanmean(x, axis=0) if x.ndim == 2 else x
    if x.shape[0] != y.shape[1]:
      raise ValueError(f"{name}: x has {x.shape[0]} points but y has {y.shape[1]} per seed")
    m, s = np.nanmean(y, axis=0), np.nanstd(y, axis=0)
    (line,) = ax.plot(x, m, label=f"{name} (n={y.shape[0]})")
    ax.fill_between(x, m - s, m + s, color=line.get_color(), alpha=0.2, lw=0)
  # several reference levels (zero-shot, the paper's numbers) each get their own dash and colour
  styles = (("--", "purple"), (":", "black"), ("-.", "grey"), ((0, (5, 1, 1, 1)), "brown"))
  for i, (name, v) in enumerate((hline or {}).items()):
    ls, color = styles[i % len(styles)]
    ax.axhline(v, ls=ls, color=color, lw=1, label=f"{name} ({number(v)})")
  ax.set(title=title, xlabel=xlabel, ylabel=ylabel)
  if ylim is not None:
    ax.set_ylim(*ylim)
  ax.grid(alpha=0.3)
  if ax.get_legend_handles_labels()[0]:
    ax.legend(fontsize=8)


def _heatmap(fig, ax, matrix, title="", xlabel="HL trained on", ylabel="LL of"):
  rows, cols = matrix["rows"], matrix["cols"]
  mean = np.array([[matrix["cells"][(r, c)][0] for c in cols] for r in rows], float)
  std = np.array([[matrix["cells"][(r, c)][1] for c in cols] for r in rows], float)
  metric = next(iter(matrix["cells"].values()))[2]
  paper = matrix.get("paper") or {}
  limits = dict(vmin=0.0, vmax=1.0) if metric == "success" else {}  # success rates side by side on one scale
  im = ax.imshow(np.ma.masked_invalid(mean), cmap="viridis", **limits)
  mid = np.nanmean(mean) if np.isfinite(mean).any() else 0.0
  for i, r in enumerate(rows):
    for j, c in enumerate(cols):
      text = f"{number(mean[i, j])}\n±{number(std[i, j], 2)}" if np.isfinite(mean[i, j]) else "not run"
      if paper.get((r, c)):
        text += f"\n(paper {paper[(r, c)]})"
      ax.text(j, i, text, ha="center", va="center", fontsize=8,
              color="k" if not np.isfinite(mean[i, j]) or mean[i, j] >= mid else "w")
  ax.set_xticks(range(len(cols)), cols)
  ax.set_yticks(range(len(rows)), rows)
  ax.set(xlabel=xlabel, ylabel=ylabel, title=title or f"{matrix['task']}: {metric}")
  fig.colorbar(im, ax=ax, label=metric)


def _bars(fig, ax, bars, title="", ylabel="success"):
  groups = list(dict.fromkeys(b["group"] for b in bars))
  methods = list(dict.fromkeys(b["method"] for b in bars))
  ax.set(title=title, ylabel=ylabel)
  if not bars:  # a table part with no cell run yet
    ax.text(0.5, 0.5, "not run", ha="center", va="center", transform=ax.transAxes)
    return
  width = 0.8 / len(methods)
  for j, m in enumerate(methods):
    mine = [(groups.index(b["group"]), b) for b in bars if b["method"] == m]
    x = np.array([i for i, _ in mine]) + (j - (len(methods) - 1) / 2) * width
    ax.bar(x, [b["mean"] for _, b in mine], width, yerr=[b["std"] for _, b in mine], capsize=3, label=m)
    for xi, (_, b) in zip(x, mine):
      if b.get("paper") is not None:
        ax.plot([xi - 0.4 * width, xi + 0.4 * width], [b["paper"]] * 2, color="k", lw=2)
  ax.plot([], [], color="k", lw=2, label="paper")
  ax.set_xticks(range(len(groups)), groups, fontsize=8)
  ax.grid(alpha=0.3, axis="y")
  ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))  # beside the axes: never over a bar


def _static_boxes(model: mujoco.MjModel):
  """(corners (4, 2), top height) of every box geom fixed to the world: walls, barriers, slot wall."""
  out = []
  for g in range(model.ngeom):
    if model.geom_bodyid[g] != 0 or model.geom_type[g] != mujoco.mjtGeom.mjGEOM_BOX:
      continue
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, model.geom_quat[g])
    rot = rot.reshape(3, 3)
    sx, sy, sz = model.geom_size[g]
    local = np.array([[-sx, -sy, 0], [sx, -sy, 0], [sx, sy, 0], [-sx, sy, 0]])
    corners = model.geom_pos[g] + local @ rot.T
    out.append((corners[:, :2], model.geom_pos[g][2] + sz))
  return out


def trajectory(traj: dict, model: mujoco.MjModel, path, title: str = "") -> Path:
  """Top-down view of one episode from :func:`hdt.transfer.evaluate.trajectory`: the scene's walls
  and barriers (shade = height), the goal-space path, sub-goals, and the block's path if any."""
  fig, ax = plt.subplots(figsize=(5, 5))
  boxes = _static_boxes(model)
  top = max([h for _, h in boxes], default=1.0)
  for corners, h in boxes:
    ax.add_patch(plt.Polygon(corners, color=plt.cm.Greys(0.3 + 0.6 * h / top), lw=0))
  for s in range(model.nsite):
    name = model.site(s).name
    if "destination" in name or "target" in name:
      ax.plot(*model.site_pos[s][:2], "r*", ms=12, label=name.split("/")[-1])
  xy = np.asarray(traj["xy"])
  ax.plot(xy[:, 0], xy[:, 1], "-", lw=1.2, label=f"{traj.get('agent', 'agent')} path")
  if len(xy):
    ax.plot(*xy[0], "go", label="start")
  goals = np.asarray(traj.get("goals", np.zeros((0, 2))))
  if len(goals):
    ax.plot(goals[:, 0], goals[:, 1], "x", color="tab:orange", ms=5, label="sub-goals")
  # The recorder logs obs_hi[2:4]: the block on BlockPush, the waypoint / goal cell on navigation.
  block = np.asarray(traj.get("block", np.zeros((0, 2))))
  shown = [xy, goals]
  if len(block) and str(traj.get("task", "")).startswith("push"):
    ax.plot(block[:, 0], block[:, 1], "-", color="tab:brown", lw=2, label="block")
    shown.append(block)
  elif len(block) and traj.get("task") in ("waypoint", "maze", "steps"):
    targets = np.unique(np.round(block, 3), axis=0)
    ax.plot(targets[:, 0], targets[:, 1], "r*", ms=10, label="waypoints" if traj["task"] == "waypoint" else "goal")
    shown.append(targets)
  pts = np.concatenate(shown)
  if boxes and len(pts) and np.ptp(pts) < 2.0:  # manipulation: zoom to the arena, not the floor
    pad = 0.05
    ax.set_xlim(pts[:, 0].min() - pad - 0.1, pts[:, 0].max() + pad + 0.1)
    ax.set_ylim(pts[:, 1].min() - pad - 0.1, pts[:, 1].max() + pad + 0.1)
  else:
    ax.autoscale()
  ax.set_aspect("equal")
  ax.set(title=title or f"{traj.get('agent')} on {traj.get('task')}", xlabel="x (m)", ylabel="y (m)")
  ax.legend(fontsize=7, loc="best")
  return _save(fig, path)
