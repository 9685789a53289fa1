"""Finetuning curves, PM → Ant Waypoint (paper Figure 6, first panel; the other panels, Ant Maze End /
Sample and Quadruped Maze Sample, are the same study with another ``STUDY``).

  PYTHONPATH=. python experiments/fig6.py --preset cpu     # this 2-core machine, < 1 hour
  PYTHONPATH=. python experiments/fig6.py --preset smoke   # minutes, plumbing only

Same methods and outputs as fig5 (``experiments.common.finetune_study``): KL finetuning (β = 1
annealed to 0 over the first 50%, lr 0.01), plain finetuning, HL from scratch on the ant's LL, Full;
metric = Waypoint return; the dashed line is the zero-shot return of the PM HL on the ant LL.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run as a script or loaded by path
from experiments import common as C  # noqa: E402

STUDY = C.FinetuneStudy("fig6", a="point", b="ant", task="waypoint",
                        title="PM → Ant Waypoint: finetuning from the PM HL")
PAPER = {"zero_shot": "483 ± 39", "finetune_kl": "best curve", "finetune": "curve",
         "scratch": "476 ± 19 (Ant HL on Ant LL, Table 1)", "full": "fails (no hierarchy)"}

PRESETS = {  # ant LL budgets are tiny here: the paper's is 2.5M env steps
    "smoke": dict(low={"point": 1000, "legged": 1000}, high=100, ft=100, seeds=1, episodes=2, evals=2),
    "cpu": dict(low={"point": 20_000, "legged": 40_000}, high=4000, ft=1500, seeds=2, episodes=20, evals=5),
    "paper": dict(low={}, high=None, ft=None, seeds=5, episodes=100, evals=20, train_episodes=20),
}


run, markdown, main = C.study_interface(STUDY, PRESETS, PAPER, __doc__)

if __name__ == "__main__":
  sys.exit(main())
