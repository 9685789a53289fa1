"""The progress of a training run, after every chunk: env steps, steps/s, ETA and the latest evaluation.

Where it is shown decides how (rich tells which): on a terminal, a live bar redrawn in place; in a log
(stderr not a terminal: a file, a pipe, CI) one line per update, ``low point [#####---] 5000/20000 steps
812/s ETA 18s return=12.3 success_max=0.5``, which scripts and tests parse; in Jupyter, rich's bar in
an output widget redrawn in place (without ipywidgets, a line per tenth of the run rather than one per
chunk). The rate and ETA count only this process's steps, so a resumed run does not claim the steps it
loaded.
"""

from __future__ import annotations

import importlib.util
import sys
import time
from typing import Callable

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

EVALS = ("eval/return", "eval/success_max", "eval/goal_dist")  # shown, as return=... success_max=...


def line(label: str, step: int, total: int, rate: float, evals: str) -> str:
  """One update as a log line."""
  frac = step / total
  bar = "#" * int(20 * frac) + "-" * (20 - int(20 * frac))
  return f"{label} [{bar}] {step}/{total} steps {rate:.0f}/s ETA {(total - step) / max(rate, 1e-9):.0f}s {evals}"


class RunProgress:
  """``progress(env_steps, metrics)`` after every chunk (metrics: per-seed arrays, ``eval/...`` when an
  evaluation ran); ``close()`` ends a live display (the runner calls it however training ends)."""

  def __init__(self, total: int, quiet: bool = False, label: str = "", start: int = 0,
               console: Console | None = None):
    self.total, self.label, self.start = total, label, start
    self.t0 = time.perf_counter()
    self.console = console or Console(stderr=True)
    jupyter = self.console.is_jupyter
    live = ((jupyter and importlib.util.find_spec("ipywidgets") is not None)
            or (not jupyter and self.console.is_terminal and not self.console.is_dumb_terminal))
    self.mode = "quiet" if quiet else "live" if live else "tenths" if jupyter else "lines"
    self.shown_tenth = -1
    self.bar = self.task = None

  def __call__(self, step: int, metrics: dict) -> None:
    if self.mode == "quiet":
      return
    rate = (step - self.start) / max(time.perf_counter() - self.t0, 1e-9)
    evals = " ".join(f"{k[5:]}={float(np.mean(v)):.3g}" for k, v in metrics.items() if k in EVALS)
    if self.mode == "live":
      self._live(step, rate, evals)
      return
    tenth = int(10 * step / self.total)
    if self.mode == "tenths" and tenth == self.shown_tenth and step < self.total:
      return
    self.shown_tenth = tenth
    print(line(self.label, step, self.total, rate, evals), file=sys.stderr, flush=True)

  def _live(self, step: int, rate: float, evals: str) -> None:
    if self.bar is None:
      self.bar = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TextColumn("steps"),
                          TextColumn("{task.fields[rate]:.0f}/s ETA {task.fields[eta]:.0f}s {task.fields[evals]}"),
                          console=self.console, auto_refresh=False)
      self.task = self.bar.add_task(self.label, total=self.total, completed=self.start, rate=0.0, eta=0.0, evals="")
      self.bar.start()
    eta = (self.total - step) / max(rate, 1e-9)
    self.bar.update(self.task, completed=step, rate=rate, eta=eta, evals=evals, refresh=True)
    if step >= self.total:
      self.close()

  def close(self) -> None:
    if self.bar is not None:
      self.bar.stop()
      self.bar = None


def run_progress(total: int, quiet: bool = False, label: str = "", start: int = 0) -> Callable[[int, dict], None]:
  """The default progress of a run (:class:`RunProgress`); ``start``: the env steps a resumed run had
  already taken (not counted in its rate)."""
  return RunProgress(total, quiet, label, start)
