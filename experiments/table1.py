"""Table 1 (zero-shot hierarchical transfer), PM rows and the arm BlockPush 1 diagonal.

  PYTHONPATH=. python experiments/table1.py --preset cpu     # this 2-core machine, well under an hour
  PYTHONPATH=. python experiments/table1.py --preset smoke   # minutes, plumbing only

Trains LLs on `reach` and HLs on each task over their own LL, then evaluates the composed policies
(mean ± std across seeds, `episodes` deterministic episodes per seed) next to the paper's numbers.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run as a script or loaded by path
from experiments import common as C  # noqa: E402

PAPER = {("point", "waypoint"): "1021 ± 43", ("point", "maze_end"): ".80", ("point", "maze_sample"): ".96",
         ("arm_point", "push1"): ".99", ("arm3", "push1"): ".96", ("arm4", "push1"): ".89"}
AGENTS = ["point", "arm_point", "arm3", "arm4"]
TASKS = {"point": [("waypoint", {}, [("waypoint", {})]),
                   ("maze", {"goal": "sample"}, [("maze_end", {"goal": "end"}), ("maze_sample", {"goal": "sample"})])]}
MANIP_TASKS = [("push1", {}, [("push1", {})])]  # (task, training options, [(row name, eval options)])

PRESETS = {  # seeds and eval episodes; budgets: hdt.transfer.configs at the same preset (hdt train --preset)
    "smoke": dict(seeds=1, episodes=4),
    "cpu": dict(seeds=2, episodes=50),
    "paper": dict(seeds=5, episodes=100),
}


def run(preset: str = "cpu", out: Path = Path("runs/table1"), seeds: int | None = None,
        quiet: bool = False, agents: list[str] | None = None) -> dict:
  pr, out = C.experiment_preset(PRESETS, preset), Path(out)
  seeds = seeds or pr["seeds"]
  results = {"preset": preset}
  for agent in agents or AGENTS:
    t0 = time.time()
    low = C.low(agent, pr, out, seeds, quiet)
    for task, kw, evals in TASKS.get(agent, MANIP_TASKS):
      high = C.high(task, low, pr, out, seeds, quiet, **kw)
      for name, ekw in evals:
        r = C.eval_hl(high, low, task, pr["episodes"], **ekw)
        results[f"{agent}/{name}"] = dict(
            metric=r["metric"], mean=r["mean"], std=r["std"], per_seed=r["per_seed"],
            paper=PAPER.get((agent, name)), low_steps=C.low_cfg(agent, pr).total_env_steps,
            high_steps=high.card.sac["total_env_steps"], seeds=seeds, episodes=pr["episodes"])
        print(name, agent, results[f"{agent}/{name}"], file=sys.stderr, flush=True)
    results[f"{agent}/minutes"] = (time.time() - t0) / 60
    C.write_result("table1", preset, results)
  return results


def markdown(result: dict) -> str:
  """The rows of RESULTS.md's Table 1: hdt at this preset next to the paper."""
  lines = ["| LL agent | HL from | task | metric | hdt (mean ± std over seeds) | paper |", "|---|---|---|---|---|---|"]
  for key, r in result.items():
    if not isinstance(r, dict):  # "preset", "<agent>/minutes"
      continue
    agent, task = key.split("/")
    lines.append(f"| {agent} | {agent} | {task} | {r['metric']} | {r['mean']:.3g} ± {r['std']:.2g} "
                 f"(seeds {', '.join(f'{v:.3g}' for v in r['per_seed'])}) | {r['paper']} |")
  lines += ["", f"Command: `{C.command('table1', result.get('preset', 'cpu'))}`"]
  return "\n".join(lines)


main = C.make_main("table1", PRESETS, run, markdown, __doc__,
                   extra=lambda p: p.add_argument("--agents", nargs="*", default=AGENTS))

if __name__ == "__main__":
  sys.exit(main())
