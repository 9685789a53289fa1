"""The matmul ceiling of the paper's LL networks: GFLOP/s of each of the SAC update's matmul shapes
run alone: the bound on the end-to-end fraction (BENCHMARKS.md, "Whole-run throughput").

    python benchmarks/matmul_shapes.py [--seeds 1 2 3] [--out benchmarks/matmul_shapes.json]

For every dense layer (in -> out) of the actor and the critic at batch B, the update does three
matmuls: forward ``[B, in] @ [in, out]``, the weight gradient ``[in, B] @ [B, out]`` and the input
gradient ``[B, out] @ [out, in]``. Each is timed alone, ``iters`` times in a ``lax.fori_loop`` whose
input depends on the previous product (so XLA cannot hoist or merge them), for 1 and for several
vmapped seeds (split over the CPU's devices, one per core, as the CLI runs seeds). The ceiling of a network is its FLOPs over the time those matmuls take at these
rates (``sum flops / sum(flops / rate)``): the update's GFLOP/s if it did nothing but its matmuls, one
after another. It is compared with the 1024 x 1024 ``jnp.dot`` peak that the e2e fractions use.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import jax
import jax.numpy as jnp

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from sac_throughput import matmul_gflops  # noqa: E402
import results  # noqa: E402

from hdt.agents import sharding  # noqa: E402

# agent: (obs, act, hidden, batch), as benchmarks/e2e_throughput.py (configs.low_config networks)
NETS = {"arm3": (11, 3, (128, 96), 100), "ant": (33, 8, (400, 300), 100)}


def rate(m: int, k: int, n: int, seeds: int = 1, iters: int = 2000) -> float:
  """GFLOP/s of ``[seeds, m, k] @ [seeds, k, n]``, chained ``iters`` times, the seeds split over devices
  as training splits them (:func:`hdt.agents.sharding.seed_mesh`)."""
  mesh = sharding.seed_mesh(seeds)
  x = jax.random.normal(jax.random.PRNGKey(0), (seeds, m, k), jnp.float32)
  w = jax.random.normal(jax.random.PRNGKey(1), (seeds, k, n), jnp.float32)
  x, w = sharding.shard((x, w), sharding.seed_sharding(seeds))

  def one_seed(x, w):
    step = lambda i, x: x + 1e-9 * (x @ w)[..., :1]  # O(m k) extra, 1/n of it
    return jax.lax.fori_loop(0, iters, step, x)

  chain = jax.jit(sharding.over_seeds(jax.vmap(one_seed), mesh, 2))

  chain(x, w).block_until_ready()
  best = float("inf")
  for _ in range(3):
    t = time.perf_counter()
    chain(x, w).block_until_ready()
    best = min(best, time.perf_counter() - t)
  return 2 * m * k * n * seeds * iters / best / 1e9


def layers(obs: int, act: int, hidden: tuple, batch: int):
  """(m, k, n) of every matmul of one update's actor and critic layers (forward and both gradients)."""
  shapes = []
  for inp, out in ((obs, 2 * act), (obs + act, 1)):  # actor: mean and log-std; critic: one value
    sizes = (inp, *hidden, out)
    for a, b in zip(sizes, sizes[1:]):
      shapes += [(batch, a, b), (a, batch, b), (batch, b, a)]
  return shapes


def main() -> None:
  p = argparse.ArgumentParser()
  p.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3])
  p.add_argument("--out", default=os.path.join(HERE, "matmul_shapes.json"))
  a = p.parse_args()
  sharding.use_cpu_cores()
  load = os.getloadavg()
  peak = matmul_gflops()
  out = dict(machine=dict(cpus=os.cpu_count(), devices=len(jax.devices()), loadavg_at_start=load, matmul_gflops_1024=peak), nets={})
  for agent, (obs, act, hidden, batch) in NETS.items():
    for s in a.seeds:
      rows = [dict(m=m, k=k, n=n, gflops=rate(m, k, n, s, iters=max(50, 2000 // s))) for m, k, n in layers(obs, act, hidden, batch)]
      flops = [2 * r["m"] * r["k"] * r["n"] for r in rows]
      ceiling = sum(flops) / sum(f / r["gflops"] for f, r in zip(flops, rows))
      out["nets"][f"{agent}_seeds{s}"] = dict(hidden=hidden, batch=batch, seeds=s, ceiling_gflops=ceiling,
                                              devices=sharding.seed_devices(s),
                                              ceiling_fraction_of_peak=ceiling / peak, shapes=rows)
      print(f"{agent} {list(hidden)} b{batch} x {s} seeds: matmul ceiling {ceiling:.1f} GFLOP/s = "
            f"{100 * ceiling / peak:.1f}% of the {peak:.0f} GFLOP/s 1024^2 peak", flush=True)
  out["machine"]["loadavg_at_end"] = os.getloadavg()
  with open(a.out, "w") as f:
    json.dump(out, f, indent=1)
  best = {ag: max(v["ceiling_fraction_of_peak"] for k, v in out["nets"].items() if k.startswith(ag)) for ag in NETS}
  results.update({f"matmul_ceiling_fraction_{ag}_ll": v for ag, v in best.items()},
                 f"benchmarks/matmul_shapes.py --seeds {' '.join(map(str, a.seeds))}: the paper LL network's "
                 f"update matmul shapes alone, best over vmapped seeds (split over {len(jax.devices())} CPU "
                 f"devices), / jnp.dot 1024 peak")


if __name__ == "__main__":
  main()
