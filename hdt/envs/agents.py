"""The nine morphologies of SPEC 2, as data."""

import numpy as np

from hdt.envs.spec import AgentSpec

# Numbers from the authors' bot_transfer/envs (SPEC.md cites each): nav epsilon_low 0.27, manip 0.01,
# start noise per episode (maze.py PointMaze/AntMaze.reset_func, reacher.py Reacher.reset_func).
_NAV = dict(family="nav", delta_max=4.0, reset_prob=0.1, ctrl_cost=0.5, reach_eps=0.27)
_LEGGED = dict(_NAV, qpos_skip=2, fall_z=(0.2, 1.0), survive_bonus=0.7, k=32, ll_horizon=100)
_MANIP = dict(family="manip", frame_skip=3, k=35, delta_max=0.07, ll_horizon=45, reset_prob=0.25,
              ctrl_cost=0.05, reach_eps=0.01, success_bonus=4.0, init_noise=0.1, init_vel_noise=0.005)


def _arm(joint_limit: float, n: int) -> dict:
  """Reacher.reset_func(low=True): joint0 uniform in +-pi, the others in +-RAND_LIMITS."""
  return dict(_MANIP, trig_angles=True, ll_qpos_noise=(float(np.pi),) + (joint_limit,) * (n - 1))

AGENTS: dict[str, AgentSpec] = {
    "point": AgentSpec("point", xml="point.xml", frame_skip=3, k=32, ll_horizon=100, qpos_skip=2,
                       **_NAV),
    "ant": AgentSpec("ant", xml="ant.xml", frame_skip=5, **_LEGGED),
    "ant3": AgentSpec("ant3", xml="ant3.xml", frame_skip=5, **_LEGGED),
    "ant2": AgentSpec("ant2", xml="ant2.xml", frame_skip=5, **_LEGGED),
    "quadruped": AgentSpec("quadruped", xml="quadruped.xml",
                           **dict(_LEGGED, frame_skip=3, k=64, ll_horizon=150, fall_z=(0.15, 0.9))),
    # ReacherPM.reset: every LL episode restarts at (0, 0) +- 0.05, every HL episode at (0.2, 0) +- 0.05.
    "arm_point": AgentSpec("arm_point", xml="arm_point.xml", qpos_skip=2,
                           **dict(_MANIP, init_noise=0.05, reset_prob=1.0, ll_qpos_offset=(-0.2, 0.0))),
    "arm2": AgentSpec("arm2", xml="arm2.xml", **_arm(3.0, 2)),
    "arm3": AgentSpec("arm3", xml="arm3.xml", **_arm(2.7, 3)),
    "arm4": AgentSpec("arm4", xml="arm4.xml", **_arm(2.0, 4)),
}
