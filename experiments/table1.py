"""Table 1 (zero-shot hierarchical transfer), PM rows and the arm BlockPush 1 diagonal.

  python experiments/table1.py --preset cpu     # this 2-core machine, well under an hour
  python experiments/table1.py --preset smoke   # seconds-scale plumbing check

Trains LLs on `reach` and HLs on each task over their own LL, then evaluates the composed policies
(mean ± std across seeds, `episodes` deterministic episodes per seed) next to the paper's numbers.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from hdt.transfer import configs
from hdt.transfer.evaluate import compose, evaluate
from hdt.transfer.pipeline import train_high, train_low

PAPER = {("point", "waypoint"): "1021 ± 43", ("point", "maze_end"): ".80", ("point", "maze_sample"): ".96",
         ("arm_point", "push1"): ".99", ("arm3", "push1"): ".96", ("arm4", "push1"): ".89"}

PRESETS = {  # LL env steps, HL steps (HL decisions), seeds, eval episodes
    "smoke": dict(low={"point": 2000, "manip": 1000}, high=500, seeds=1, episodes=4),
    "cpu": dict(low={"point": 20_000, "manip": 60_000}, high=6000, seeds=2, episodes=50),
}


def main():
  p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  p.add_argument("--preset", choices=list(PRESETS), default="cpu")
  p.add_argument("--out", type=Path, default=Path("runs/table1"))
  p.add_argument("--agents", nargs="*", default=["point", "arm_point", "arm3", "arm4"])
  a = p.parse_args()
  pr = PRESETS[a.preset]
  results = {}
  res_path = Path("experiments/results") / f"table1_{a.preset}.json"
  for agent in a.agents:
    t0 = time.time()
    steps = pr["low"]["point" if agent == "point" else "manip"]
    low_cfg = configs.low_config(agent, total_env_steps=steps, num_envs=8, updates_per_step=8,
                                 steps_per_chunk=max(1, steps // 8 // 10), num_eval_episodes=16)
    low = train_low(agent, low_cfg, seeds=pr["seeds"], out=a.out / f"{agent}_low")
    tasks = [("waypoint", {}), ("maze", {"goal": "sample"})] if agent == "point" else [("push1", {})]
    for task, kw in tasks:
      k = low.meta["k"]
      hcfg = configs.high_config(task, k, total_env_steps=pr["high"], num_envs=8, updates_per_step=8,
                                 steps_per_chunk=max(1, pr["high"] // 8 // 5), num_eval_episodes=8)
      high = train_high(task, low.run_dir, hcfg, seeds=pr["seeds"], out=a.out / f"{agent}_high_{task}", **kw)
      pol = compose(high.run_dir, low.run_dir)
      evals = [(task, {})] if task != "maze" else [("maze_end", {"goal": "end"}), ("maze_sample", {"goal": "sample"})]
      for name, ekw in evals:
        ev = evaluate(pol, task, episodes=pr["episodes"], **ekw)
        metric = "return" if task == "waypoint" else "success"
        results[f"{agent}/{name}"] = dict(metric=metric, mean=ev[f"{metric}_mean"], std=ev[f"{metric}_std"],
                                          per_seed=ev["per_seed"][metric].tolist(), paper=PAPER.get((agent, name)),
                                          low_steps=steps, high_steps=pr["high"], seeds=pr["seeds"],
                                          episodes=pr["episodes"])
        print(name, agent, results[f"{agent}/{name}"], flush=True)
    results[f"{agent}/minutes"] = (time.time() - t0) / 60
    res_path.write_text(json.dumps(results, indent=1))
  print(markdown(results, a.preset))


def markdown(results: dict, preset: str) -> str:
  """Rows of RESULTS.md: hdt at this preset next to the paper."""
  lines = ["| LL agent | HL from | task | metric | hdt (mean ± std over seeds) | paper |", "|---|---|---|---|---|---|"]
  for key, r in results.items():
    if key.endswith("/minutes"):
      continue
    agent, task = key.split("/")
    lines.append(f"| {agent} | {agent} | {task} | {r['metric']} | {r['mean']:.3g} ± {r['std']:.2g} "
                 f"(seeds {', '.join(f'{v:.3g}' for v in r['per_seed'])}) | {r['paper']} |")
  return "\n".join(lines)

if __name__ == "__main__":
  main()
