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

PRESETS = C.NAV_PM_TO_ANT_PRESETS


run, markdown, main = C.study_interface(STUDY, PRESETS, PAPER, __doc__)

if __name__ == "__main__":
  sys.exit(main())
