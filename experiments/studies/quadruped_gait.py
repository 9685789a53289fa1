"""How fast can the quadruped walk? Open-loop periodic gaits found by the cross-entropy method.

    python experiments/studies/quadruped_gait.py [--objective speed|reward] [--iters 40] [--pop 64] [--json PATH]

The LL must cover up to 4 m in its 150-step (2.25 s) reach episodes; the trained LLs walk at
0.68-0.80 m/s, and half of the goals would need 1.30 m/s (RESULTS.md, Table 1). This asks whether the
body can do it: each gait drives the 12 servos of hdt's quadruped (the authors' DM Control robot, its
reach env: same physics, starts and action map) with one sinusoid per actuator,

    a = clip(offset_kind + amp_kind * sin(2 pi f t + phase_kind + phase_leg), -1, 1) * (sign_leg for yaw)

18 numbers: the frequency; amplitude, offset and phase of each actuator kind (yaw, lift, extend); a
phase and a yaw sign per leg (a trot, a pace or a bound are points of this family). A gait's score is
the torso's planar displacement over the episode divided by its 2.25 s, counted as 0 if it falls
(the env's fall test), averaged over 4 fresh starts of the reach env. Reported: the best gait's mean speed over 32 fresh starts, the steady speed
over its last second, and the share of goals uniform in the ±4 m box that speed brings within 0.27 m
of the start in 2.25 s. ``--objective reward`` scores a gait instead by what the authors' LL reward
pays per step (its speed minus 0.5 sum(ctrl^2), ``quadruped.py`` ``low_level_reward`` and
``hierarchical.py`` ``low_level_step``): the gait an optimal LL would settle on, had it no goal to reach.
"""

from __future__ import annotations

import argparse
import json
import math

import jax
import jax.numpy as jnp
import numpy as np

LO = np.array([0.5] + [0.0, -1.0, 0.0] * 3 + [0.0] * 4 + [-1.0] * 4, np.float32)
HI = np.array([4.0] + [1.0, 1.0, 2 * math.pi] * 3 + [2 * math.pi] * 4 + [1.0] * 4, np.float32)


def make_rollout(env, steps: int):
  dt = float(env.dt)
  n_legs, kinds = 4, 3

  def actions(p, t):
    f = p[0]
    amp, off, ph = p[1:10:3], p[2:10:3], p[3:10:3]
    leg_ph, sign = p[10:14], p[14:18]
    phase = 2 * jnp.pi * f * t * dt + ph[None, :] + leg_ph[:, None]  # (leg, kind)
    a = jnp.clip(off[None, :] + amp[None, :] * jnp.sin(phase), -1.0, 1.0)
    a = a.at[:, 0].multiply(sign)
    return a.reshape(n_legs * kinds)  # the actuators' order: per leg yaw, lift, extend

  def rollout(p, key):
    s0 = env.reset(key)

    def f(s, t):
      a = actions(p, t)
      n = env.step(s, a, auto_reset=False)
      return n, (n.obs_hi[:2], n.metrics["fall"], jnp.sum(env.ctrl(a) ** 2))

    _, (xy, fall, sq) = jax.lax.scan(f, s0, jnp.arange(steps))
    return jnp.concatenate([s0.obs_hi[None, :2], xy]), jnp.any(fall > 0), jnp.mean(sq)

  return jax.jit(jax.vmap(rollout, in_axes=(0, 0))), dt


def score(xy, fell, dt):
  seconds = (xy.shape[1] - 1) * dt
  speed = np.linalg.norm(xy[:, -1] - xy[:, 0], axis=-1) / seconds
  return np.where(fell, 0.0, speed)


