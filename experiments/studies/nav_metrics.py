"""Every metric of a hierarchy's evaluation rollout (falls, sub-goal distances, episode length), not only
return and success: for explaining a navigation cell.

  python experiments/studies/nav_metrics.py HIGH LOW [LOW ...] --task maze [--set goal=end] [--episodes 50] [--seed 0]

Runs hdt.transfer.evaluate.evaluate for one HL seed and prints, per LL, the means over episodes that its rollout
computes (``k``: mean over steps, ``k_max``/``k_final``: per episode, then averaged).
"""

from __future__ import annotations

import argparse

import jax
import numpy as np

from hdt.transfer import evaluate as ev


def metrics(high: str, low: str, task: str, episodes: int, seed: int, **task_kw) -> dict:
  captured = {}
  get = jax.device_get

  def keep(x):  # evaluate() reduces its rollout's metrics to return and success; keep the rest
    out = get(x)
    if isinstance(out, dict) and "return" in out:
      captured.update(out)
    return out

  jax.device_get = keep
  try:
    ev.evaluate(ev.compose(high, low), task, episodes=episodes, seeds=[seed], **task_kw)
  finally:
    jax.device_get = get
  return {k: float(np.asarray(v).ravel()[0]) for k, v in captured.items()}


if __name__ == "__main__":
  p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  p.add_argument("high")
  p.add_argument("lows", nargs="+")
  p.add_argument("--task", required=True)
  p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
  p.add_argument("--episodes", type=int, default=50)
  p.add_argument("--seed", type=int, default=0)
  a = p.parse_args()
  kw = dict(s.split("=", 1) for s in a.set)
  for low in a.lows:
    m = metrics(a.high, low, a.task, a.episodes, a.seed, **kw)
    print(low, ", ".join(f"{k} {v:.3f}" for k, v in sorted(m.items())))
