"""Grouped bars of evaluated cells beside the paper's numbers (PNG + CSV), e.g. Table 2's plain vs aligned.

  PYTHONPATH=. python experiments/studies/bars.py --out experiments/results/NAME \\
      "GROUP|METHOD|PAPER=MATRIX.json#CELL" ...

Each bar is one cell of a matrix JSON that ``hdt eval`` wrote (``CELL`` as in its ``cells``, e.g.
``plain|PM`` = the LL named plain under the HL named PM), a metric of a one-pair eval JSON
(``eval_push1.json#success``), or ``GROUP|METHOD|PAPER=FILE.csv#GROUP|METHOD``
to take a row of a CSV this script wrote before (for an eval whose directory is gone). PAPER is the
paper's number for that cell (``-`` for none); it is drawn as a black tick on the bar.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

from hdt import plots
from hdt.report import write_csv

FIELDS = ("group", "method", "mean", "std", "paper", "source")


def read_bar(spec: str) -> dict:
  """One bar from ``GROUP|METHOD|PAPER=FILE#CELL``."""
  label, _, source = spec.partition("=")
  parts = label.split("|")
  if len(parts) != 3 or "#" not in source:
    raise SystemExit(f"bar {spec!r}: write GROUP|METHOD|PAPER=FILE#CELL (PAPER may be -)")
  group, method, paper = parts
  path, _, cell = source.rpartition("#")
  if path.endswith(".csv"):
    with open(path) as f:
      rows = [r for r in csv.DictReader(f) if f"{r['group']}|{r['method']}" == cell]
    if not rows:
      raise SystemExit(f"{path} has no bar {cell!r}")
    mean, std, source = float(rows[0]["mean"]), float(rows[0]["std"]), rows[0]["source"]
  else:
    saved = json.loads(Path(path).read_text())
    if "cells" in saved:  # a matrix: CELL is "LL|HL"
      if cell not in saved["cells"]:
        raise SystemExit(f"{path} has no cell {cell!r}; it has {sorted(saved['cells'])}")
      mean, std = saved["cells"][cell][:2]
    elif f"{cell}_mean" in saved:  # one HL over one LL: CELL is the metric
      mean, std = saved[f"{cell}_mean"], saved[f"{cell}_std"]
    else:
      raise SystemExit(f"{path} has no cell or metric {cell!r}")
  return dict(group=group, method=method, mean=mean, std=std, paper=None if paper == "-" else float(paper),
              source=source)


def main(argv=None):
  p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  p.add_argument("bars", nargs="+", help="GROUP|METHOD|PAPER=MATRIX.json#CELL")
  p.add_argument("--out", required=True, help="output path without extension (.png and .csv are written)")
  p.add_argument("--title", default="")
  p.add_argument("--ylabel", default="success")
  args = p.parse_args(argv)
  bars = [read_bar(s) for s in args.bars]
  out = Path(args.out)
  write_csv(out.with_suffix(".csv"), FIELDS, ({k: ("" if b[k] is None else b[k]) for k in FIELDS} for b in bars))
  png = plots.grouped_bars(bars, out.with_suffix(".png"), title=args.title, ylabel=args.ylabel)
  print(f"wrote {png} and {out.with_suffix('.csv')}")


if __name__ == "__main__":
  main()