def main() -> None:
  ap = argparse.ArgumentParser()
  ap.add_argument("--iters", type=int, default=30)
  ap.add_argument("--pop", type=int, default=64)
  ap.add_argument("--elite", type=int, default=8)
  ap.add_argument("--objective", choices=("speed", "reward"), default="speed",
                  help="speed: the fastest gait; reward: the gait the authors' LL reward pays most")
  ap.add_argument("--starts", type=int, default=4, help="fresh starts per gait and iteration")
  ap.add_argument("--seed", type=int, default=0)
  ap.add_argument("--json", default=None)
  args = ap.parse_args()
  from hdt.agents.sharding import use_cpu_cores
  use_cpu_cores()
  from hdt.envs import make
  env = make("quadruped", "reach")
  steps = env.horizon
  rollout, dt = make_rollout(env, steps)
  lam = float(env.agent.ctrl_cost)
  # "speed": the body's ability; "reward": what the authors' LL reward pays per step for walking at that
  # speed (speed towards the goal minus lambda * sum(ctrl^2); the survive bonus is the same for every gait)
  objective = (lambda v, sq: v) if args.objective == "speed" else (lambda v, sq: v - lam * sq)
  rng = np.random.default_rng(args.seed)
  mean, std = (LO + HI) / 2, (HI - LO) / 2
  best = (-1.0, None)
  history = []
  for it in range(args.iters):
    pop = np.clip(mean + std * rng.standard_normal((args.pop, len(LO))), LO, HI).astype(np.float32)
    # each gait from the same args.starts fresh starts (common random numbers), scored by its mean
    keys = jnp.tile(jax.random.split(jax.random.PRNGKey(1000 + it), args.starts), (args.pop, 1))
    xy, fell, sq = jax.device_get(rollout(jnp.asarray(np.repeat(pop, args.starts, 0)), keys))
    s = objective(score(xy, fell, dt), sq).reshape(args.pop, args.starts).mean(1)
    order = np.argsort(-s)
    elite = pop[order[:args.elite]]
    mean, std = elite.mean(0), np.maximum(elite.std(0), 0.02 * (HI - LO))
    if s[order[0]] > best[0]:
      best = (float(s[order[0]]), pop[order[0]])
    history.append(dict(iter=it, best=float(s[order[0]]), elite_mean=float(s[order[:args.elite]].mean()),
                        fell=float(np.mean(fell))))
    unit = " m/s" if args.objective == "speed" else " per step"
    print(f"iter {it:2d}: best {s[order[0]]:.2f}{unit}, elite mean {s[order[:args.elite]].mean():.2f}, "
          f"falls {np.mean(fell):.2f}", flush=True)
  # the best gait from 32 fresh starts
  n = 32
  p = jnp.asarray(np.repeat(best[1][None], n, 0))
  xy, fell, sq = jax.device_get(rollout(p, jax.random.split(jax.random.PRNGKey(7), n)))
  speeds = score(xy, fell, dt)
  last = int(round(1.0 / dt))
  steady = np.linalg.norm(xy[:, -1] - xy[:, -1 - last], axis=-1) / (last * dt)
  eps, box = float(env.agent.reach_eps), float(env.agent.delta_max)
  g = np.random.default_rng(0).uniform(-box, box, (200_000, 2))
  within = lambda v: float(np.mean(np.hypot(g[:, 0], g[:, 1]) < eps + v * steps * dt))
  out = dict(episode_s=steps * dt, best_gait=[float(x) for x in best[1]],
             objective=args.objective, ctrl_sq_per_step=float(sq.mean()),
             reward_rate_without_survive=float(np.mean(speeds - lam * sq)), speed_mean=float(speeds.mean()), speed_min=float(speeds.min()), falls=float(np.mean(fell)),
             steady_speed_last_1s=float(steady.mean()), goals_within_reach_at_that_speed=within(float(speeds.mean())),
             search=history, pop=args.pop, iters=args.iters, seed=args.seed)
  print(json.dumps({k: v for k, v in out.items() if k not in ("search", "best_gait")}, indent=1))
  if args.json:
    with open(args.json, "w") as fh:
      json.dump(out, fh, indent=1)


if __name__ == "__main__":
  main()
