"""How well an LL follows an HL's sub-goals, per (HL, LL) pair over zoo or run policies: the tip's
distance to the sub-goal when the HL step ends, how often it gets within the HL step's epsilon, how
many LL steps an HL step takes, and how far the block moves (RESULTS.md, Table 1 notes).

  PYTHONPATH=. python experiments/studies/ll_tracking.py --high PM=zoo:arm_point/push1 \\
      --low 3Link400k=zoo:arm3/low --low 3Link1p2m=zoo:arm3/low_paper --task push1 --episodes 16
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from hdt.transfer.evaluate import hl_rollouts


def track(high: str, low: str, task: str, episodes: int = 16, key: int = 1) -> list[dict]:
  """Per LL seed: tracking statistics of ``high``'s deterministic episodes over ``low`` (seed i of each)."""
  record = lambda s, n: (s.obs_hi, n.metrics["sub_goal_dist"], n.metrics["ll_steps"], n.metrics["success"], n.done)
  rows = []
  for i, (env, (hi, dist, ll_steps, succ, done)) in enumerate(hl_rollouts(high, low, record, episodes, key)):
    live = np.cumsum(done, 1) - done == 0  # HL steps up to and including the episode's last
    block = hi[..., 2:4]
    moved = np.linalg.norm(np.where(live[..., None], block - block[:, :1], 0.0), axis=-1).max(1)
    rows.append(dict(seed=i, success=float((succ * live).max(1).mean()),
                     sub_goal_dist=float(dist[live].mean()), within_eps=float((dist[live] < env.eps).mean()),
                     ll_steps=float(ll_steps[live].mean()), block_moved=float(moved.mean())))
  return rows


def main(argv=None):
  p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  p.add_argument("--high", action="append", required=True, help="NAME=RUN (repeatable)")
  p.add_argument("--low", action="append", required=True, help="NAME=RUN (repeatable)")
  p.add_argument("--task", required=True)
  p.add_argument("--episodes", type=int, default=16)
  a = p.parse_args(argv)
  print("| HL | LL | success | tip–sub-goal distance at the HL step's end (m) | within ε | LL steps per HL step "
        "| block moved (m) |\n|---|---|---|---|---|---|---|")
  for h in a.high:
    hn, _, hr = h.rpartition("=")
    for lo in a.low:
      ln, _, lr = lo.rpartition("=")
      rows = track(hr, lr, a.task, a.episodes)
      m = {k: np.mean([r[k] for r in rows]) for k in rows[0] if k != "seed"}
      print(f"| {hn} | {ln} | {m['success']:.2f} | {m['sub_goal_dist']:.4f} | {m['within_eps']:.2f} | "
            f"{m['ll_steps']:.1f} | {m['block_moved']:.3f} |", flush=True)


if __name__ == "__main__":
  sys.exit(main())
