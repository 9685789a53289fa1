"""The best a planar arm's LL can do on its reach task: 1 cm goals (the authors' epsilon_low) that lie
inside the arm's workspace, and what a scripted controller reaches.

    PYTHONPATH=. python benchmarks/reach_ceiling.py [--agents arm3,arm2,arm4] [--episodes 2000]

An LL episode's goal is the fingertip plus a uniform offset in +-delta_max (hdt.envs.tasks.Reach.sample,
the authors' Reacher skill space); near full extension part of that box lies outside the arm's reach.

- ``reachable``: the share of evaluation goals (fresh resets, as ``acting.evaluate`` draws them) within 1 cm
  of the workspace: an annulus around the root (the first joint turns freely), from the fingertip's closest
  approach (the base pole it collides with, or the folded arm) to the stretched arm's length. No policy can
  beat it in expectation.
- ``scripted``: success (``success_max``: within 1 cm at some step, as ``hdt eval`` counts it) of a
  controller that reads only the LL's observation: inverse kinematics on a joint grid (the solution nearest
  in joint space to the current angles), then a saturated PD law on the joint angles. It shows what the
  dynamics allow within the 45-step horizon; best of a few gains.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import hdt  # noqa: E402
from hdt.agents import acting  # noqa: E402

GAINS = [(1.0, 0.3), (1.5, 0.5), (3.0, 1.0), (10.0, 4.0)]  # (kp, kd) in action units per rad, rad/s


def chain(env):
  """(root xy, link lengths, collision radius at the root, action bound of the unsaturated range) of a
  planar arm: hinge bodies in a row along x at zero angles, the fingertip site at the end."""
  m = env.physics.mj_model
  d = mujoco.MjData(m)
  mujoco.mj_kinematics(m, d)
  bodies = [m.jnt_bodyid[j] for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
  tip = d.site_xpos[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "agent/goal_point")]
  pts = np.array([d.xpos[b] for b in bodies] + [tip])
  if not np.allclose(pts[:, 1:], pts[0, 1:], atol=1e-9):
    raise SystemExit(f"{env.agent.name}: not a planar chain along x at zero angles")
  lengths = np.diff(pts[:, 0])
  size = lambda name: m.geom_size[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name), 0]
  names = {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) for g in range(m.ngeom)}
  pole = size("agent/base") + size("agent/fingertip") if {"agent/base", "agent/fingertip"} <= names else 0.0
  # a motor's force saturates at forcerange before ctrlrange: beyond it, more action only costs control
  a_max = float(np.min(np.where(m.actuator_forcelimited > 0, m.actuator_forcerange[:, 1] / m.actuator_ctrlrange[:, 1],
                                1.0)))
  return pts[0, :2], lengths, float(pole), a_max


def measure(agent: str, episodes: int, grid_points: int, key: int = 1) -> dict:
  env = hdt.envs.make(agent, "reach")
  root, lengths, pole, a_max = chain(env)
  n = len(lengths)
  eps = env.agent.reach_eps

  def fk(q):
    a = jnp.cumsum(q, -1)
    return jnp.stack([(jnp.cos(a) * lengths).sum(-1), (jnp.sin(a) * lengths).sum(-1)], -1)

  m = env.physics.mj_model
  lim = [m.jnt_range[j, 1] if m.jnt_limited[j] else np.pi for j in range(1, n)]
  axes = [np.linspace(-l * 0.98, l * 0.98, grid_points) for l in lim]
  tail = np.array(list(itertools.product(*axes)), np.float32)  # joints 1..n-1; joint 0 is solved for
  p0 = np.asarray(fk(jnp.concatenate([jnp.zeros((len(tail), 1)), tail], 1)))
  r0, phi0 = np.linalg.norm(p0, axis=1), np.arctan2(p0[:, 1], p0[:, 0])
  r_in, r_out = max(float(r0.min()), pole), float(lengths.sum())

  # evaluation goals: acting.evaluate's resets for this key
  s0 = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(key), episodes))
  q0 = np.asarray(s0.physics.qpos)[:, :n]
  fk_err = np.abs(np.asarray(fk(jnp.asarray(q0))) + root - np.asarray(s0.obs_hi)[:, :2]).max()
  if fk_err > 1e-4:
    raise SystemExit(f"{agent}: the chain's kinematics misses the sensor by {fk_err:.2g} m")
  rg = np.linalg.norm(np.asarray(s0.task["t"]["goal"]) - root, axis=1)
  reachable = float(np.mean((rg <= r_out + eps) & (rg >= r_in - eps)))

  wrap = lambda x: (x + jnp.pi) % (2 * jnp.pi) - jnp.pi
  tail_j, r0_j, phi0_j = map(jnp.asarray, (tail, r0, phi0))

  def controller(kp, kd):
    def act(obs):  # obs: cos q, sin q, qvel, goal - fingertip (hdt's arm LL observation)
      q = jnp.arctan2(obs[n:2 * n], obs[:n])
      v, rel = obs[2 * n:3 * n], obs[-2:]
      goal = fk(q) + rel
      theta0 = jnp.arctan2(goal[1], goal[0]) - phi0_j
      far = jnp.abs(r0_j - jnp.linalg.norm(goal))
      dist = wrap(theta0 - q[0]) ** 2 + jnp.sum(jnp.square(tail_j - q[1:]), -1)
      i = jnp.argmin(jnp.where(far < 0.3 * eps, dist, 1e3 + far))  # nearest exact solution, else the closest
      err = jnp.concatenate([wrap(theta0[i] - q[0])[None], tail_j[i] - q[1:]])
      return jnp.clip(kp * err - kd * v, -a_max, a_max)
    return lambda params, obs: jax.vmap(act)(obs)

  scripted = {}
  for kp, kd in GAINS:
    out = jax.jit(lambda k: acting.evaluate(env, controller(kp, kd), None, k, episodes))(jax.random.PRNGKey(key))
    scripted[f"kp={kp},kd={kd}"] = {k: float(out[k]) for k in ("success_max", "goal_dist_final", "return")}
  best = max(scripted, key=lambda g: scripted[g]["success_max"])
  se = lambda p: float(np.sqrt(p * (1 - p) / episodes))
  return dict(agent=agent, episodes=episodes, eps=eps, delta_max=env.agent.delta_max, links=lengths.tolist(),
              workspace=[r_in, r_out], reachable=reachable, reachable_se=se(reachable),
              scripted_best=best, scripted=scripted[best]["success_max"], scripted_se=se(scripted[best]["success_max"]),
              scripted_all=scripted, a_max=a_max)


def main():
  p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  p.add_argument("--agents", default="arm3,arm2,arm4")
  p.add_argument("--episodes", type=int, default=2000)
  p.add_argument("--grid-points", type=int, default=0, help="per joint (default: 801, 201, 41 for 1, 2, 3 joints after the first)")
  p.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "reach_ceiling.json"))
  p.add_argument("--no-results", action="store_true", help="do not update benchmarks/results.json")
  args = p.parse_args()
  rows = []
  for agent in args.agents.split(","):
    n_tail = len(hdt.envs.AGENTS[agent].ll_qpos_noise) - 1
    rows.append(measure(agent, args.episodes, args.grid_points or {1: 801, 2: 201}.get(n_tail, 41)))
    r = rows[-1]
    print(f"{agent}: goals within 1 cm of the workspace {r['reachable']:.3f} ± {r['reachable_se']:.3f}; "
          f"scripted IK + PD {r['scripted']:.3f} ± {r['scripted_se']:.3f} ({r['scripted_best']}); "
          f"workspace {r['workspace'][0]:.3f}-{r['workspace'][1]:.3f} m, {args.episodes} episodes", flush=True)
  with open(args.out + ".tmp", "w") as f:
    json.dump(rows, f, indent=1)
  os.replace(args.out + ".tmp", args.out)
  arm3 = [r for r in rows if r["agent"] == "arm3"]
  if arm3 and not args.no_results:
    import results
    src = (f"benchmarks/reach_ceiling.py: arm3 LL evaluation goals (fresh resets, {args.episodes} episodes) within "
           f"1 cm of the workspace / scripted IK + PD success_max")
    results.update({"arm3_reach_1cm_goal_ceiling": arm3[0]["reachable"],
                    "arm3_reach_1cm_scripted": arm3[0]["scripted"]}, src)


if __name__ == "__main__":
  main()
