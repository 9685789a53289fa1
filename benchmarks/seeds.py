"""Vmapped seeds vs sequential seeds, compile time of the training step, and peak memory.

    python benchmarks/seeds.py [--quick] [--seeds 16] [--out FILE]

1. **Seeds.** The same small config trained for the same number of env steps per seed, 16 seeds
   vmapped in one ``jit(vmap(run_chunk))`` vs 16 seeds one after the other (seeds=[s], the jitted
   chunk compiled once and reused: the best a sequential user can do in one process). Wall-clock
   includes init and compile for both; the ratio is sequential / vmapped. Two configs: the paper's
   reference setting (1 env, 1 update per env step, [64,64] batch 64) and a CPU setting
   (8 envs, 2 updates per step, batch 256).
2. **Compile and memory.** For the point / arm3 / ant LL configs (``configs.low_config``, paper
   networks and buffers, 8 parallel envs, 8 updates per training step, 1 seed), each in a fresh
   subprocess: the time of ``lower`` + ``compile`` of ``run_chunk``, the first call, the steady-state
   call, and the peak resident memory (``resource.getrusage(RUSAGE_SELF).ru_maxrss``) after the
   steady-state calls. JAX's CPU device reports no memory statistics (``memory_stats()`` is None);
   they are recorded when available.

Every measurement runs in its own subprocess so that ru_maxrss and caches do not leak across.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))

SEED_CONFIGS = {
    # name: (agent, overrides) with total_env_steps per seed
    "paper_1env_utd1": ("point", dict(num_envs=1, updates_per_step=1, batch_size=64,
                                      total_env_steps=2000, steps_per_chunk=500)),
    "cpu_8env_u2_b256": ("point", dict(num_envs=8, updates_per_step=2, batch_size=256,
                                       total_env_steps=8000, steps_per_chunk=250)),
}
QUICK_SEED_CONFIGS = {
    "paper_1env_utd1": ("point", dict(num_envs=1, updates_per_step=1, batch_size=64,
                                      total_env_steps=1000, steps_per_chunk=250)),
}
COMPILE_AGENTS = ["point", "arm3", "ant"]


def _maxrss_mb():
  return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def _mem_stats():
  import jax
  try:
    return jax.devices()[0].memory_stats()
  except Exception:  # noqa: BLE001
    return None


# ------------------------------------------------------------------------------------------------
# Child measurements (run as `python seeds.py --child KIND ...`; print one JSON line).


def child_seeds(agent, overrides, seeds, mode):
  import jax
  from hdt.agents.train import make_train, seed_indices, seed_keys, vmapped
  from hdt.envs import make
  from hdt.transfer import configs

  t0 = time.perf_counter()
  env = make(agent, "reach")
  cfg = configs.low_config(agent, **overrides)
  trainer = make_train(env, cfg)
  fns = vmapped(trainer)
  chunk = None
  groups = [list(range(seeds))] if mode == "vmap" else [[s] for s in range(seeds)]
  compile_s = 0.0
  for g in groups:
    ts = fns.init(seed_keys(g), seed_indices(len(g)))
    if chunk is None:
      tc = time.perf_counter()
      chunk = fns.run_chunk.lower(ts).compile()
      compile_s = time.perf_counter() - tc
    for _ in range(cfg.num_chunks):
      ts, m = chunk(ts)
    jax.block_until_ready(m)
  total = time.perf_counter() - t0
  return dict(mode=mode, seeds=seeds, total_s=total, compile_s=compile_s,
              env_steps_per_seed=cfg.total_env_steps,
              updates_per_seed=cfg.num_chunks * cfg.steps_per_chunk * cfg.updates_per_step,
              env_steps_per_s=seeds * cfg.total_env_steps / (total - compile_s),
              maxrss_mb=_maxrss_mb(), load=os.getloadavg()[0])


def child_compile(agent, steps_per_chunk, num_envs, updates_per_step):
  import jax
  import numpy as np
  from hdt.agents.train import make_train, seed_indices, seed_keys, vmapped
  from hdt.envs import make
  from hdt.transfer import configs

  rss0 = _maxrss_mb()
  env = make(agent, "reach")
  cfg = configs.low_config(agent, num_envs=num_envs, updates_per_step=updates_per_step,
                           steps_per_chunk=steps_per_chunk, learning_starts=0,
                           total_env_steps=100 * num_envs * steps_per_chunk)
  trainer = make_train(env, cfg)
  fns = vmapped(trainer)
  t = time.perf_counter()
  ts = jax.block_until_ready(fns.init(seed_keys([0]), seed_indices(1)))
  init_s = time.perf_counter() - t
  rss_init = _maxrss_mb()
  # (a) compile in isolation (AOT), (b) the first call through the jitted function (trace +
  # compile + run), (c) steady-state calls.
  t = time.perf_counter()
  fns.run_chunk.lower(ts).compile()
  aot_compile_s = time.perf_counter() - t
  jax.clear_caches()
  fns = vmapped.__wrapped__(trainer)  # fresh jit objects: the first call compiles again
  t = time.perf_counter()
  ts, m = fns.run_chunk(ts)
  jax.block_until_ready(m)
  first_call_s = time.perf_counter() - t
  times = []
  for _ in range(3):
    t = time.perf_counter()
    ts, m = fns.run_chunk(ts)
    jax.block_until_ready(m)
    times.append(time.perf_counter() - t)
  steady = float(np.median(times))
  replay_mb = sum(x.nbytes for x in jax.tree_util.tree_leaves(ts.replay)) / 2**20
  return dict(agent=agent, hidden=list(cfg.hidden_sizes), batch=cfg.batch_size,
              buffer=cfg.buffer_size, num_envs=num_envs, updates_per_step=updates_per_step,
              steps_per_chunk=steps_per_chunk, obs=int(env.observation_size),
              act=int(env.action_size), init_s=init_s, aot_compile_s=aot_compile_s,
              first_call_s=first_call_s, steady_call_s=steady,
              first_minus_steady_s=first_call_s - steady,
              env_steps_per_s=num_envs * steps_per_chunk / steady,
              replay_mb=replay_mb, maxrss_start_mb=rss0, maxrss_after_init_mb=rss_init,
              maxrss_mb=_maxrss_mb(), jax_memory_stats=_mem_stats(), load=os.getloadavg()[0])


def run_child(args):
  cmd = [sys.executable, os.path.abspath(__file__), "--child", json.dumps(args)]
  p = subprocess.run(cmd, capture_output=True, text=True, env=os.environ.copy())
  lines = [l for l in p.stdout.splitlines() if l.startswith("{")]
  if p.returncode or not lines:
    raise RuntimeError(f"child {args} failed:\n{p.stderr[-3000:]}")
  return json.loads(lines[-1])


def main():
  ap = argparse.ArgumentParser()
  ap.add_argument("--quick", action="store_true")
  ap.add_argument("--seeds", type=int, default=16)
  ap.add_argument("--skip-seeds", action="store_true")
  ap.add_argument("--skip-compile", action="store_true")
  ap.add_argument("--compile-agents", default=",".join(COMPILE_AGENTS))
  ap.add_argument("--child", help=argparse.SUPPRESS)
  ap.add_argument("--out", default=os.path.join(HERE, "seeds.json"))
  ap.add_argument("--no-results", action="store_true")
  args = ap.parse_args()

  if args.child:
    c = json.loads(args.child)
    kind = c.pop("kind")
    out = child_seeds(**c) if kind == "seeds" else child_compile(**c)
    print(json.dumps(out))
    return

  import jax
  out = dict(machine=dict(platform=platform.platform(), cpus=os.cpu_count(), jax=jax.__version__,
                          load_start=os.getloadavg()[0]), seeds={}, compile={})
  if os.path.exists(args.out) and not args.quick:
    with open(args.out) as f:
      prev = json.load(f)
    out["seeds"], out["compile"] = prev.get("seeds", {}), prev.get("compile", {})
  n = 4 if args.quick else args.seeds
  if not args.skip_seeds:
    for name, (agent, ov) in (QUICK_SEED_CONFIGS if args.quick else SEED_CONFIGS).items():
      vm = run_child(dict(kind="seeds", agent=agent, overrides=ov, seeds=n, mode="vmap"))
      print(f"  {name}: {n} seeds vmapped   {vm['total_s']:7.1f}s (compile {vm['compile_s']:.1f}s, "
            f"load {vm['load']:.1f})", flush=True)
      sq = run_child(dict(kind="seeds", agent=agent, overrides=ov, seeds=n, mode="sequential"))
      print(f"  {name}: {n} seeds sequential {sq['total_s']:7.1f}s (compile {sq['compile_s']:.1f}s, "
            f"load {sq['load']:.1f})", flush=True)
      out["seeds"][name] = dict(agent=agent, overrides=ov, vmap=vm, sequential=sq,
                                speedup=sq["total_s"] / vm["total_s"],
                                speedup_excl_compile=(sq["total_s"] - sq["compile_s"])
                                / (vm["total_s"] - vm["compile_s"]))
  if not args.skip_compile:
    agents = ["point"] if args.quick else args.compile_agents.split(",")
    for agent in agents:
      r = run_child(dict(kind="compile", agent=agent, steps_per_chunk=50,
                         num_envs=8, updates_per_step=8))
      out["compile"][agent] = r
      print(f"  compile {agent}: AOT {r['aot_compile_s']:.1f}s, first call {r['first_call_s']:.1f}s, "
            f"steady {r['steady_call_s']:.2f}s, maxrss {r['maxrss_mb']:.0f} MB (load {r['load']:.1f})",
            flush=True)
  out["machine"]["load_end"] = os.getloadavg()[0]
  with open(args.out, "w") as f:
    json.dump(out, f, indent=1)

  print()
  print(f"Seeds: vmapped vs sequential (same work), load {out['machine']['load_start']:.1f} -> "
        f"{out['machine']['load_end']:.1f}")
  print(f"{'config':20s} {'seeds':>5s} {'env steps/seed':>14s} {'vmapped s':>10s} {'sequential s':>12s} "
        f"{'ratio':>6s} {'ratio excl. compile':>19s}")
  for name, r in out["seeds"].items():
    print(f"{name:20s} {r['vmap']['seeds']:5d} {r['vmap']['env_steps_per_seed']:14d} "
          f"{r['vmap']['total_s']:10.1f} {r['sequential']['total_s']:12.1f} {r['speedup']:6.2f} "
          f"{r['speedup_excl_compile']:19.2f}")
  print()
  print("Compile time and memory of the training chunk (1 seed, 8 envs, 8 updates/step, 50 steps = 400 env steps and 400 updates per chunk)")
  print(f"{'agent':6s} {'net':>10s} {'batch':>5s} {'buffer':>8s} {'AOT compile':>11s} {'1st call':>8s} "
        f"{'steady':>7s} {'replay MB':>9s} {'maxrss MB':>9s}")
  for a, r in out["compile"].items():
    print(f"{a:6s} {str(r['hidden']):>10s} {r['batch']:5d} {r['buffer']:8d} {r['aot_compile_s']:11.1f} "
          f"{r['first_call_s']:8.1f} {r['steady_call_s']:7.2f} {r['replay_mb']:9.0f} {r['maxrss_mb']:9.0f}")
  if not args.quick and not args.no_results:
    key = "paper_1env_utd1" if "paper_1env_utd1" in out["seeds"] else None
    if key:
      sys.path.insert(0, HERE)
      import results as results_lib
      results_lib.update({"vmap_seed_speedup": out["seeds"][key]["speedup"]},
                         f"benchmarks/seeds.py ({key}, {n} seeds)",
                         load=out["seeds"][key]["vmap"]["load"])


if __name__ == "__main__":
  main()
