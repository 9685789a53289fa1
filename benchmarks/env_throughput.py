"""Environment throughput: MJX vs the native backend vs raw mujoco.rollout, per agent and scene.

  python benchmarks/env_throughput.py [--batch 64] [--steps 200] [--skip-mjx] [--scenes point:reach,ant:reach]
                                     [--out benchmarks/env_throughput.json]

Env steps/s are full environment steps (best of 3 timed calls) (frame_skip physics steps each, plus rewards, observations and
auto-reset), batched with vmap inside a jitted lax.scan. Raw rollout is the upper bound for the native
backend: one mujoco.rollout call over the same batch and the same number of physics steps, no JAX.
"native" is the XLA FFI custom call; "callback" the same backend through jax.pure_callback (its fallback).
"""

from __future__ import annotations

import argparse
import json
import os
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout

import hdt.envs as E
from hdt.envs.physics import NativePhysics

SCENES = [("point", "reach"), ("point", "maze"), ("ant", "reach"), ("ant", "maze"), ("ant", "steps"),
          ("ant3", "reach"), ("ant2", "reach"), ("quadruped", "reach"), ("arm_point", "push1"),
          ("arm2", "push1"), ("arm3", "push1"), ("arm3", "insert"), ("arm4", "push1"), ("arm4", "insert")]


def env_rate(env, batch, steps):
  keys = jax.random.split(jax.random.PRNGKey(0), batch)
  acts = jax.random.uniform(jax.random.PRNGKey(1), (steps, batch, env.action_size), minval=-1, maxval=1)

  def run(keys, acts):
    s = jax.vmap(env.reset)(keys)
    s, r = jax.lax.scan(lambda s, a: (lambda n: (n, n.reward))(jax.vmap(env.step)(s, a)), s, acts)
    return r.sum()

  t0 = time.perf_counter()
  f = jax.jit(run).lower(keys, acts).compile()
  compile_s = time.perf_counter() - t0
  f(keys, acts).block_until_ready()
  return batch * steps / _best_time(lambda: f(keys, acts).block_until_ready()), compile_s


def _best_time(fn, repeats=3):
  """Best of ``repeats`` wall-clock times: the least disturbed by other processes."""
  times = []
  for _ in range(repeats):
    t0 = time.perf_counter()
    fn()
    times.append(time.perf_counter() - t0)
  return min(times)


def raw_rollout_rate(env, batch, steps):
  m = env.mj_model
  nthread = os.cpu_count() or 1
  datas = [mujoco.MjData(m) for _ in range(nthread)]
  d = mujoco.MjData(m)
  mujoco.mj_forward(m, d)
  state = np.tile(np.concatenate([[d.time], d.qpos, d.qvel]), (batch, 1))
  nphys = steps * env.agent.frame_skip
  ctrl = np.random.default_rng(0).uniform(-1, 1, (batch, nphys, m.nu)) * m.actuator_ctrlrange[:, 1]
  rollout.rollout(m, datas, state, ctrl[:, :10], persistent_pool=True)
  return batch * steps / _best_time(lambda: rollout.rollout(m, datas, state, ctrl, persistent_pool=True))


def main():
  p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  p.add_argument("--batch", type=int, default=64)
  p.add_argument("--steps", type=int, default=200)
  p.add_argument("--skip-mjx", action="store_true")
  p.add_argument("--scenes", default=None, help="comma-separated agent:task pairs (default: all)")
  p.add_argument("--out", default="benchmarks/env_throughput.json")
  a = p.parse_args()
  rows = []
  scenes = SCENES if a.scenes is None else [tuple(s.split(":")) for s in a.scenes.split(",")]
  hdr = (f"{'agent':10s} {'task':7s} {'fs':>2s} {'raw rollout':>12s} {'native':>10s} {'callback':>10s} "
         f"{'mjx':>10s} {'native/raw':>10s} {'native/mjx':>10s} {'compile n/m (s)':>16s}")
  print(f"env steps/s, batch {a.batch}, {a.steps} steps, {os.cpu_count()} CPU threads, jax {jax.__version__}, "
        f"mujoco {mujoco.__version__}\n{hdr}", flush=True)
  for agent, task in scenes:
    nat_env = E.make(agent, task, backend="native")
    raw = raw_rollout_rate(nat_env, a.batch, a.steps)
    nat, nat_c = env_rate(nat_env, a.batch, a.steps)
    cb_env = E.make(agent, task, backend="native")
    cb_env.physics = NativePhysics(cb_env.mj_model, cb_env.agent.frame_skip, use_ffi=False)
    cb, _ = env_rate(cb_env, a.batch, a.steps)
    mjx, mjx_c = (float("nan"), float("nan")) if a.skip_mjx else env_rate(
        E.make(agent, task, backend="mjx"), a.batch, a.steps)
    rows.append(dict(agent=agent, task=task, frame_skip=nat_env.agent.frame_skip, raw_rollout=raw,
                     native=nat, native_callback=cb, mjx=mjx, native_over_raw=nat / raw, native_over_mjx=nat / mjx,
                     compile_native_s=nat_c, compile_mjx_s=mjx_c))
    print(f"{agent:10s} {task:7s} {nat_env.agent.frame_skip:2d} {raw:12.0f} {nat:10.0f} {cb:10.0f} {mjx:10.0f} "
          f"{nat / raw:10.2f} {nat / mjx:10.1f} {nat_c:7.1f}/{mjx_c:<7.1f}", flush=True)
  with open(a.out, "w") as f:
    json.dump(dict(batch=a.batch, steps=a.steps, cpu_threads=os.cpu_count(), rows=rows), f, indent=1)


if __name__ == "__main__":
  main()
