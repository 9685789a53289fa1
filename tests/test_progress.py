"""A run's progress: one line per update in a log (the format scripts parse), a live bar on a
terminal, a line per tenth of the run in Jupyter without widgets; rate and ETA of this process only."""

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


def test_jupyter_without_widgets_gets_a_line_per_tenth(monkeypatch, capsys):
  monkeypatch.setattr(progress.importlib.util, "find_spec", lambda name: None)  # no ipywidgets
  show = progress.RunProgress(1000, label="high", console=_console(force_jupyter=True))
  assert show.mode == "tenths"
  for step in range(10, 1001, 10):  # 100 chunks
    show(step, {})
  lines = capsys.readouterr().err.splitlines()
  assert len(lines) == 11 and lines[-1].startswith("high [####################] 1000/1000 steps")


def test_quiet_shows_nothing(capsys):
  show = progress.RunProgress(10, quiet=True, console=_console(force_terminal=True))
  show(10, {"eval/return": [1.0]})
  show.close()
  assert show.mode == "quiet" and capsys.readouterr().err == "" and show.console.file.getvalue() == ""
