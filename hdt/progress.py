"""The progress of a training run, after every chunk: env steps, steps/s, ETA and the latest evaluation.

Where it is shown decides how (rich tells which): on a terminal, a live bar redrawn in place; in a log
(stderr not a terminal: a file, a pipe, CI) one line per update, ``low point [#####---] 5000/20000 steps
812/s ETA 18s return=12.3 success_max=0.5``, which scripts and tests parse; in Jupyter, the same rich
bar as one output of the cell, redrawn in place at most once a second (IPython's display handle, so
no ipywidgets are needed and a long run does not flood the notebook with a line per chunk). The rate
and ETA count only this process's steps, so a resumed run does not claim the steps it loaded.
"""

from __future__ import annotations

import io
import sys
import time
from typing import Callable

import numpy as np
from rich.console import Console
from rich.jupyter import JUPYTER_HTML_FORMAT, JupyterRenderable
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

from hdt.numfmt import number

EVALS = ("eval/return", "eval/success_max", "eval/goal_dist")  # shown, as return=... success_max=...
NOTEBOOK_EVERY = 1.0  # seconds between redraws of a notebook's bar (each is a message to the browser)


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
    live = self.console.is_terminal and not self.console.is_dumb_terminal
    self.mode = "quiet" if quiet else "notebook" if self.console.is_jupyter else "live" if live else "lines"
    self.bar = self.task = self.handle = None
    self.shown_at, self.stale = -float("inf"), False  # when the notebook's bar was last redrawn; behind since

  def __call__(self, step: int, metrics: dict) -> None:
    if self.mode == "quiet":
      return
    rate = (step - self.start) / max(time.perf_counter() - self.t0, 1e-9)
    evals = " ".join(f"{k[5:]}={number(float(np.mean(v)))}" for k, v in metrics.items() if k in EVALS)
    if self.mode == "live":
      self._live(step, rate, evals)
    elif self.mode == "notebook":
      self._notebook(step, rate, evals)
    else:
      print(line(self.label, step, self.total, rate, evals), file=sys.stderr, flush=True)

  def _update(self, step: int, rate: float, evals: str) -> None:
    """The rich bar (made on first use) at ``step``."""
    if self.bar is None:
      self.bar = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TextColumn("steps"),
                          TextColumn("{task.fields[rate]:.0f}/s ETA {task.fields[eta]:.0f}s {task.fields[evals]}"),
                          console=self.console, auto_refresh=False)
      self.task = self.bar.add_task(self.label, total=self.total, completed=self.start, rate=0.0, eta=0.0, evals="")
    eta = (self.total - step) / max(rate, 1e-9)
    self.bar.update(self.task, completed=step, rate=rate, eta=eta, evals=evals)

  def _live(self, step: int, rate: float, evals: str) -> None:
    started = self.bar is not None
    self._update(step, rate, evals)
    if not started:
      self.bar.start()
    self.bar.refresh()
    if step >= self.total:
      self.close()

  def _notebook(self, step: int, rate: float, evals: str) -> None:
    """One output in the cell, redrawn in place (an IPython display handle) at most every
    NOTEBOOK_EVERY seconds and at the end; rich's Live would need ipywidgets for the same."""
    from IPython.display import display
    self._update(step, rate, evals)
    now = time.perf_counter()
    if self.handle is None:
      self.handle = display(self._rendered(), display_id=True)
      if self.handle is None:  # no kernel to update it in place: a line per update instead
        self.mode = "lines"
    elif step >= self.total or now - self.shown_at >= NOTEBOOK_EVERY:
      self.handle.update(self._rendered())
    else:
      self.stale = True  # drawn at the next redraw, or by close()
      return
    self.shown_at, self.stale = now, False

  def _rendered(self) -> JupyterRenderable:
    """The bar as HTML (with rich's colours) and plain text, as rich shows a renderable in Jupyter."""
    out = Console(record=True, file=io.StringIO(), width=self.console.width, force_terminal=True,
                  color_system="truecolor")
    out.print(self.bar.get_renderable())
    return JupyterRenderable(out.export_html(inline_styles=True, code_format=JUPYTER_HTML_FORMAT, clear=False),
                             out.export_text())

  def close(self) -> None:
    if self.handle is not None and self.bar is not None and self.stale:  # a notebook shows where the run ended
      self.handle.update(self._rendered())
      self.stale = False
    if self.bar is not None:
      self.bar.stop()  # ends a live display (nothing to end in a notebook)
      self.bar = None


def run_progress(total: int, quiet: bool = False, label: str = "", start: int = 0) -> Callable[[int, dict], None]:
  """The default progress of a run (:class:`RunProgress`); ``start``: the env steps a resumed run had
  already taken (not counted in its rate)."""
  return RunProgress(total, quiet, label, start)
