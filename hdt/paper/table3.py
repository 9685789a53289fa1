"""Table 3: Steps, where hierarchical transfer is not optimal: the ant can climb the low barriers of
the half-size U-maze, the point mass cannot. Zero-shot: the PM and Ant HLs over the PM and Ant LLs
(the ant's LL trained on reach over random steps, with 16 rangefinders, as the authors'); then the
PM HL on the ant by plain and KL finetuning (β 0.01, lr 1e-3) against the ant's HL from scratch, for
the same ant samples. Success on the maze's end goal."""

from __future__ import annotations

from hdt.paper.runs import High, Low, Preset
from hdt.paper.table import Cell, Part, Table, finetune_part

PM_LOW = Low("point", zoo="point/low")
ANT_LOW = Low("ant", "steps", zoo="ant/low_steps_fast_600k")  # hdt's fast setting, 600k of 2.5M env steps
ANT_HIGH = "ant/steps_120k"  # the ant's own Steps HL over ANT_LOW, 120k of the paper's 400k decisions
ZERO_SHOT = {("PM", "PM"): ".60 ± .22", ("PM", "Ant"): ".00 ± .00",  # (LL, HL): the paper's success
             ("Ant", "PM"): ".32 ± .16", ("Ant", "Ant"): ".59 ± .05"}


def parts(pr: Preset) -> tuple[Part, ...]:
  lows, highs = {"PM": PM_LOW, "Ant": ANT_LOW}, {"PM": High("steps", PM_LOW, zoo="point/steps"),
                                                 "Ant": High("steps", ANT_LOW, zoo=ANT_HIGH)}
  zero = Part("zero_shot", "Zero-shot (success)", "steps",
              tuple(Cell(r, c, high=highs[c], low=lows[r], paper=p) for (r, c), p in ZERO_SHOT.items()))
  tuned = finetune_part("finetuning", "PM HL → Ant LL: finetuning (success)", highs["PM"], ANT_LOW, "steps", pr,
                        methods=("finetune", "finetune_kl", "scratch"),
                        paper={"zero_shot": ".32 ± .16", "finetune": ".53 ± .09", "finetune_kl": ".52 ± .13",
                               "scratch": ".59 ± .05"},
                        zoo={"scratch": ANT_HIGH, "finetune_kl": "ant/steps_ft_kl_from_pm_120k",
                             "finetune": "ant/steps_ft_from_pm_120k"})
  return zero, tuned


TABLE = Table("table3", "Table 3: Steps (PM → Ant)", parts,
              note="HL scratch is the ant's HL trained for the finetuning budget (at the paper preset the task's "
                   "400k decisions: the Ant / Ant cell).")
