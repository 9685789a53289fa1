"""Learning curves of finished runs as PNG + CSV (mean over seeds, ±1 std band): for RESULTS.md.

  PYTHONPATH=. python experiments/studies/curves.py RUN [RUN ...] --metric success_max --out experiments/results/NAME

A RUN is a run directory, ``label=RUN_DIR``, or ``label=FILE.csv#name``: the series ``name`` of a CSV this
script wrote before (for a run whose directory is gone). ``--hline label=value`` draws a reference level;
``--xscale label=factor`` multiplies a series' x (e.g. a Full run's env steps by 1/k, onto HL decisions).
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import numpy as np

from hdt import plots
from hdt.report import write_csv
from hdt.report import read_eval_curves


def from_csv(path: str, name: str) -> tuple[np.ndarray, np.ndarray]:
  """``(x[T], y[S, T])`` of series ``name`` in a CSV written by this script."""
  with open(path) as f:
    rows = [r for r in csv.DictReader(f) if r["run"] == name]
  if not rows:
    raise ValueError(f"{path} has no series {name!r}")
  seeds = sorted((k for k in rows[0] if k.startswith("seed_") and rows[0][k] != ""), key=lambda k: int(k[5:]))
  return np.array([float(r["x"]) for r in rows]), np.array([[float(r[k]) for r in rows] for k in seeds])


def budget_unit(run: str) -> str | None:
  """What a run directory's budget counts ("env steps" or "HL decisions"), None if it does not say."""
  path = Path(run.split("#", 1)[0]) / "config.json"
  if "#" in run or not path.exists():
    return None
  return json.loads(path.read_text()).get("budget_unit")


def main(argv=None):
  p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  p.add_argument("runs", nargs="+", help="run directories (label=RUN to name a line)")
  p.add_argument("--metric", default="success_max", help="eval column without 'eval/' (default success_max)")
  p.add_argument("--out", required=True, help="output path without extension (.png and .csv are written)")
  p.add_argument("--xlabel", help="default: what the runs' budgets count (config.json's budget_unit), "
                                   "else HL decisions")
  p.add_argument("--title", default="")
  p.add_argument("--hline", action="append", default=[], help="label=value: a dashed reference level")
  p.add_argument("--xmax", type=float, default=None, help="drop points beyond this x")
  p.add_argument("--xscale", action="append", default=[],
                 help="label=factor: multiply that series' x, e.g. Full=0.03125 (env steps / k 32)")
  a = p.parse_args(argv)
  xscale = {k: float(v) for k, _, v in (s.rpartition("=") for s in a.xscale)}
  series, rows, units = {}, [], set()
  for spec in a.runs:
    label, _, run = spec.rpartition("=") if "=" in spec else (Path(spec).name, "", spec)
    x, y = from_csv(*run.split("#", 1)) if "#" in run else read_eval_curves(run)[f"eval/{a.metric}"]
    units.add(budget_unit(run))
    x = x * xscale.get(label, 1.0)
    if a.xmax is not None:
      x, y = x[x <= a.xmax], y[:, x <= a.xmax]
    series[label] = (x, y)
    for t in range(len(x)):
      rows.append({"run": label, "x": x[t], "mean": float(np.mean(y[:, t])), "std": float(np.std(y[:, t])),
                   **{f"seed_{i}": float(y[i, t]) for i in range(y.shape[0])}})
  out = Path(a.out)
  hline = {k: float(v) for k, _, v in (h.rpartition("=") for h in a.hline)}
  plots.learning_curves(series, out.with_suffix(".png"), hline=hline, title=a.title,
                        xlabel=a.xlabel or (units.pop() if len(units) == 1 and None not in units else "HL decisions"),
                        ylabel=a.metric)
  keys = list(dict.fromkeys(k for r in rows for k in r))
  write_csv(out.with_suffix(".csv"), keys, rows)
  print(out.with_suffix(".png"), out.with_suffix(".csv"))


if __name__ == "__main__":
  main()
