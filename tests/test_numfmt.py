"""Numbers as hdt's tables, heatmaps and progress lines show them."""

from hdt import progress
from hdt.numfmt import mean_std, number


def test_a_return_past_a_thousand_reads_whole_not_in_e_notation():
  assert mean_std(1004.87, 75.0) == "1005 ± 75"
  assert mean_std(-82.3, 128.6) == "-82.3 ± 129"
  assert number(1126.1) == "1126"
  assert mean_std(999.7, 99.7) == "1000 ± 100"  # rounding up to the next power of ten


def test_rates_keep_three_significant_digits():
  assert mean_std(0.90667, 0.0377) == "0.907 ± 0.038"
  assert number(0.0001234) == "0.000123"


def test_a_progress_line_shows_a_large_return_whole(capsys):
  show = progress.run_progress(100, label="high")
  show(100, {"eval/return": [1004.9]})
  assert "return=1005" in capsys.readouterr().err
