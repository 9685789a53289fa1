"""Learning-curve plots: mean line and ± std band over seeds per method (matplotlib, Agg backend)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def learning_curves(series: dict[str, tuple[np.ndarray, np.ndarray]], path: str | Path,
                    hline: dict[str, float] | None = None, title: str = "",
                    xlabel: str = "env steps of B", ylabel: str = "success") -> Path:
  """One line per method: ``series[name] = (x, y)`` with x of shape (T,) or (S, T) and y of shape
  (S, T) (S seeds). Seeds share the x grid (the mean over seeds when x is (S, T)); NaNs are ignored.
  ``hline[name] = level`` draws a dashed horizontal line (e.g. the zero-shot level). Writes ``path``
  (PNG) atomically and returns it."""
  import matplotlib
  matplotlib.use("Agg")  # headless; no display on the training machines
  import matplotlib.pyplot as plt

  fig, ax = plt.subplots(figsize=(6, 4))
  for name, (x, y) in series.items():
    y = np.atleast_2d(np.asarray(y, float))
    x = np.asarray(x, float)
    x = np.nanmean(x, axis=0) if x.ndim == 2 else x
    if x.shape[0] != y.shape[1]:
      raise ValueError(f"{name}: x has {x.shape[0]} points but y has {y.shape[1]} per seed")
    mean, std = np.nanmean(y, axis=0), np.nanstd(y, axis=0)
    (line,) = ax.plot(x, mean, label=f"{name} (n={y.shape[0]})")
    ax.fill_between(x, mean - std, mean + std, color=line.get_color(), alpha=0.2, linewidth=0)
  for name, level in (hline or {}).items():
    ax.axhline(level, linestyle="--", color="purple", label=f"{name} ({level:.3g})")
  ax.set_xlabel(xlabel)
  ax.set_ylabel(ylabel)
  if title:
    ax.set_title(title)
  ax.grid(alpha=0.3)
  ax.legend(fontsize=8)
  fig.tight_layout()
  path = Path(path)
  path.parent.mkdir(parents=True, exist_ok=True)
  tmp = path.with_name("." + path.name + ".tmp.png")
  fig.savefig(tmp, dpi=120)
  plt.close(fig)
  tmp.replace(path)
  return path
