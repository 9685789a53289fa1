"""Learning curves of finished runs as PNG + CSV (mean over seeds, ±1 std band): for RESULTS.md.

  PYTHONPATH=. python experiments/curves.py RUN [RUN ...] --metric success_max --out experiments/results/NAME
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from hdt import plots  # noqa: E402
from hdt.report import read_eval_curves  # noqa: E402


def main(argv=None):
  p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  p.add_argument("runs", nargs="+", help="run directories (label=RUN to name a line)")
  p.add_argument("--metric", default="success_max", help="eval column without 'eval/' (default success_max)")
  p.add_argument("--out", required=True, help="output path without extension (.png and .csv are written)")
  p.add_argument("--xlabel", default="HL decisions")
  p.add_argument("--title", default="")
  a = p.parse_args(argv)
  series, rows = {}, []
  for spec in a.runs:
    label, _, run = spec.rpartition("=") if "=" in spec else (Path(spec).name, "", spec)
    x, y = read_eval_curves(run)[f"eval/{a.metric}"]
    series[label] = (x, y)
    for t in range(len(x)):
      rows.append({"run": label, "x": x[t], "mean": float(np.mean(y[:, t])), "std": float(np.std(y[:, t])),
                   **{f"seed_{i}": float(y[i, t]) for i in range(y.shape[0])}})
  out = Path(a.out)
  plots.learning_curves(series, out.with_suffix(".png"), title=a.title, xlabel=a.xlabel, ylabel=a.metric)
  keys = list(dict.fromkeys(k for r in rows for k in r))
  with open(out.with_suffix(".csv"), "w", newline="") as f:
    w = csv.DictWriter(f, fieldnames=keys)
    w.writeheader()
    w.writerows(rows)
  print(out.with_suffix(".png"), out.with_suffix(".csv"))


if __name__ == "__main__":
  main()
