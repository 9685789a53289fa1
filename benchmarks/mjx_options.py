"""MJX solver options vs env throughput, compile time and agreement with native MuJoCo (BENCHMARKS.md, "MJX").

  python benchmarks/mjx_options.py [--scenes ant/reach,arm3/push1] [--variants default,n10/10]
                                   [--batch 64] [--steps 100] [--reps 3] [--out benchmarks/mjx_options.json]

Each variant is applied by ``MJXPhysics(model, frame_skip, options)`` to a copy of the MjModel (the
native backend is untouched). Per scene and variant one program is compiled: ``batch`` envs vmapped
inside a jitted ``lax.scan`` of ``steps`` env steps (as ``env_rate`` in env_throughput.py). Its first
two envs get the keys and actions of tests/test_backends.py, so the same run also gives the
agreement with native MuJoCo, measured as that test does (max |qpos diff|; for legged agents over the
first 5 steps and on the torso xy over all steps) and checked against the test's tolerances.
Env steps/s is the best of ``reps`` timed calls (fewer if one call takes over 30 s).
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import sys
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))
import hdt.envs as E  # noqa: E402
from hdt.envs.physics import MJXPhysics  # noqa: E402
from test_backends import LEGGED, SMOOTH  # noqa: E402  (the agreement test's tolerances)

SCENES = [("ant", "reach"), ("arm3", "push1"), ("quadruped", "reach"), ("point", "maze")]
# name -> MJX options (see hdt.envs.physics.mjx_model_copy). "mjcf" = the model's own settings,
# i.e. MuJoCo's defaults here (Newton, 100 iterations, 50 line-search iterations).
VARIANTS = {
    "mjcf": dict(iterations=100, ls_iterations=50, solver="newton"),
    "n10/10": dict(iterations=10, ls_iterations=10, solver="newton"),
    "n4/6": dict(iterations=4, ls_iterations=6, solver="newton"),
    "n1/4": dict(iterations=1, ls_iterations=4, solver="newton"),
    "cg10/10": dict(iterations=10, ls_iterations=10, solver="cg"),
    "n4/6-eulerdamp": dict(iterations=4, ls_iterations=6, solver="newton", disable=("eulerdamp",)),
}
# "<variant>+trim": also fewer candidate contact pairs (bench only, see trim_contacts).


def trim_contacts(model, agent):
  """A copy of ``model`` with fewer collision pairs for MJX to compute. Legged agents: only the torso
  and the feet touch the floor (not exact: a fallen robot's thighs do). Arms: the fingertip keeps the
  block but drops the arena walls, which are out of reach of arm2-4 (exact for them)."""
  m = copy.copy(model)
  names = [m.geom(i).name for i in range(m.ngeom)]
  if E.AGENTS[agent].legged:
    for i, n in enumerate(names):
      if n.startswith("agent/") and not any(k in n for k in ("torso", "ankle", "toe")):
        m.geom_contype[i] = m.geom_conaffinity[i] = 0
  elif agent in ("arm2", "arm3", "arm4"):
    m.geom_conaffinity[names.index("agent/fingertip")] = 2  # walls have contype 1 only
    m.geom_contype[names.index("block/block")] |= 2
  else:
    raise ValueError(f"no contact trimming defined for {agent}")
  return m


def inputs(env, batch, steps):
  """Keys and actions; envs 0-1 get exactly those of tests/test_backends.py (nenv=2, 100 steps)."""
  keys = jnp.concatenate([jax.random.split(jax.random.PRNGKey(0), 2),
                          jax.random.split(jax.random.PRNGKey(3), batch - 2)])
  test_acts = 0.5 * jax.random.uniform(jax.random.PRNGKey(1), (steps, 2, env.action_size), minval=-1, maxval=1)
  acts = jax.random.uniform(jax.random.PRNGKey(2), (steps, batch - 2, env.action_size), minval=-1, maxval=1)
  return keys, jnp.concatenate([test_acts, acts], axis=1)


def compile_run(env, keys, acts):
  def run(keys, acts):
    s = jax.vmap(env.reset)(keys)

    def f(s, a):
      s = jax.vmap(env.step)(s, a)
      return s, (s.reward, s.physics.qpos)
    r, q = jax.lax.scan(f, s, acts)[1]
    return r.sum(), q

  t0 = time.perf_counter()
  f = jax.jit(run).lower(keys, acts).compile()
  return f, time.perf_counter() - t0


def timed(f, keys, acts, reps):
  best, out = float("inf"), None
  for _ in range(reps):
    t0 = time.perf_counter()
    out = jax.block_until_ready(f(keys, acts))
    best = min(best, time.perf_counter() - t0)
    if best > 30:
      break
  return best, out


def agreement(agent, nat, mjx):
  d = np.abs(nat - mjx)
  if agent in LEGGED:
    early, late = LEGGED[agent]
    e, l = float(d[:5].max()), float(d[:, :, :2].max())
    return dict(early=e, late=l, ok=bool(np.isfinite(mjx).all() and e < early and l < late))
  return dict(max=float(d.max()), ok=bool(np.isfinite(mjx).all() and d.max() < SMOOTH))


def main():
  p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  p.add_argument("--scenes", default=",".join(f"{a}/{t}" for a, t in SCENES))
  p.add_argument("--variants", default=",".join(VARIANTS))
  p.add_argument("--batch", type=int, default=64)
  p.add_argument("--steps", type=int, default=100)
  p.add_argument("--reps", type=int, default=3)
  p.add_argument("--out", default="benchmarks/mjx_options.json")
  p.add_argument("--append", action="store_true", help="add rows to an existing --out")
  a = p.parse_args()
  assert a.steps == 100, "the agreement check replays tests/test_backends.py, which runs 100 steps"
  scenes = [tuple(s.split("/")) for s in a.scenes.split(",")]
  variants = a.variants.split(",")
  rows = json.load(open(a.out))["rows"] if a.append else []
  print(f"MJX env steps/s (batch {a.batch}, {a.steps} steps, best of {a.reps}) | compile s | agreement "
        f"with native; {os.cpu_count()} CPU threads, jax {jax.__version__}, mujoco {mujoco.__version__}, "
        f"load {os.getloadavg()[0]:.2f}", flush=True)
  print(f"{'scene':16s} {'variant':16s} {'steps/s':>9s} {'compile':>8s} {'load':>5s}  agreement", flush=True)
  for agent, task in scenes:
    nat_env = E.make(agent, task, backend="native")
    keys, acts = inputs(nat_env, a.batch, a.steps)
    f, _ = compile_run(nat_env, keys, acts)
    nat_q = np.asarray(f(keys, acts)[1])[:, :2]
    first_q = None
    for v in variants:
      env = E.make(agent, task, backend="mjx")
      base, trim = v.split("+")[0], v.endswith("+trim")
      model = trim_contacts(env.mj_model, agent) if trim else env.mj_model
      env.physics = MJXPhysics(model, env.agent.frame_skip, VARIANTS[base])
      f, compile_s = compile_run(env, keys, acts)
      dt, (_, q) = timed(f, keys, acts, a.reps)
      q = np.asarray(q)
      first_q = q if first_q is None else first_q
      agr = agreement(agent, nat_q, q[:, :2])
      agr["vs_first"] = float(np.abs(q - first_q).max())
      load = os.getloadavg()[0]
      rows.append(dict(agent=agent, task=task, variant=v, options=dict(VARIANTS[base], trim=trim), steps_per_s=a.batch * a.steps / dt,
                       compile_s=compile_s, load1=load, agreement=agr))
      agr_s = " ".join(f"{k}={x:.2e}" if isinstance(x, float) else f"{k}={x}" for k, x in agr.items())
      print(f"{agent + '/' + task:16s} {v:16s} {a.batch * a.steps / dt:9.0f} {compile_s:8.1f} {load:5.2f}  {agr_s}",
            flush=True)
      with open(a.out, "w") as fh:
        json.dump(dict(batch=a.batch, steps=a.steps, reps=a.reps, cpu_threads=os.cpu_count(),
                       jax=jax.__version__, mujoco=mujoco.__version__, rows=rows), fh, indent=1)


if __name__ == "__main__":
  main()
