"""The one-off studies of experiments/studies/ that other tests do not cover."""

import csv
import json

import pytest


def test_bars_plots_matrix_cells_beside_the_paper(tmp_path):
  from experiments.studies import bars
  m = tmp_path / "matrix_push1.json"
  m.write_text(json.dumps({"cells": {"plain|PM": [0.1, 0.02, "success"], "aligned|PM": [0.3, 0.1, "success"]}}))
  out = tmp_path / "t2"
  bars.main([f"PM->3Link|plain|0.17={m}#plain|PM", f"PM->3Link|aligned|0.34={m}#aligned|PM", "--out", str(out)])
  rows = list(csv.DictReader(open(out.with_suffix(".csv"))))
  assert [(r["method"], float(r["mean"]), float(r["paper"])) for r in rows] == [("plain", 0.1, 0.17), ("aligned", 0.3, 0.34)]
  assert out.with_suffix(".png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
  # a bar taken back from the CSV (its eval directory gone) keeps its numbers and source
  bars.main([f"PM->3Link|aligned|-={out.with_suffix('.csv')}#PM->3Link|aligned", "--out", str(tmp_path / "again")])
  (row,) = csv.DictReader(open(tmp_path / "again.csv"))
  assert float(row["mean"]) == 0.3 and row["paper"] == "" and row["source"].endswith("#aligned|PM")
  one = tmp_path / "eval_push1.json"  # one HL over one LL
  one.write_text(json.dumps({"success_mean": 0.05, "success_std": 0.07, "per_seed": {}}))
  bars.main([f"PM->3Link|aligned|0.34={one}#success", "--out", str(tmp_path / "one")])
  (row,) = csv.DictReader(open(tmp_path / "one.csv"))
  assert (float(row["mean"]), float(row["std"])) == (0.05, 0.07)
  with pytest.raises(SystemExit, match="no cell 'x'"):
    bars.main([f"g|m|-={m}#x", "--out", str(tmp_path / "bad")])


def test_ll_speed_ceiling_is_the_share_of_goals_within_reach():
  """The goals an LL can reach at a speed: those uniform in the ±delta_max box within its radius."""
  import math

  from experiments.studies.ll_speed import reach_ceiling
  assert reach_ceiling(2.0, 4.0) == pytest.approx(math.pi * 4 / 64, abs=0.005)
  assert reach_ceiling(4.0 * math.sqrt(2), 4.0) == 1.0 and reach_ceiling(0.0, 4.0) == 0.0
