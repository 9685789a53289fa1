"""Waypoint return of a scripted greedy HL (sub-goal = the waypoint, clipped to the sub-goal box)
over a point-mass LL, for the authors' class defaults k = 15 (point mass) and 20 (ant, quadruped) and
the paper's k = 32 (RESULTS.md, Waypoint).

  python experiments/studies/waypoint_k.py [--low zoo:point/low] [--k 15 20 32]
"""

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from hdt.transfer.pipeline import high_env


def greedy_return(k: int, episodes: int = 32, low: str = "zoo:point/low") -> tuple[float, float, float]:
  env = high_env("waypoint", low, k=k)

  def episode(key):
    def step(s, _):
      a = jnp.clip((s.obs_hi[2:4] - s.obs_hi[:2]) / env.delta_max, -1, 1)  # obs_hi = (point, waypoint)
      s = env.step(s, a)
      return s, (s.reward, s.metrics["waypoints"] > 0)
    _, (r, hit) = jax.lax.scan(step, env.reset(key), None, length=env.horizon)
    return r.sum(), hit.sum()

  r, hits = jax.jit(jax.vmap(episode))(jax.random.split(jax.random.PRNGKey(0), episodes))
  return float(np.mean(r)), float(np.std(r)), float(np.mean(hits))


if __name__ == "__main__":
  ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  ap.add_argument("--low", default="zoo:point/low", help="the LL run or zoo entry")
  ap.add_argument("--k", type=int, nargs="+", default=[15, 20, 32])
  ap.add_argument("--episodes", type=int, default=32)
  args = ap.parse_args()
  for k in args.k:
    mean, std, hits = greedy_return(k, args.episodes, args.low)
    print(f"k={k}: greedy HL return {mean:.0f} ± {std:.0f}, HL steps with a waypoint {hits:.1f} of 50")
