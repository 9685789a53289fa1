"""Which seed decides a zero-shot transfer: every HL seed over every LL seed.

``hdt eval`` pairs HL seed i with LL seed i, so a seed at 0 may be the HL's fault or the LL's. Here
HL seed h drives LL seed (h + s) mod n_LL for every shift s; shift 0 is exactly ``hdt eval``'s pairing
and episodes (same keys). Writes a CSV (one row per HL seed, LL seed) and a heatmap per LL run.

  PYTHONPATH=. python experiments/studies/seed_cross.py --high zoo:arm2/push1_500k --task push1 --episodes 100 \\
      --low plain=zoo:arm3/low --low online=runs/arm3_aligned_arm2_online --out experiments/results/NAME
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import jax
import numpy as np

from hdt import plots
from hdt.report import write_csv
from hdt.transfer import checkpoint as ckpt
from hdt.transfer import evaluate as ev


def cross(high: str, low: str, task: str, episodes: int) -> tuple[np.ndarray, str]:
  """(metric[h, l] of HL seed h over LL seed l, the metric's name: the task's own, success or return)."""
  hp, hmetas = ckpt.load_all(high, "final")
  lp, lmetas = ckpt.load_all(low, ev.LOW_PARAMS)
  base = ev.compose(high, low)  # checks the pair and builds the cards
  nh, nl = len(hmetas), len(lmetas)
  take = lambda tree, idx: None if tree is None else jax.tree.map(lambda x: x[idx], tree)
  out, metric = np.full((nh, nl), np.nan), None
  for s in range(nl):
    hi, lo = np.arange(nh), (np.arange(nh) + s) % nl
    pol = dataclasses.replace(base, params=take(hp["policy"], hi), obs_norm=take(hp.get(ckpt.NORM), hi),
                              low_params=take(lp["policy"], lo), low_obs_norm=take(lp.get(ckpt.NORM), lo))
    res = ev.evaluate(pol, task, episodes=episodes)
    metric = res["metric"]
    out[hi, lo] = res["per_seed"][metric]
    print(f"  {low} shift {s}: " + ", ".join(f"HL{h}/LL{l} {v:.3g}" for h, l, v in zip(hi, lo, out[hi, lo])),
          flush=True)
  return out, metric


def main(argv=None):
  p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  p.add_argument("--high", required=True)
  p.add_argument("--low", action="append", required=True, metavar="NAME=RUN")
  p.add_argument("--task", required=True)
  p.add_argument("--episodes", type=int, default=100)
  p.add_argument("--out", required=True, help="output path without extension (.csv and _NAME.png are written)")
  args = p.parse_args(argv)
  rows = []
  for spec in args.low:
    name, _, run = spec.partition("=")
    m, metric = cross(args.high, run, args.task, args.episodes)
    rows += [dict(low=name, hl_seed=h, ll_seed=l, metric=metric, value=f"{m[h, l]:.4f}") for h in range(m.shape[0])
             for l in range(m.shape[1])]
    cells = {(f"LL seed {l}", f"HL seed {h}"): (m[h, l], 0.0, metric) for h in range(m.shape[0])
             for l in range(m.shape[1])}
    plots.heatmap(dict(rows=[f"LL seed {l}" for l in range(m.shape[1])], cols=[f"HL seed {h}" for h in range(m.shape[0])],
                       cells=cells, task=args.task), f"{args.out}_{name}.png",
                  title=f"{args.task}: HL {args.high} over LL {name} ({run}), {metric} per seed pair",
                  xlabel=f"seed of the HL ({args.high})", ylabel=f"seed of the LL ({name})")
    print(f"{name}: mean {np.mean(m):.3f}; per LL seed {np.round(m.mean(0), 3).tolist()}; "
          f"per HL seed {np.round(m.mean(1), 3).tolist()}", flush=True)
  write_csv(Path(args.out + ".csv"), ("low", "hl_seed", "ll_seed", "metric", "value"), rows)


if __name__ == "__main__":
  main()
