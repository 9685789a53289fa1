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
  fig, ax = plt.subplots(figsize=(6, 4))
  for name, (x, y) in series.items():
    y = np.atleast_2d(np.asarray(y, float))
    x = np.asarray(x, float)
    x = np.nanmean(x, axis=0) if x.ndim == 2 else x
    if x.shape[0] != y.shape[1]:
      raise ValueError(f"{name}: x has {x.shape[0]} points but y has {y.shape[1]} per seed")
    m, s = np.nanmean(y, axis=0), np.nanstd(y, axis=0)
    (line,) = ax.plot(x, m, label=f"{name} (n={y.shape[0]})")
    ax.fill_between(x, m - s, m + s, color=line.get_color(), alpha=0.2, lw=0)
  for name, v in (hline or {}).items():
    ax.axhline(v, ls="--", color="purple", lw=1, label=f"{name} ({v:.3g})")
  ax.set(title=title, xlabel=xlabel, ylabel=ylabel)
  ax.grid(alpha=0.3)
  ax.legend(fontsize=8)
  return _save(fig, path)


def heatmap(matrix: dict, path, title: str = "", xlabel: str = "HL trained on", ylabel: str = "LL of") -> Path:
  """A zero-shot transfer matrix from :func:`hdt.transfer.evaluate.zero_shot_matrix` (or any matrix of
  that form; ``xlabel`` / ``ylabel`` name its columns and rows)."""
  rows, cols = matrix["rows"], matrix["cols"]
  mean = np.array([[matrix["cells"][(r, c)][0] for c in cols] for r in rows])
  std = np.array([[matrix["cells"][(r, c)][1] for c in cols] for r in rows])
  metric = next(iter(matrix["cells"].values()))[2]
  fig, ax = plt.subplots(figsize=(1.6 * len(cols) + 2, 1.2 * len(rows) + 1.5))
  im = ax.imshow(mean, cmap="viridis")
  for i in range(len(rows)):
    for j in range(len(cols)):
      ax.text(j, i, f"{mean[i, j]:.3g}\n±{std[i, j]:.2g}", ha="center", va="center",
              color="w" if mean[i, j] < mean.mean() else "k", fontsize=9)
  ax.set_xticks(range(len(cols)), cols)
  ax.set_yticks(range(len(rows)), rows)
  ax.set(xlabel=xlabel, ylabel=ylabel, title=title or f"{matrix['task']}: {metric}")
  fig.colorbar(im, ax=ax, label=metric)
  return _save(fig, path)


def grouped_bars(bars: list[dict], path, title: str = "", ylabel: str = "success") -> Path:
  """Bars of ``mean`` ± ``std`` grouped by ``group``, one colour per ``method``; a black tick at
  ``paper`` where a bar has the paper's number (e.g. Table 2: plain vs aligned LL per transfer)."""
  groups = list(dict.fromkeys(b["group"] for b in bars))
  methods = list(dict.fromkeys(b["method"] for b in bars))
  width = 0.8 / len(methods)
  fig, ax = plt.subplots(figsize=(1.1 * len(groups) * len(methods) + 2, 4))
  for j, m in enumerate(methods):
    mine = [(groups.index(b["group"]), b) for b in bars if b["method"] == m]
    x = np.array([i for i, _ in mine]) + (j - (len(methods) - 1) / 2) * width
    ax.bar(x, [b["mean"] for _, b in mine], width, yerr=[b["std"] for _, b in mine], capsize=3, label=m)
    for xi, (_, b) in zip(x, mine):
      if b.get("paper") is not None:
        ax.plot([xi - 0.4 * width, xi + 0.4 * width], [b["paper"]] * 2, color="k", lw=2)
  ax.plot([], [], color="k", lw=2, label="paper")
  ax.set_xticks(range(len(groups)), groups, fontsize=8)
  ax.set(title=title, ylabel=ylabel)
  ax.grid(alpha=0.3, axis="y")
  ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))  # beside the axes: never over a bar
  return _save(fig, path)


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
