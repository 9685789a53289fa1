"""Figure 6: finetuning from the PM on navigation: Ant Waypoint, Ant Maze End, Ant Maze Sample and
Quadruped Maze Sample. Per panel: the PM's HL (Maze: trained on Maze Sample) over B's LL zero-shot,
then KL finetuning (Waypoint β 1, lr 0.01; Maze β 0.01, lr 1e-3, annealed over the first half), plain
finetuning, B's HL from scratch and Full, for the same env steps of B. Maze End finetunes with the
goal always at the maze's end, as the paper."""

from __future__ import annotations

from hdt.paper.runs import LEGGED_LOW, High, Low, Preset
from hdt.paper.table import Part, Table, finetune_part

PM_LOW = Low("point", zoo="point/low")
PM_HIGH = {"waypoint": High("waypoint", PM_LOW, zoo="point/waypoint"), "maze": High("maze", PM_LOW, zoo="point/maze")}
# name: (B, task, options, title, the zero-shot level the paper's Table 1 gives, zoo entries of its methods)
PANELS = {"ant_waypoint": ("ant", "waypoint", (), "Ant Waypoint (return)", "483 ± 39",
                           {"finetune_kl": "ant/waypoint_ft_kl_from_pm", "finetune": "ant/waypoint_ft_from_pm",
                            "scratch": "ant/waypoint_200k", "full": "ant/full_waypoint_224k"}),
          "ant_maze_end": ("ant", "maze", (("goal", "end"),), "Ant Maze End (success)", ".30 ± .08",
                           {"finetune_kl": "ant/maze_end_ft_kl_from_pm_200k",
                            "finetune": "ant/maze_end_ft_from_pm_200k", "scratch": "ant/maze_end_200k",
                            "full": "ant/full_maze_end_96k"}),
          "ant_maze_sample": ("ant", "maze", (("goal", "sample"),), "Ant Maze Sample (success)", ".62 ± .04",
                              {"finetune_kl": "ant/maze_sample_ft_kl_from_pm_200k",
                               "finetune": "ant/maze_sample_ft_from_pm_200k", "scratch": "ant/maze_400k",
                               "full": "ant/full_maze_sample_96k"}),
          "quadruped_maze_sample": ("quadruped", "maze", (("goal", "sample"),), "Quadruped Maze Sample (success)",
                                    ".78 ± .08", {"finetune_kl": "quadruped/maze_sample_ft_kl_from_pm_200k",
                                                 "finetune": "quadruped/maze_sample_ft_from_pm_200k",
                                                 "scratch": "quadruped/maze_200k",
                                                 "full": "quadruped/full_maze_sample_96k"})}
# What the paper says of the curves (its numbers are curves only)
WORDS = {"finetune_kl": "above plain finetuning, modestly on Maze", "finetune": "above HL scratch",
         "full": "unsuccessful without hierarchy"}


def parts(pr: Preset) -> tuple[Part, ...]:
  return tuple(finetune_part(name, title, PM_HIGH[task], Low(b, zoo=LEGGED_LOW.get(b)), task, pr, options,
                             paper=dict(WORDS, zero_shot=zero), zoo=zoo)
               for name, (b, task, options, title, zero, zoo) in PANELS.items())


TABLE = Table("fig6", "Figure 6: finetuning from the PM on navigation", parts,
              note="Each method gets the same env steps of B: HL decisions times B's k for the hierarchical "
                   "ones, env steps for Full; curves are the runs' periodic evaluations.")
