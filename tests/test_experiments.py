"""The experiment-module interface (``hdt reproduce NAME``): fig5 end to end at its tiny test preset."""

import csv
import json
from pathlib import Path

import pytest

from hdt import cli





@pytest.mark.parametrize("name", ["table1", "table2", "table3", "fig5", "fig6"])
def test_interface(name):
  mod = cli.load_experiment(name)
  assert {"smoke", "cpu", "paper"} <= set(mod.PRESETS)
  assert callable(mod.run) and callable(mod.markdown) and callable(mod.main)


@pytest.mark.slow  # 7 trainings (A's LL and HL, B's LL, four methods): compile-bound, minutes here
def test_fig5_writes_curves_png_and_results(tmp_path, monkeypatch):
  fig5 = cli.load_experiment("fig5")
  from experiments import common
  monkeypatch.setattr(common, "RESULTS", tmp_path / "results")  # keep experiments/results clean
  res = fig5.run("test", out=tmp_path / "runs", quiet=True)
  saved = json.loads((tmp_path / "results" / "fig5_test.json").read_text())
  assert saved["methods"].keys() == res["methods"].keys() == {"finetune_kl", "finetune", "scratch", "full"}
  for m, r in saved["methods"].items():
    (path,) = r["csv"]
    assert Path(path).name == f"{m}_seed0.csv"
    rows = list(csv.DictReader(open(path)))
    assert list(rows[0]) == ["env_steps", "success", "return"] and len(rows) >= 2
    xs = [float(r["env_steps"]) for r in rows]
    assert xs[0] == 0 and xs[-1] == saved["b_env_steps"]  # B's env samples, HL steps x k or env steps
    assert all(0 <= float(r["success"]) <= 1 for r in rows)
  png = Path(saved["png"])
  assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
  md = fig5.markdown(saved)
  assert "| zero-shot |" in md and ".17" in md and "hdt reproduce fig5 --preset test" in md


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
