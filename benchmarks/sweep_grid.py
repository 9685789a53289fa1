"""A vmapped learning-rate grid vs one run: 8 learning rates x 2 seeds in one program vs 1 seed.

    python benchmarks/sweep_grid.py [--steps 4000] [--repeats 3] [--out benchmarks/sweep_grid.json]

Point LL at the paper's settings (``configs.low_config("point")``: [64,64], batch 64, 1 env, one
update per env step), ``--steps`` env steps. Each measurement is a fresh process (imports, env,
compile, training, evaluations after every chunk), run in turn A B A B ... so that a drift of the
machine's load hits both alike:

* ``one``: ``hdt.agents.train.run(env, cfg, seeds=[0])``;
* ``grid``: the same call with ``seeds=[0, 1]`` and ``hyper={"actor_lr": lrs, "critic_lr": lrs,
  "alpha_lr": lrs}`` (8 values): 16 runs in one vmapped program, as ``hdt sweep --grid`` does.

Reported per mode: the whole process's wall-clock, and inside it the training loop (``run``) and
its steady state (the chunks after the first, i.e. without compilation). The headline
``lr_grid8_vs_one_run_ratio`` is the median of the paired ratios grid / one of whole-process
wall-clock (what a user waits for); the ratio of steady-state chunk times is reported beside it.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
LRS = [1e-4, 2e-4, 3e-4, 5e-4, 7e-4, 1e-3, 2e-3, 3e-3]


def child(mode: str, steps: int) -> dict:
  t_start = time.perf_counter()
  from hdt.agents import train as sac_train
  from hdt.agents.sharding import use_cpu_cores
  from hdt.envs import make
  use_cpu_cores()  # as the CLI: the 16 runs split over the cores
  from hdt.transfer import configs
  env = make("point", "reach")
  cfg = configs.low_config("point", total_env_steps=steps, steps_per_chunk=steps // 4, num_envs=1,
                           updates_per_step=1)
  chunk_end = []
  kw = dict(hyper={"actor_lr": LRS, "critic_lr": LRS, "alpha_lr": LRS}) if mode == "grid" else {}
  seeds = [0, 1] if mode == "grid" else [0]
  t_run = time.perf_counter()
  res = sac_train.run(env, cfg, seeds, progress_fn=lambda s, m: chunk_end.append(time.perf_counter()), **kw)
  t_end = time.perf_counter()
  per_chunk = [b - a for a, b in zip(chunk_end, chunk_end[1:])]
  return dict(mode=mode, runs=int(res.history["eval/return"].shape[0]), run_s=t_end - t_run,
              devices=len(res.state.env_steps.sharding.device_set),
              steady_chunk_s=sorted(per_chunk)[len(per_chunk) // 2], in_process_s=t_end - t_start)


def main() -> None:
  ap = argparse.ArgumentParser()
  ap.add_argument("--steps", type=int, default=4000)
  ap.add_argument("--repeats", type=int, default=3)
  ap.add_argument("--out", default=os.path.join(HERE, "sweep_grid.json"))
  ap.add_argument("--child", choices=("one", "grid"))
  args = ap.parse_args()
  if args.child:
    print(json.dumps(child(args.child, args.steps)))
    return
  rows = []
  load_start = os.getloadavg()
  for r in range(args.repeats):
    for mode in ("one", "grid"):
      t0 = time.perf_counter()
      out = subprocess.run([sys.executable, __file__, "--child", mode, "--steps", str(args.steps)],
                           capture_output=True, text=True, check=True)
      row = json.loads(out.stdout.strip().splitlines()[-1]) | dict(process_s=time.perf_counter() - t0, repeat=r)
      rows.append(row)
      print(json.dumps(row), flush=True)
  med = lambda xs: sorted(xs)[len(xs) // 2]
  pick = lambda mode, k: [x[k] for x in rows if x["mode"] == mode]
  ratio = lambda k: med([g / o for g, o in zip(pick("grid", k), pick("one", k))])
  summary = dict(
      steps=args.steps, lrs=LRS, seeds=2, repeats=args.repeats, load_start=load_start, load_end=os.getloadavg(),
      ratio_process=ratio("process_s"), ratio_run=ratio("run_s"), ratio_steady_chunk=ratio("steady_chunk_s"),
      one_process_s=med(pick("one", "process_s")), grid_process_s=med(pick("grid", "process_s")), rows=rows)
  with open(args.out, "w") as f:
    json.dump(summary, f, indent=1)
  print(json.dumps({k: v for k, v in summary.items() if k != "rows"}, indent=1))
  sys.path.insert(0, HERE)
  from results import update
  update({"lr_grid8_vs_one_run_ratio": summary["ratio_process"]},
         f"benchmarks/sweep_grid.py --steps {args.steps} --repeats {args.repeats}: point LL, 8 lrs x 2 seeds "
         f"vmapped / 1 seed, whole-process wall-clock, median of paired ratios")


if __name__ == "__main__":
  main()
