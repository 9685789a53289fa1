"""SAC throughput on this machine: gradient updates/s, their GFLOP/s, and end-to-end env steps/s.

    python benchmarks/sac_throughput.py [--quick] [--single-thread-eigen] [--out FILE]

Writes ``benchmarks/sac_throughput.json`` next to this file (or ``--out``) and prints a table.
Compile times are included in the JSON; set JAX_COMPILATION_CACHE_DIR to reuse compilations.

FLOP counting (analytic, matmuls only; a multiply-add is 2 FLOPs; biases, activations, the
tanh-Gaussian, Adam, sampling and gathers are not counted). For an MLP with layer widths
d_0 -> ... -> d_L, a forward pass costs F = sum_i 2 d_i d_{i+1} per sample; a backward pass costs F
for the weight gradients plus F - F_1 for the input gradients (F_1 = first layer) when the network
input needs no gradient, or F when it does. Per sample of one SAC update:

  critic step: policy fwd on s' (F_pi) + target twin-Q fwd (2 F_q) + online twin-Q fwd (2 F_q)
               + online twin-Q backward, weights and inner inputs (2 F_q + 2 (F_q - F_q1))
  actor step:  policy fwd (F_pi) + twin-Q fwd (2 F_q) + twin-Q backward to the action input only
               (2 F_q; the whole first layer is counted) + policy backward (F_pi + F_pi - F_pi1)

times the batch size. Policy widths [obs, h..., 2*act]; critic widths [obs+act, h..., 1].
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

if "--single-thread-eigen" in sys.argv:  # must be set before jax is imported
  os.environ["XLA_FLAGS"] = os.environ.get("XLA_FLAGS", "") + " --xla_cpu_multi_thread_eigen=false"

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from hdt.agents import networks as nets  # noqa: E402
from hdt.agents import replay as replay_lib  # noqa: E402
from hdt.agents.sac import SACConfig, init_sac_state, make_update  # noqa: E402
from hdt.agents.train import make_train, seed_keys  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests"))
from toy_env import PointGoal  # noqa: E402

# (name, hidden sizes, batch, obs size, action size, what the dims stand for)
SIZES = [
    ("PM LL [64,64] b64", (64, 64), 64, 4, 2, "point mass LL: vel+g-xy / 2 forces"),
    ("manip LL [128,96] b100", (128, 96), 100, 11, 3, "3-link arm LL: cos,sin,vel,g-tip / 3"),
    ("ant LL [400,300] b100", (400, 300), 100, 125, 8, "ant LL with 96 contact forces / 8"),
    ("reference [256,256] b256", (256, 256), 256, 125, 8, "ant dims, brax-style net"),
]


def mlp_flops(widths):
  layers = [2 * a * b for a, b in zip(widths[:-1], widths[1:])]
  return sum(layers), layers[0]


def update_flops(hidden, batch, obs, act):
  f_pi, f_pi1 = mlp_flops([obs, *hidden, 2 * act])
  f_q, f_q1 = mlp_flops([obs + act, *hidden, 1])
  critic = f_pi + 2 * f_q + 2 * f_q + 2 * f_q + 2 * (f_q - f_q1)
  actor = f_pi + 2 * f_q + 2 * f_q + f_pi + (f_pi - f_pi1)
  return batch * (critic + actor)


def timeit(fn, *args, repeats=5, min_time=0.5):
  """Median wall time of fn(*args) (blocked), after one warm-up call; returns (seconds, compile_s)."""
  t0 = time.perf_counter()
  jax.block_until_ready(fn(*args))
  compile_s = time.perf_counter() - t0
  times = []
  for _ in range(repeats):
    t0 = time.perf_counter()
    n = 0
    while True:
      jax.block_until_ready(fn(*args))
      n += 1
      if time.perf_counter() - t0 >= min_time:
        break
    times.append((time.perf_counter() - t0) / n)
  return float(np.median(times)), compile_s


def matmul_gflops(n=1024):
  a = jax.random.normal(jax.random.PRNGKey(0), (n, n), jnp.float32)
  b = jax.random.normal(jax.random.PRNGKey(1), (n, n), jnp.float32)
  f = jax.jit(jnp.dot)
  t, _ = timeit(f, a, b)
  return 2 * n ** 3 / t / 1e9


def bench_updates(hidden, batch, obs, act, seeds, n_updates):
  """n_updates SAC updates in one lax.scan (sampling from a filled replay included)."""
  cfg = SACConfig(hidden_sizes=hidden, batch_size=batch, buffer_size=10_000)
  net = nets.make_sac_networks(obs, act, hidden)
  update = make_update(net, cfg, act)

  def init(key):
    k1, k2 = jax.random.split(key)
    rb = replay_lib.init(cfg.buffer_size, replay_lib.make_transition_spec(obs, act))
    data = jax.tree_util.tree_map(
        lambda x: jax.random.uniform(k2, x.shape, jnp.float32, -1.0, 1.0), rb.data
    )
    rb = rb.replace(data=data, size=jnp.asarray(cfg.buffer_size, jnp.int32))
    return init_sac_state(net, cfg, k1), rb, key

  def many(carry):
    state, rb, key = carry

    def one(c, _):
      state, key = c
      key, k_idx, k_noise = jax.random.split(key, 3)
      b = replay_lib.sample(rb, k_idx, batch)
      noise = jax.random.normal(k_noise, (2, batch, act))
      state, m = update(state, b, noise)
      return (state, key), m["critic_loss"]

    (state, key), losses = jax.lax.scan(one, (state, key), None, length=n_updates)
    return (state, rb, key), losses[-1]

  keys = seed_keys(range(seeds))
  carry = jax.jit(jax.vmap(init))(keys)
  f = jax.jit(jax.vmap(many), donate_argnums=0)
  holder = {"c": carry}

  def call():
    holder["c"], loss = f(holder["c"])
    return loss

  t, compile_s = timeit(call, repeats=3, min_time=0.3)
  return n_updates / t, compile_s  # updates/s per seed


def bench_env_steps(seeds, buffer_size=200_000, steps=1000):
  env = PointGoal()
  cfg = SACConfig(total_env_steps=10 * steps, steps_per_chunk=steps, learning_starts=0,
                  buffer_size=buffer_size)
  tr = make_train(env, cfg)
  ts = jax.jit(jax.vmap(tr.init))(seed_keys(range(seeds)))
  f = jax.jit(jax.vmap(tr.run_chunk), donate_argnums=0)
  holder = {"ts": ts}

  def call():
    holder["ts"], m = f(holder["ts"])
    return m["critic_loss"]

  t, compile_s = timeit(call, repeats=3, min_time=0.3)
  return seeds * steps / t, compile_s


def main():
  ap = argparse.ArgumentParser()
  ap.add_argument("--quick", action="store_true", help="fewer sizes, for a smoke run")
  ap.add_argument("--vmap-seeds", type=int, default=8)
  ap.add_argument("--single-thread-eigen", action="store_true",
                  help="XLA_FLAGS=--xla_cpu_multi_thread_eigen=false (one thread per matmul)")
  ap.add_argument("--out", default=os.path.join(HERE, "sac_throughput.json"))
  args = ap.parse_args()
  sizes = SIZES[:1] if args.quick else SIZES

  peak = matmul_gflops()
  print(f"dense float32 matmul (jnp.dot 1024x1024): {peak:.1f} GFLOP/s")
  rows = []
  for name, hidden, batch, obs, act, dims in sizes:
    flops = update_flops(hidden, batch, obs, act)
    n_upd = max(50, min(1000, int(2e10 / flops)))  # ~1-2 s per call
    ups1, c1 = bench_updates(hidden, batch, obs, act, 1, n_upd)
    upsn, cn = bench_updates(hidden, batch, obs, act, args.vmap_seeds, max(20, n_upd // 4))
    row = dict(
        config=name, hidden=list(hidden), batch=batch, obs=obs, act=act, dims=dims,
        mflop_per_update=flops / 1e6,
        updates_per_s_1seed=ups1, gflops_1seed=ups1 * flops / 1e9,
        vmap_seeds=args.vmap_seeds, updates_per_s_per_seed_vmapped=upsn,
        gflops_vmapped=upsn * args.vmap_seeds * flops / 1e9,
        compile_s_1seed=c1, compile_s_vmapped=cn,
    )
    row["pct_of_matmul_1seed"] = 100 * row["gflops_1seed"] / peak
    row["pct_of_matmul_vmapped"] = 100 * row["gflops_vmapped"] / peak
    rows.append(row)
    print(f"  {name}: {ups1:.0f} upd/s, {row['gflops_1seed']:.1f} GFLOP/s (compile {c1:.1f}s); "
          f"{args.vmap_seeds} seeds: {upsn:.0f} upd/s/seed (compile {cn:.1f}s)")

  env_rows = []
  for seeds, buf in [(1, 200_000), (16, 200_000)] + ([] if args.quick else [(1, 1_000_000)]):
    sps, c = bench_env_steps(seeds, buf)
    env_rows.append(dict(seeds=seeds, buffer_size=buf, env_steps_per_s=sps,
                         env_steps_per_s_per_seed=sps / seeds, compile_s=c))
    print(f"  run_chunk toy env, {seeds} seed(s), buffer {buf}: {sps:.0f} env steps/s (compile {c:.1f}s)")

  load = os.getloadavg()
  result = dict(
      machine=dict(platform=platform.platform(), cpus=os.cpu_count(), jax=jax.__version__,
                   device=str(jax.devices()[0]), loadavg_at_end=load,
                   xla_flags=os.environ.get("XLA_FLAGS", "")),
      matmul_gflops_1024=peak,
      flop_counting=__doc__.split("FLOP counting")[1].strip(),
      updates=rows,
      env_steps=env_rows,
  )
  with open(args.out, "w") as f:
    json.dump(result, f, indent=2)

  print()
  print(f"SAC gradient-update throughput (float32, CPU x{os.cpu_count()}; dense matmul peak "
        f"{peak:.1f} GFLOP/s; load avg {load[0]:.1f})")
  hdr = (f"{'config':26s} {'obs/act':>7s} {'MFLOP/upd':>9s} {'upd/s':>7s} {'GFLOP/s':>8s} "
         f"{'%peak':>6s} | {'upd/s/seed':>10s} {'GFLOP/s':>8s} {'%peak':>6s}  ({args.vmap_seeds} seeds vmapped)")
  print(hdr)
  print("-" * len(hdr))
  for r in rows:
    print(f"{r['config']:26s} {r['obs']:>3d}/{r['act']:<3d} {r['mflop_per_update']:9.2f} "
          f"{r['updates_per_s_1seed']:7.0f} {r['gflops_1seed']:8.2f} {r['pct_of_matmul_1seed']:5.1f}% | "
          f"{r['updates_per_s_per_seed_vmapped']:10.0f} {r['gflops_vmapped']:8.2f} "
          f"{r['pct_of_matmul_vmapped']:5.1f}%")
  print()
  print("End to end (run_chunk on the toy env: policy act + env step + replay insert + 1 update per env step, [64,64] b64)")
  print(f"{'seeds':>5s} {'buffer':>9s} {'env steps/s':>12s} {'per seed':>9s}")
  for r in env_rows:
    print(f"{r['seeds']:5d} {r['buffer_size']:9d} {r['env_steps_per_s']:12.0f} {r['env_steps_per_s_per_seed']:9.0f}")


if __name__ == "__main__":
  main()
