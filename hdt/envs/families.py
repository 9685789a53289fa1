"""Defaults of the three robot families, shared by the registry (``hdt.envs.agents``) and by robots
loaded from an MJCF file (``hdt.envs.robot``).

LL budgets (env steps) are the paper's Appendix D: point mass 200k, legged 2.5M, manipulation 1.2M.
Numbers from the authors' bot_transfer/envs (SPEC.md cites each): nav epsilon_low 0.27, manip 0.01,
start noise per episode (maze.py PointMaze/AntMaze.reset_func, reacher.py Reacher.reset_func; in the
open arena point_mass.py PointMassLargeMJ: qpos +-0.05 * arena_width 8, qvel +-velocity_bound 0.1,
ant.py Ant.reset_func: qpos +-0.13, qvel 0.13 N(0, 1)).
Each entry is complete: every AgentSpec field without a class default has a value (the point mass's
for "nav", the ant's for "legged", the arms' for "manip").
"""

import numpy as np

NAV = dict(family="nav", frame_skip=3, k=32, ll_horizon=100, qpos_skip=2, delta_max=4.0,
           reset_prob=0.1, ctrl_cost=0.5, reach_eps=0.27, ll_budget=200_000, open_noise=(0.4, 0.1))
LEGGED = dict(NAV, frame_skip=5, fall_z=(0.2, 1.0), survive_bonus=0.7, ll_budget=2_500_000,
              open_noise=(0.13, 0.13))
MANIP = dict(family="manip", frame_skip=3, k=35, delta_max=0.07, ll_horizon=45, reset_prob=0.25,
             ctrl_cost=0.05, reach_eps=0.01, success_bonus=4.0, init_noise=0.1, init_vel_noise=0.005,
             ll_budget=1_200_000)

# "legged" is a navigation robot (goal space: torso xy) that can fall.
FAMILIES: dict[str, dict] = {"nav": NAV, "legged": LEGGED, "manip": MANIP}


def arm_start_noise(joint_limits) -> tuple[float, ...]:
  """Reacher.reset_func(low=True): an arm starts its LL episodes at uniform joint angles, within
  +-pi on an unlimited joint and +-limit on a limited one (``None`` = unlimited)."""
  return tuple(float(np.pi) if lim is None else float(lim) for lim in joint_limits)


def arm(joint_limits) -> dict:
  """Defaults of a planar arm (hinges only): the manip family, angles observed as (cos, sin)."""
  return dict(MANIP, trig_angles=True, ll_qpos_noise=arm_start_noise(joint_limits))
