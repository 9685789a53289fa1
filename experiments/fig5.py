"""Finetuning curves, PM → 3Link BlockPush 1 (paper Figure 7, second panel; "fig5" in hdt's naming).

  PYTHONPATH=. python experiments/fig5.py --preset cpu     # this 2-core machine, < 1 hour
  PYTHONPATH=. python experiments/fig5.py --preset smoke   # minutes, plumbing only

A = manipulation point mass (LL on reach, HL on push1), B = 3-link arm (LL on reach). Four methods
for the same number of B's env samples: KL-regularised finetuning of A's HL (β = 1 annealed to 0 over
the first 50%, lr 0.01), plain finetuning, HL from scratch on B's LL, and Full (flat SAC); the
zero-shot level (A's HL on B's LL, no training) is the dashed line. Writes
experiments/results/fig5_<preset>.json, fig5_<preset>/<method>_seed<i>.csv and fig5_<preset>.png.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run as a script or loaded by path
from experiments import common as C  # noqa: E402

STUDY = C.FinetuneStudy("fig5", a="arm_point", b="arm3", task="push1",
                        title="PM → 3Link BlockPush 1: finetuning from the PM HL")
# The paper shows curves only; its text: KL finetuning is at least 2x faster than plain finetuning on
# BlockPush, both beat the HL from scratch; zero-shot PM HL on the 3Link LL .17 (Table 1).
PAPER = {"zero_shot": ".17", "finetune_kl": "fastest (≥ 2× plain finetune)", "finetune": "curve",
         "scratch": "slower", "full": "slower (succeeds eventually)"}

PRESETS = {  # HL decisions of each method (ft) and evaluations over it; other budgets: hdt.transfer.configs
    "test": dict(sac="smoke", ft=64, seeds=1, episodes=2, evals=1),  # tests only
    "smoke": dict(ft=200, seeds=1, episodes=4, evals=2),
    "cpu": dict(ft=3000, seeds=2, episodes=50, evals=5),  # A's and B's runs = table1's
    "paper": dict(ft=None, seeds=5, episodes=100, evals=20),
}


run, markdown, main = C.study_interface(STUDY, PRESETS, PAPER, __doc__)

if __name__ == "__main__":
  sys.exit(main())
