"""Training-chunk rate of SAC options against the plain setting, in alternating A/B rounds
(BENCHMARKS.md, "Time to quality").

    python benchmarks/sac_options_rate.py --agent ant --options policy_delay=2 n_step=3 --rounds 5

Each setting is the ``--fast`` LL setting (``configs.FAST_LOW``) with one option changed; whole
``run_chunk`` calls (physics, acting, replay and updates; 8 envs x 8 updates per step, 1 seed) are timed
round by round, every setting once per round, so a change in the machine's load hits all of them.
Prints env steps/s (median over rounds) and the ratio to the plain setting; writes nothing.
"""

from __future__ import annotations

import argparse
import ast
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from e2e_throughput import time_chunks  # noqa: E402

from hdt.agents import train as sac_train  # noqa: E402
from hdt.envs import make  # noqa: E402
from hdt.transfer import configs  # noqa: E402


def trainer(agent: str, steps: int, rounds: int, **option):
  cfg = configs.low_config(agent, **{**configs.FAST_LOW, "steps_per_chunk": steps, "learning_starts": 64,
                                     "total_env_steps": steps * 8 * (rounds + 2), "buffer_size": 100_000,
                                     **option})
  fns = sac_train.vmapped(sac_train.make_train(make(agent, "reach"), cfg), 1)
  ts = fns.init(sac_train.seed_keys([0]), sac_train.seed_indices(1))
  ts, _, _ = time_chunks(fns, ts, 1)  # compiled and warm
  return fns, ts


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  p.add_argument("--agent", default="ant")
  p.add_argument("--options", nargs="+", default=["policy_delay=2"], metavar="FIELD=VALUE")
  p.add_argument("--rounds", type=int, default=5)
  p.add_argument("--steps", type=int, default=250, help="training steps per chunk (x 8 env steps)")
  args = p.parse_args()
  settings = {"plain": {}}
  for o in args.options:
    name, _, value = o.partition("=")
    settings[o] = {name: ast.literal_eval(value)}
  built = {k: trainer(args.agent, args.steps, args.rounds, **v) for k, v in settings.items()}
  times = {k: [] for k in settings}
  load0 = os.getloadavg()[0]
  for _ in range(args.rounds):
    for k, (fns, ts) in built.items():
      ts, _, t = time_chunks(fns, ts, 1)
      built[k] = (fns, ts)
      times[k].append(t)
  base = np.median(times["plain"])
  print(f"{args.agent}, fast setting, 8 envs x 8 updates, {args.steps * 8} env steps per chunk, "
        f"{args.rounds} rounds, load {load0:.2f} -> {os.getloadavg()[0]:.2f}")
  for k, ts in times.items():
    t = float(np.median(ts))
    print(f"  {k:16s} {args.steps * 8 / t:7.1f} env steps/s (chunk {t:.3f} s, spread {min(ts):.3f}-{max(ts):.3f}),"
          f" {base / t:.2f}x plain")


if __name__ == "__main__":
  main()
