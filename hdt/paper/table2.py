"""Table 2: discriminative LL alignment (Algorithm 1). A's HL, with no training, over B's plain LL
("zero-shot") and over B's LL aligned to A's LL by a discriminator ("discrim", A's discriminator
settings: ``configs.disc_config``). Navigation: PM → Ant, Ant3, Quadruped on Waypoint and PM → Ant,
Quadruped on Maze End and Maze Sample; manipulation: PM, 2Link, 3Link → 3Link, 4Link on BlockPush 1
and 2, and 3Link → 4Link on PegInsert."""

from __future__ import annotations

from hdt.paper.runs import LEGGED_LOW, High, Low, Preset
from hdt.paper.table import Cell, Part, Table

LABEL = {"point": "PM", "ant": "Ant", "ant3": "Ant3", "quadruped": "Quad", "arm_point": "PM", "arm2": "2Link",
         "arm3": "3Link", "arm4": "4Link"}
# The zoo entries behind the paper preset's cells (RESULTS.md, Table 2): A's LLs and HLs, B's plain and aligned LLs.
ZOO_A_LOW = {"point": "point/low", "arm_point": "arm_point/low", "arm2": "arm2/low_paper", "arm3": "arm3/low_paper",
             ("arm3", "insert"): "arm3/low_insert"}
ZOO_A_HIGH = {("point", "waypoint"): "point/waypoint", ("point", "maze"): "point/maze",
              ("arm_point", "push1"): "arm_point/push1_500k", ("arm_point", "push2"): "arm_point/push2",
              ("arm2", "push1"): "arm2/push1_500k", ("arm2", "push2"): "arm2/push2",
              ("arm3", "push1"): "arm3/push1_500k", ("arm3", "push2"): "arm3/push2", ("arm3", "insert"): "arm3/insert"}
ZOO_B_LOW = {**LEGGED_LOW, "arm3": "arm3/low_paper",
             "arm4": "arm4/low_paper", ("arm4", "insert"): "arm4/low_insert_1p2m",
             ("arm3", "arm_point"): "arm3/low_aligned_pm_1p2m", ("arm3", "arm2"): "arm3/low_aligned_arm2_1p2m",
             ("arm4", "arm3"): "arm4/low_aligned_arm3_1p2m", ("arm4", "arm2"): "arm4/low_aligned_arm2_1p2m",
             (("arm4", "insert"), "arm3"): "arm4/low_insert_aligned_arm3_1p2m",
             ("ant", "point"): "ant/low_aligned_pm_fast_1200k",
             ("quadruped", "point"): "quadruped/low_aligned_pm_fast_1200k",
             ("ant3", "point"): "ant3/low_aligned_pm_fast_1200k"}

# (A, B, the paper's zero-shot, discrim) per part
PAPER = {
    "waypoint": (("point", "ant", "483 ± 39", "546 ± 33"), ("point", "ant3", "489 ± 74", "495 ± 38"),
                 ("point", "quadruped", "169 ± 33", "338 ± 39")),
    "maze_end": (("point", "ant", ".30 ± .08", ".55 ± .13"), ("point", "quadruped", ".40 ± .22", ".40 ± .21")),
    "maze_sample": (("point", "ant", ".62 ± .04", ".72 ± .03"), ("point", "quadruped", ".78 ± .08", ".89 ± .06")),
    "push1": (("arm_point", "arm3", ".17 ± .08", ".34 ± .10"), ("arm2", "arm3", ".20 ± .09", ".43 ± .15"),
              ("arm2", "arm4", ".07 ± .04", ".17 ± .08"), ("arm3", "arm4", ".10 ± .05", ".23 ± .13")),
    "push2": (("arm_point", "arm3", ".24 ± .12", ".43 ± .12"), ("arm2", "arm3", ".61 ± .16", ".42 ± .11"),
              ("arm2", "arm4", ".19 ± .12", ".46 ± .30"), ("arm3", "arm4", ".39 ± .16", ".44 ± .14")),
    "insert": (("arm3", "arm4", ".80 ± .18", ".93 ± .05"),),
}
TASKS = {"waypoint": ("waypoint", (), "Waypoint (return)"), "maze_end": ("maze", (("goal", "end"),), "Maze End (success)"),
         "maze_sample": ("maze", (("goal", "sample"),), "Maze Sample (success)"),
         "push1": ("push1", (), "BlockPush 1 (success)"), "push2": ("push2", (), "BlockPush 2 (success)"),
         "insert": ("insert", (), "PegInsert (success)")}


def _key(agent, terrain):
  return agent if terrain == "plane" else (agent, terrain)


def transfer(a: str, b: str, task: str, paper: tuple[str, str], terrain: str) -> tuple[Cell, Cell]:
  a_low = Low(a, terrain, zoo=ZOO_A_LOW.get(_key(a, terrain)))
  a_high = High(task, a_low, zoo=ZOO_A_HIGH.get((a, task)))
  plain = Low(b, terrain, zoo=ZOO_B_LOW.get(_key(b, terrain)))
  aligned = Low(b, terrain, imitate=a_low, zoo=ZOO_B_LOW.get((_key(b, terrain), a)))
  row = f"{LABEL[a]} → {LABEL[b]}"
  return (Cell(row, "zero-shot", high=a_high, low=plain, paper=paper[0]),
          Cell(row, "discrim", high=a_high, low=aligned, paper=paper[1]))


def parts(pr: Preset) -> tuple[Part, ...]:
  out = []
  for name, rows in PAPER.items():
    task, options, title = TASKS[name]
    terrain = "insert" if task == "insert" else "plane"  # an insert HL needs insert-scene LLs
    cells = tuple(c for a, b, *paper in rows for c in transfer(a, b, task, paper, terrain))
    out.append(Part(name, title, task, cells, options=options, kind="bars", corner="A → B"))
  return tuple(out)


ZOO_ALIGNED = ", ".join(f"{LABEL[a]} → {LABEL[b]}" if isinstance(b, str) else f"{LABEL[a]} → {LABEL[b[0]]} ({b[1]})"
                        for b, a in (k for k in ZOO_B_LOW if isinstance(k, tuple)) if a in LABEL)
TABLE = Table("table2", "Table 2: discriminative LL alignment", parts,
              note="Aligned LLs use A's discriminator settings (offline data for navigation, online for "
                   "manipulation, the paper's learning rates and weights); at the paper preset the zoo holds the "
                   f"{ZOO_ALIGNED} aligned LLs.")
