"""A run's progress: one line per update in a log (the format scripts parse), a live bar on a
terminal, one bar redrawn in place at most once a second in Jupyter; rate and ETA of this process only."""

import io

from rich.console import Console

from hdt import progress


def _console(**kw) -> Console:
  return Console(file=io.StringIO(), width=120, **kw)


def test_a_log_gets_one_line_per_update_counting_only_this_process_steps(monkeypatch, capsys):
  # a run resumed at 900k of 1M steps that took 10 s for its next 10k: 1000/s, ETA 90 s
  clock = iter([0.0, 10.0])
  monkeypatch.setattr(progress.time, "perf_counter", lambda: next(clock))
  show = progress.run_progress(1_000_000, label="low", start=900_000)
  assert show.mode == "lines"  # stderr is captured: not a terminal
  show(910_000, {"eval/return": [1.0, 2.0], "loss": [3.0]})
  line = capsys.readouterr().err
  assert line == "low [##################--] 910000/1000000 steps 1000/s ETA 90s return=1.5\n", line


def test_a_terminal_gets_a_live_bar_that_ends_with_the_run(capsys):
  console = _console(force_terminal=True)
  show = progress.RunProgress(100, label="low point", console=console)
  assert show.mode == "live"
  for step in (25, 50, 100):
    show(step, {"eval/success_max": [0.5]})
  assert show.bar is None  # stopped at the last step
  text = console.file.getvalue()
  assert "low point" in text and "100/100" in text and "success_max=0.5" in text
  assert capsys.readouterr().err == ""  # nothing line by line


class _Handle:
  """IPython's DisplayHandle: what the notebook shows."""

  def __init__(self, shown):
    self.shown = [shown]

  def update(self, shown):
    self.shown.append(shown)


def test_a_notebook_gets_one_rich_bar_redrawn_in_place_at_most_once_a_second(monkeypatch, capsys):
  import IPython.display
  handles, clock = [], {"now": 0.0}
  monkeypatch.setattr(IPython.display, "display", lambda obj, display_id: handles.append(_Handle(obj)) or handles[-1])
  monkeypatch.setattr(progress.time, "perf_counter", lambda: clock["now"])
  show = progress.RunProgress(1000, label="high", console=_console(force_jupyter=True))
  assert show.mode == "notebook"
  for step in range(10, 1001, 10):  # 100 chunks, 0.1 s each: 10 s
    clock["now"] += 0.1
    show(step, {"eval/return": [2.0]})
  show.close()
  assert len(handles) == 1 and capsys.readouterr().err == ""  # one output, no lines
  shown = handles[0].shown
  assert 10 <= len(shown) <= 12  # the first, about one a second, the last
  last = shown[-1]._repr_mimebundle_([], [])
  assert "high" in last["text/plain"] and "1000/1000" in last["text/plain"] and "return=2" in last["text/plain"]
  assert last["text/html"].startswith("<pre") and "1000/1000" in last["text/html"]


def test_a_run_that_stops_early_leaves_its_last_step_in_the_notebook(monkeypatch):
  import IPython.display
  handles = []
  monkeypatch.setattr(IPython.display, "display", lambda obj, display_id: handles.append(_Handle(obj)) or handles[-1])
  show = progress.RunProgress(1000, label="low", console=_console(force_jupyter=True))
  show(100, {})
  show(200, {})  # within the second: not drawn yet
  show.close()  # e.g. training diverged: the bar still ends at 200
  assert "200/1000" in handles[0].shown[-1]._repr_mimebundle_([], [])["text/plain"]


def test_without_a_kernel_to_redraw_in_a_forced_notebook_it_falls_back_to_lines(monkeypatch, capsys):
  import IPython.display
  monkeypatch.setattr(IPython.display, "display", lambda obj, display_id: None)  # what IPython gives outside a kernel
  show = progress.RunProgress(100, label="low", console=_console(force_jupyter=True))
  for step in (50, 100):
    show(step, {})
  assert show.mode == "lines" and capsys.readouterr().err.count("low [") == 1  # the second update as a line


def test_quiet_shows_nothing(capsys):
  show = progress.RunProgress(10, quiet=True, console=_console(force_terminal=True))
  show(10, {"eval/return": [1.0]})
  show.close()
  assert show.mode == "quiet" and capsys.readouterr().err == "" and show.console.file.getvalue() == ""
