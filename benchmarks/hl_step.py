"""Where an HL step over a legged LL goes, and what it costs against the LL steps it runs.

    python benchmarks/hl_step.py [--low zoo:ant/low_fast_1200k] [--tasks waypoint maze] [--envs 8] [--chunks 3]

For each task, on native MuJoCo with the HL's training setting (``configs.high_config(task)``,
``--envs`` parallel envs, one HL update per HL decision as the authors' SB2 SAC), per HL decision:

* ``train_s``: a whole HL training step (``Trainer.run_chunk``: the HL env step with its LL, acting,
  replay, the HL update), from timed chunks;
* ``env_s``: the HL env step alone (vmapped ``HighLevelEnv.step`` under random HL actions, in a scan);
* ``ll_s``: the same number of LL steps as the HL step ran (``ll_steps``), as a plain vmapped scan of
  LL inference + inner env step with no while loop, early stop or HL;
* ``ratio = train_s / ll_s``, the HL step's cost in units of the k LL steps it runs; ``env_s - ll_s``
  is the while loop (and its early stop under vmap) and the HL env's bookkeeping, ``train_s - env_s``
  the HL's acting, replay and update.

``hl_decisions_per_s`` = envs / train_s. Timings are medians of ``--reps`` runs after a warm-up.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import results  # noqa: E402
from e2e_throughput import time_chunks  # noqa: E402

from hdt.agents import train as sac_train  # noqa: E402
from hdt.transfer import configs  # noqa: E402
from hdt.transfer.pipeline import high_env_with_low  # noqa: E402


def timed(fn, reps: int) -> float:
  jax.block_until_ready(fn())  # warm-up (and compile)
  ts = []
  for _ in range(reps):
    t = time.perf_counter()
    jax.block_until_ready(fn())
    ts.append(time.perf_counter() - t)
  return float(np.median(ts))


def measure(task: str, low: str, envs: int, chunks: int, reps: int, decisions: int = 64) -> dict:
  env, _ = high_env_with_low(task, low, "native")
  inner, policy, low_params = env.env, env.low_policy, env.low_params
  k = env.k

  # the HL env step alone, under random HL actions
  def hl_rollout(key):
    keys = jax.random.split(key, envs)
    s = jax.vmap(env.reset)(keys)

    def step(s, key):
      a = jax.random.uniform(key, (envs, env.action_size), minval=-1.0, maxval=1.0)
      s = jax.vmap(env.step)(s, a)
      return s, s.metrics["ll_steps"]

    _, ll = jax.lax.scan(step, s, jax.random.split(key, decisions))
    return ll

  hl_rollout = jax.jit(hl_rollout)
  ll_steps = float(jnp.mean(hl_rollout(jax.random.PRNGKey(1))))
  env_s = timed(lambda: hl_rollout(jax.random.PRNGKey(2)), reps) / decisions

  # the same LL steps as a plain scan: LL inference + the inner env step, no while loop
  n_ll = max(1, int(round(ll_steps)))
  task_obj = inner.task

  def ll_rollout(key):
    s = jax.vmap(inner.reset)(jax.random.split(key, envs))
    goal = jnp.zeros((envs, 2))

    def step(s, _):
      obs = jax.vmap(task_obj.ll_observation)(s.obs_lo, s.obs_hi, goal)
      a = jax.vmap(policy, in_axes=(None, 0))(low_params, obs)
      return jax.vmap(lambda st, ac: inner.step(st, ac, auto_reset=False))(s, a), None

    s, _ = jax.lax.scan(step, s, None, length=n_ll * decisions)
    return s.obs_hi

  ll_rollout = jax.jit(ll_rollout)
  ll_s = timed(lambda: ll_rollout(jax.random.PRNGKey(3)), reps) / decisions

  # a whole HL training step: the trainer's chunk
  steps = decisions
  cfg = configs.high_config(task, num_envs=envs, updates_per_step=envs, steps_per_chunk=steps,
                            learning_starts=0, total_env_steps=steps * envs * (chunks + 2), buffer_size=100_000)
  fns = sac_train.vmapped(sac_train.make_train(env, cfg), 1)
  ts = fns.init(sac_train.seed_keys([0]), sac_train.seed_indices(1))
  train_s = time_chunks(fns, ts, chunks)[2] / steps  # per training step = envs HL decisions in parallel

  return dict(task=task, low=low, k=k, envs=envs, ll_steps_per_decision=ll_steps,
              train_s=train_s, env_s=env_s, ll_s=ll_s, ratio=train_s / ll_s,
              while_loop_overhead_s=env_s - ll_s, hl_update_s=train_s - env_s,
              hl_decisions_per_s=envs / train_s, load=round(os.getloadavg()[0], 2))


def main(argv=None) -> int:
  ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  ap.add_argument("--low", default="zoo:ant/low_fast_1200k")
  ap.add_argument("--tasks", nargs="+", default=["waypoint", "maze"])
  ap.add_argument("--envs", type=int, default=8)
  ap.add_argument("--chunks", type=int, default=3)
  ap.add_argument("--reps", type=int, default=3)
  ap.add_argument("--out", default=os.path.join(HERE, "hl_step.json"))
  ap.add_argument("--no-results", action="store_true")
  args = ap.parse_args(argv)
  rows = []
  for task in args.tasks:
    r = measure(task, args.low, args.envs, args.chunks, args.reps)
    print(f"{task}: {r['ll_steps_per_decision']:.1f} LL steps/decision, train {1e3 * r['train_s']:.1f} ms, "
          f"HL env {1e3 * r['env_s']:.1f} ms, LL steps {1e3 * r['ll_s']:.1f} ms -> ratio {r['ratio']:.2f}, "
          f"{r['hl_decisions_per_s']:.0f} decisions/s (load {r['load']})", flush=True)
    rows.append(r)
  with open(args.out + ".tmp", "w") as f:  # no machine path in the record
    json.dump(dict(args=dict(vars(args), out=os.path.relpath(args.out)), rows=rows), f, indent=1)
  os.replace(args.out + ".tmp", args.out)
  if not args.no_results:
    by = {r["task"]: r for r in rows}
    vals = {}
    if "waypoint" in by:
      vals["hl_step_cost_ratio_ant"] = by["waypoint"]["ratio"]
    if "maze" in by:
      vals["hl_decisions_per_s_ant_maze"] = by["maze"]["hl_decisions_per_s"]
      vals.setdefault("hl_step_cost_ratio_ant", by["maze"]["ratio"])
    results.update(vals, f"python benchmarks/hl_step.py --low {args.low} --envs {args.envs}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
