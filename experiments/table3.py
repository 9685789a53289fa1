"""Table 3 (Steps): where hierarchical transfer is not optimal. The ant can climb the low barriers of
the half-size U-maze, the point mass cannot.

  PYTHONPATH=. python experiments/table3.py --preset cpu     # this 2-core machine, < 1 hour (tiny ant)
  PYTHONPATH=. python experiments/table3.py --preset smoke   # minutes, plumbing only

A = point mass: LL on reach, HL on ``steps`` over it. B = ant with 16 rangefinders: LL pretrained on
reach over random steps (``train_low("ant", terrain="steps")``). Success on the maze end goal of:
zero-shot (PM HL on the ant LL), plain finetuning and KL finetuning of the PM HL (β = 0.01, lr 1e-3,
the paper's Maze values), and an HL trained from scratch on the ant LL, each for the same ant samples.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run as a script or loaded by path
from experiments import common as C  # noqa: E402

STUDY = C.FinetuneStudy("table3", a="point", b="ant", task="steps",
                        methods=("finetune", "finetune_kl", "scratch"), b_low=(("terrain", "steps"),),
                        title="PM → Ant Steps")
PAPER = {"zero_shot": ".32 ± .16", "finetune": ".53 ± .09", "finetune_kl": ".52 ± .13",
         "scratch": ".59 ± .05"}

PRESETS = C.NAV_PM_TO_ANT_PRESETS


run, markdown, main = C.study_interface(STUDY, PRESETS, PAPER, __doc__)

if __name__ == "__main__":
  sys.exit(main())
