"""Table 2 (discriminative LL alignment): zero-shot success of A's HL on B's plain LL vs on B's LL
aligned to A (paper Algorithm 1; SPEC 5 "Discriminator").

  PYTHONPATH=. python experiments/table2.py --preset cpu     # this 2-core machine, < 1 hour
  PYTHONPATH=. python experiments/table2.py --preset smoke   # minutes, plumbing only

Per row (A → B, task): A's LL on reach and A's HL on the task over it; B's LL plain and B's LL aligned
to A (``train_low(B, imitate=A's LL)``, the paper's discriminator hyper-parameters for A); then A's HL
evaluated, without training, on both of B's LLs. Runs are shared across rows (B's plain LL, and an
A's LL that is another row's B).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run as a script or loaded by path
from experiments import common as C  # noqa: E402
from hdt.envs.tasks import get_task  # noqa: E402

ROWS = {  # name: (A, B, task, paper zero-shot plain -> aligned)
    "pm_3link_push1": ("arm_point", "arm3", "push1", (".17", ".34")),
    "2link_3link_push1": ("arm2", "arm3", "push1", (".20", ".43")),
    "3link_4link_insert": ("arm3", "arm4", "insert", (".80", ".93")),
}

PRESETS = {  # seeds, eval episodes, rows; budgets: hdt.transfer.configs at the same preset
    "smoke": dict(seeds=1, episodes=4, rows=["pm_3link_push1"]),
    "cpu": dict(seeds=2, episodes=50, rows=["pm_3link_push1", "2link_3link_push1"]),  # table1's runs reused
    "paper": dict(seeds=5, episodes=100, rows=list(ROWS)),
}


def run(preset: str = "cpu", out: Path = Path("runs/table2"), seeds: int | None = None,
        quiet: bool = False) -> dict:
  pr, out = C.experiment_preset(PRESETS, preset), Path(out)
  seeds = seeds or pr["seeds"]
  lows, highs, minutes, rows = {}, {}, {}, {}

  def low(agent, terrain, imitate=None):  # one run per (agent, terrain, A imitated), shared by the rows
    key = (agent, terrain, imitate)
    if key not in lows:
      name = f"{agent}_low" + (f"_{terrain}" if terrain != "plane" else "") + (f"_aligned_{imitate}" if imitate else "")
      kw = {} if terrain == "plane" else {"terrain": terrain}  # an insert HL needs an insert-scene LL
      lows[key] = C.timed(minutes, f"low {agent}" + (f"<-{imitate}" if imitate else ""), lambda: C.low(
          agent, pr, out, seeds, quiet, name=name,
          imitate=lows[(imitate, terrain, None)] if imitate else None, **kw))
    return lows[key]

  for name in pr["rows"]:
    a, b, task, paper = ROWS[name]
    terrain = get_task(task).ll_terrain or "plane"
    a_low = low(a, terrain)
    if (a, task) not in highs:
      highs[(a, task)] = C.timed(minutes, f"high {a} {task}", lambda: C.high(task, a_low, pr, out, seeds, quiet))
    plain, aligned = low(b, terrain), low(b, terrain, imitate=a)
    rows[name] = dict(a=a, b=b, task=task, paper=dict(plain=paper[0], aligned=paper[1]),
                      plain=C.eval_hl(highs[(a, task)], plain, task, pr["episodes"]),
                      aligned=C.eval_hl(highs[(a, task)], aligned, task, pr["episodes"]),
                      # LL quality: final distance to goal of each LL on reach (deterministic eval)
                      goal_dist=dict(plain=_final(plain, "eval/goal_dist_final"),
                                     aligned=_final(aligned, "eval/goal_dist_final")))
    result = dict(experiment="table2", preset=preset, command=C.command("table2", preset), seeds=seeds,
                  budget=pr, rows=rows, minutes=minutes)
    C.write_result("table2", preset, result)  # after every row: a killed run keeps what it did
  return result


def _final(res, key):
  h = res.history.get(key)
  return None if h is None else [float(v) for v in h[:, -1]]


def markdown(result: dict) -> str:
  r = result
  lines = ["| A → B | task | zero-shot (plain B LL) | aligned B LL | paper plain → aligned | B LL goal dist plain / aligned |",
           "|---|---|---|---|---|---|"]
  for row in r["rows"].values():
    gd = row.get("goal_dist") or {}
    fmt = lambda v: "—" if not v else f"{sum(v) / len(v):.3g}"
    lines.append(f"| {row['a']} → {row['b']} | {row['task']} | {C.cell(row['plain'])} | {C.cell(row['aligned'])} "
                 f"| {row['paper']['plain']} → {row['paper']['aligned']} | {fmt(gd.get('plain'))} / {fmt(gd.get('aligned'))} |")
  lines += ["", f"{r['seeds']} seeds, budget {r['budget']}. Command: `{r['command']}`"]
  return "\n".join(lines)


main = C.make_main("table2", PRESETS, run, markdown, __doc__)

if __name__ == "__main__":
  sys.exit(main())
