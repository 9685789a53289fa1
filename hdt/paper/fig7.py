"""Figure 7: finetuning on BlockPush 1: 2Link, 3Link and 4Link from the PM, and 4Link from the 3Link.
Per panel: A's HL over B's LL zero-shot, then KL finetuning (β 1 annealed to 0 over the first half,
lr 0.01), plain finetuning, B's HL from scratch and Full, for the same env steps of B (the paper
preset: 100k HL decisions per method, the authors' finetuning default)."""

from __future__ import annotations

import dataclasses

from hdt.paper.runs import PRESETS, High, Low, Preset
from hdt.paper.table import Part, Table, finetune_part

A_HIGH = {"arm_point": High("push1", Low("arm_point", zoo="arm_point/low"), zoo="arm_point/push1"),
          "arm3": High("push1", Low("arm3", zoo="arm3/low_paper"), zoo="arm3/push1_500k")}
ZOO_LOW = {"arm2": "arm2/low_paper", "arm3": "arm3/low_paper", "arm4": "arm4/low_paper"}
# name: (A, B, title, the zero-shot level of Table 1 / Appendix E, zoo entries of its methods)
PANELS = {"pm_2link": ("arm_point", "arm2", "2Link from PM (success)", ".36 ± .14",
                       {"finetune_kl": "arm2/push1_ft_kl_from_pm"}),
          "pm_3link": ("arm_point", "arm3", "3Link from PM (success)", ".17 ± .08",
                       {"finetune_kl": "arm3/push1_ft_kl_from_pm"}),
          "pm_4link": ("arm_point", "arm4", "4Link from PM (success)", ".24 ± .11", {}),
          "3link_4link": ("arm3", "arm4", "4Link from 3Link (success)", ".10 ± .05",
                          {"finetune_kl": "arm4/push1_ft_kl_from_arm3"})}
WORDS = {"finetune_kl": "fastest: at least 2× plain finetuning", "finetune": "unstable across seeds on the 2Link",
         "scratch": "slower than finetuning", "full": "eventually successful, cut off in the figure"}


def parts(pr: Preset) -> tuple[Part, ...]:
  return tuple(finetune_part(name, title, A_HIGH[a], Low(b, zoo=ZOO_LOW[b]), "push1", pr,
                             paper=dict(WORDS, zero_shot=zero), zoo=zoo)
               for name, (a, b, title, zero, zoo) in PANELS.items())


TABLE = Table("fig7", "Figure 7: finetuning on BlockPush 1", parts,
              presets={**PRESETS, "cpu": dataclasses.replace(PRESETS["cpu"], ft=3000),
                       "paper": dataclasses.replace(PRESETS["paper"], ft=100_000)},
              note="Each method gets the same env steps of B: HL decisions times B's k for the hierarchical "
                   "ones, env steps for Full; curves are the runs' periodic evaluations.")
