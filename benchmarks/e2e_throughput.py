"""End-to-end training throughput against the machine's matmul peak (BENCHMARKS.md, "Whole-run throughput").

    python benchmarks/e2e_throughput.py [--agents arm3 ant] [--chunks 3] [--out benchmarks/e2e_throughput.json]

Times whole training chunks (``Trainer.run_chunk``: the native MuJoCo env steps, acting, replay
writes and samples, and the gradient updates; the periodic evaluation is not included) of the
paper's LL networks on the real envs (``configs.low_config(agent)``: arm3 [128,96] batch 100, ant
[400,300] batch 100), for a few settings of envs x updates per step and vmapped seeds. Seeds split over
the CPU's devices, one per core, as the CLI runs them (``hdt.agents.sharding.use_cpu_cores``; set
``JAX_NUM_CPU_DEVICES=1`` for one device).

GFLOP/s counts the matmuls of the SAC updates only (``sac_throughput.update_flops``: forward, weight
and input gradients of actor, twin critic and target pass); acting (one policy forward per env step)
and the physics are work the count leaves out, so the fraction is a lower bound on how busy the
machine is. The dense float32 matmul peak (``jnp.dot`` 1024x1024) is measured in the same process.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import jax
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from sac_throughput import matmul_gflops, update_flops  # noqa: E402
import results  # noqa: E402

from hdt.agents import sharding  # noqa: E402
from hdt.agents import train as sac_train  # noqa: E402
from hdt.envs import make  # noqa: E402
from hdt.transfer import configs  # noqa: E402

# (envs, updates per env-step batch, seeds): the paper's 1 env x 1 update, the 8 x 8 used for the zoo's
# paper-budget LLs, and that with 3 vmapped seeds (how they were trained), 2 and 4 (split over 2 cores)
SETTINGS = [(1, 1, 1), (8, 8, 1), (8, 8, 2), (8, 8, 3), (8, 8, 4)]


def time_chunks(fns, ts, chunks: int) -> tuple:
  """(state after, seconds of the first chunk (compile included), median seconds of ``chunks`` more)
  of ``fns.run_chunk`` (which donates its state, so the state is threaded through)."""
  t0 = time.perf_counter()
  ts, _ = fns.run_chunk(ts)
  jax.block_until_ready(ts)
  first_s = time.perf_counter() - t0
  times = []
  for _ in range(chunks):
    t0 = time.perf_counter()
    ts, _ = fns.run_chunk(ts)
    jax.block_until_ready(ts)
    times.append(time.perf_counter() - t0)
  return ts, first_s, float(np.median(times))


def measure(agent: str, envs: int, updates: int, seeds: int, chunks: int) -> dict:
  env = make(agent, "reach")
  steps = max(1, 2000 // envs)  # ~2000 env steps per seed per chunk
  cfg = configs.low_config(agent, num_envs=envs, updates_per_step=updates, steps_per_chunk=steps,
                           learning_starts=0, total_env_steps=steps * envs * (chunks + 1), buffer_size=100_000)
  fns = sac_train.vmapped(sac_train.make_train(env, cfg), seeds)
  ts = fns.init(sac_train.seed_keys(range(seeds)), sac_train.seed_indices(seeds))
  ts, compile_s, t = time_chunks(fns, ts, chunks)
  env_steps = seeds * envs * steps / t
  n_updates = seeds * updates * steps / t
  flops = update_flops(tuple(cfg.hidden_sizes), cfg.batch_size, int(env.observation_size), int(env.action_size))
  return dict(agent=agent, hidden=list(cfg.hidden_sizes), batch=cfg.batch_size, obs=int(env.observation_size),
              act=int(env.action_size), envs=envs, updates_per_step=updates, seeds=seeds,
              devices=len(ts.env_steps.sharding.device_set),
              chunk_s=t, first_chunk_s=compile_s, env_steps_per_s=env_steps, env_steps_per_s_per_seed=env_steps / seeds,
              updates_per_s=n_updates, mflop_per_update=flops / 1e6, gflops=n_updates * flops / 1e9)


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  p.add_argument("--agents", nargs="+", default=["arm3", "ant"])
  p.add_argument("--chunks", type=int, default=3)
  p.add_argument("--out", default=os.path.join(HERE, "e2e_throughput.json"))
  args = p.parse_args()
  sharding.use_cpu_cores()
  load0 = os.getloadavg()
  peak = matmul_gflops()
  rows = []
  for agent in args.agents:
    for envs, updates, seeds in SETTINGS:
      r = measure(agent, envs, updates, seeds, args.chunks)
      r["peak_fraction"] = r["gflops"] / peak
      rows.append(r)
      print(f"{agent:5s} {envs} env x {updates} upd x {seeds} seeds on {r['devices']} devices: "
            f"{r['env_steps_per_s']:8.0f} env steps/s "
            f"({r['env_steps_per_s_per_seed']:.0f}/seed), {r['updates_per_s']:7.0f} updates/s, "
            f"{r['gflops']:5.1f} GFLOP/s = {100 * r['peak_fraction']:4.1f}% of {peak:.0f}", flush=True)
  peak_end = matmul_gflops()
  out = dict(machine=dict(loadavg_at_start=load0, loadavg_at_end=os.getloadavg(), cpus=os.cpu_count(),
                          devices=len(jax.devices()),
                          matmul_gflops_start=peak, matmul_gflops_end=peak_end), rows=rows)
  with open(args.out + ".tmp", "w") as f:
    json.dump(out, f, indent=1)
  os.replace(args.out + ".tmp", args.out)
  best = {a: max((r for r in rows if r["agent"] == a), key=lambda r: r["peak_fraction"]) for a in args.agents}
  results.update({f"e2e_matmul_peak_fraction_{a}_ll": r["peak_fraction"] for a, r in best.items()
                  if a in ("arm3", "ant")},
                 "benchmarks/e2e_throughput.py: whole run_chunk on the real env, paper LL network, best of "
                 + ", ".join(f"{e}env x {u}upd x {s}seeds" for e, u, s in SETTINGS)
                 + f" (seeds split over {len(jax.devices())} CPU devices); update matmul FLOPs / jnp.dot 1024 peak "
                 "in the same process", load=load0[0])


if __name__ == "__main__":
  main()
