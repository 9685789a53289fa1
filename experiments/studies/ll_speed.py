"""How fast a navigation LL walks to its goal, and what that allows within its episode.

    python experiments/studies/ll_speed.py RUN [RUN ...] [--episodes 64] [--horizon N] [--action-scale S ...] [--json PATH]

For each LL run (a run directory or zoo:NAME; its best parameters), deterministic reach episodes
without auto-reset: the start and final distance to the goal, the speed towards it (up to the first step within epsilon), the control cost
and reward per step, the share that comes within the reach epsilon at some step (overall and by the
goal's start distance), and the ceiling that
speed sets: the share of the LL's goals (uniform in the ±delta_max box) within
``epsilon + speed x episode length``.

``--action-scale``: the LL's actions multiplied by each factor (then clipped to the action box), a
policy near the trained one with longer or shorter strides: whether the env's reward would pay a
faster walk than the one training found.
"""

from __future__ import annotations

import argparse
import json
import math

import jax
import jax.numpy as jnp
import numpy as np


def reach_ceiling(radius: float, delta_max: float, n: int = 200_000, seed: int = 0) -> float:
  """The share of goals uniform in the ±delta_max square that lie within ``radius`` of the start."""
  g = np.random.default_rng(seed).uniform(-delta_max, delta_max, (n, 2))
  return float(np.mean(np.hypot(g[:, 0], g[:, 1]) < radius))


def measure(run: str, episodes: int = 64, horizon: int | None = None, key: int = 3, action_scale: float = 1.0) -> dict:
  from hdt.transfer.evaluate import load_policy
  policy = load_policy(run, "best")
  overrides = {} if horizon is None else {"ll_horizon": horizon}
  env = policy.card.make_env("reach", "auto", **overrides)
  steps = env.horizon
  first = lambda tree: jax.tree.map(lambda x: x[0], tree)
  apply, params = policy.card.policy_fn(first(policy.obs_norm)), first(policy.params)
  cost = env.agent.ctrl_cost

  def episode(k):
    def f(s, _):
      a = jnp.clip(action_scale * apply(params, s.obs), -1.0, 1.0)
      n = env.step(s, a, auto_reset=False)
      return n, (n.metrics["goal_dist"], cost * jnp.sum(env.ctrl(a) ** 2), n.reward)
    return jax.lax.scan(f, env.reset(k), None, length=steps)[1]

  dist, ctrl, reward = jax.device_get(jax.jit(jax.vmap(episode))(
      jax.random.split(jax.random.PRNGKey(key), episodes)))
  seconds = steps * float(env.dt)
  start, end = dist[:, 0], dist[:, -1]
  eps, box = float(env.agent.reach_eps), float(env.agent.delta_max)
  # walking speed: up to the first step within eps (an LL that arrived stands still after it)
  hit = dist < eps
  reached = hit.any(axis=1)
  last = np.where(reached, hit.argmax(axis=1), steps - 1)
  rows = np.arange(len(dist))
  speed = float(np.mean((start - dist[rows, last]) / ((last + 1) * float(env.dt))))
  # reach success by the goal's start distance: what the LL does with goals its speed allows
  edges = [0.0, 1.0, 2.0, 3.0, 4.0, np.inf]
  by_dist = {f"{lo:g}-{hi:g} m": dict(episodes=int(m.sum()), reached=float(reached[m].mean()) if m.any() else None)
             for lo, hi in zip(edges, edges[1:]) for m in [(start >= lo) & (start < hi)]}
  return dict(run=run, agent=policy.agent, action_scale=action_scale, steps=steps, seconds=seconds, episodes=episodes,
              start_dist=float(start.mean()), final_dist=float(end.mean()), speed=speed,
              reached=float(reached.mean()), reached_by_start_dist=by_dist, ctrl_cost_per_step=float(ctrl.mean()),
              reward_per_step=float(reward.mean()),
              ceiling_at_this_speed=reach_ceiling(eps + speed * seconds, box),
              speed_for_half=(math.sqrt(0.5 * (2 * box) ** 2 / math.pi) - eps) / seconds)


def main(argv=None) -> None:
  ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  ap.add_argument("runs", nargs="+")
  ap.add_argument("--episodes", type=int, default=64)
  ap.add_argument("--horizon", type=int, default=None, help="LL episode length (default: the agent's)")
  ap.add_argument("--action-scale", type=float, nargs="+", default=[1.0],
                  help="multiply the LL's actions by each factor (default 1: the policy as trained)")
  ap.add_argument("--json", default=None)
  args = ap.parse_args(argv)
  rows = [measure(r, args.episodes, args.horizon, action_scale=s) for r in args.runs for s in args.action_scale]
  for r in rows:
    scaled = "" if r["action_scale"] == 1.0 else f" (actions x{r['action_scale']:g})"
    print(f"{r['run']}{scaled}: {r['steps']} steps = {r['seconds']:.2f} s; distance {r['start_dist']:.2f} -> "
          f"{r['final_dist']:.2f} m, speed towards the goal {r['speed']:.2f} m/s, reached {r['reached']:.2f} "
          f"(ceiling at this speed {r['ceiling_at_this_speed']:.2f}; half the goals need "
          f"{r['speed_for_half']:.2f} m/s); per step: ctrl cost {r['ctrl_cost_per_step']:.2f}, "
          f"reward {r['reward_per_step']:.2f}")
    print("  reached by start distance: " + ", ".join(
        f"{k} {v['reached']:.2f} ({v['episodes']})" for k, v in r["reached_by_start_dist"].items() if v["episodes"]))
  if args.json:
    from hdt import atomic
    atomic.write_text(args.json, json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
  main()
