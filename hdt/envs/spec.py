"""AgentSpec: what distinguishes one morphology from another (besides its MJCF file)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

XML_DIR = Path(__file__).resolve().parents[2] / "xml"


@dataclasses.dataclass(frozen=True)
class AgentSpec:
  name: str
  family: str  # "nav" (goal space = torso xy) or "manip" (goal space = end-effector xy)
  xml: str  # file name in xml/agents/
  frame_skip: int
  k: int  # LL steps per HL action
  delta_max: float  # goal box half-width per axis (m)
  ll_horizon: int  # LL training episode length
  reset_prob: float  # chance of a physics reset at the end of an LL episode
  ll_budget: int  # the paper's LL training budget in env steps (hdt.transfer.configs reads it)
  qpos_skip: int = 0  # leading agent qpos entries left out of obs_lo (global x, y)
  trig_angles: bool = False  # observe hinge angles as (cos, sin)
  fall_z: tuple[float, float] | None = None  # torso height bounds; outside them the agent has fallen
  contact_clip: float = 10.0  # touch readings (N) are scaled by 1/contact_clip and clipped to [0, 1]
  # The authors' legged observation: cfrc_ext of every body clipped to [-1, 1] (ant.py Ant.state,
  # quadruped.py Quadruped.state). Their models hold the world body before the robot's bodies and
  # two marker bodies (target, highlevel) after them, whose rows are always zero: contact_rows gives
  # those (before, after) counts, so the layout is theirs and a policy runs unchanged in their env.
  contact_forces: bool = False
  contact_rows: tuple[int, int] = (1, 2)
  ctrl_cost: float = 0.5  # lambda of the LL action penalty
  survive_bonus: float = 0.0  # legged LL reward per step while not fallen
  reach_eps: float = 0.27  # epsilon_low: LL goal reached within this distance (m); ends an HL step early
  init_noise: float = 0.1  # uniform qpos noise of an episode start, redrawn every episode
  init_vel_noise: float = 0.1  # qvel noise of an episode start (normal for legged agents, else uniform)
  # (qpos half-width, qvel scale) of starts in the open arena (Waypoint, and the nav LL, which the
  # authors train on the Waypoint class: PointMassLargeMJ / Ant.reset_func); empty: the two above.
  open_noise: tuple[float, ...] = ()
  # The start's qpos noise also on free joints (x, y, z and the quaternion, renormalised), as the
  # authors' reset_funcs add it to every qpos entry (ant.py Ant.reset_func, maze.py AntMaze.reset_func).
  free_joint_noise: bool = True
  # LL (reach) starts: per agent-qpos uniform half-widths (empty: the task's start_noise) around qpos0 + offset.
  # The authors' arms start their LL episodes at random joint angles, their point mass at (0, 0).
  ll_qpos_noise: tuple[float, ...] = ()
  ll_qpos_offset: tuple[float, ...] = ()
  max_ll_episodes: int = 10  # an LL episode resets the physics after this many that did not
  success_bonus: float = 0.0  # manip LL: c in c * 1{|g - tip| < eps}
  gear_scale: float = 1.0  # multiplies every actuator gear: a variant of a morphology (alignment tests)

  @property
  def xml_path(self) -> Path:
    return XML_DIR / "agents" / self.xml

  @property
  def legged(self) -> bool:
    return self.fall_z is not None

  def replace(self, **changes) -> "AgentSpec":
    return dataclasses.replace(self, **changes)
