"""Tasks of SPEC 3: the LL goal-reaching task and the HL tasks, as data plus pure reward functions.

A task sees the physics only through a few named quantities ``q`` (goal-space point, torso height,
end effector, block), so one task serves every agent of its family.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from hdt.envs.spec import AgentSpec

Quantities = dict[str, jax.Array]


@dataclasses.dataclass(frozen=True)
class Task:
  name: str = ""
  family: str = ""  # "nav" or "manip"
  hl_horizon: int = 50  # HL steps per episode; LL steps = hl_horizon * k
  point_sensor: str = "agent/goal_point"  # sensor giving the goal-space point
  # What the HL policy observes (hdt.transfer.hierarchy): obs_hi with the goal-space (x, y) pairs
  # starting at the offsets ``hl_relative`` expressed relative to the goal-space point obs_hi[:2],
  # and that point itself kept (``hl_absolute``) or dropped. Both are goal-space quantities, so the
  # HL input stays morphology-independent. Defaults: obs_hi unchanged.
  hl_relative: tuple[int, ...] = ()
  hl_absolute: bool = True
  # One HL step (the authors' Hierarchical.high_level_step): the LL runs until the goal-space point is
  # within epsilon of the sub-goal (the agent's reach_eps unless ``hl_eps`` is set) or k steps went
  # by; the HL reward is the task reward at the end minus ``skill_penalty * |z|`` (z in metres).
  skill_penalty: float = 0.05
  hl_eps: float | None = None
  low_level: bool = False  # the LL reach task (its own episode starts, AgentSpec.ll_qpos_*)
  # The LL under (or of) this task observes g - p for the first ``ll_points`` goal-space points of
  # obs_hi (the insert LL: peg tip and end effector), the goal-space point's last (ll_observation).
  ll_points: ClassVar[int] = 1
  agent_variant: ClassVar[str] = ""  # the agents' scene variant (hdt.envs.agents.VARIANTS)
  ll_terrain: ClassVar[str] = ""  # the reach terrain an LL under this task must be trained on ("": any)
  # Quantities the task reads besides the goal-space point: name in ``q`` -> MJCF sensor of its scene.
  sensors: ClassVar[dict[str, str]] = {}

  # -- defaults read by training and reporting (class data, not env options) ----------------------
  # The paper's HL budget in HL decisions (its HL "Timesteps", Appendix D); also the Full baseline's
  # budget in LL env steps (paper table). 0: the task has no HL (reach).
  hl_budget: ClassVar[int] = 0
  # HL finetuning with a KL tie to A's HL (SPEC 4): initial KL weight (beta) and learning rate.
  finetune_kl_weight: ClassVar[float] = 1.0
  finetune_lr: ClassVar[float] = 1e-2
  # The metric a table reports: "success" (episode success rate) or "return".
  headline: ClassVar[str] = "return"
  # How one HL step reduces each per-LL-step metric ("mean" over the LL steps taken unless listed):
  # "last" = its value at the end of the step, "max", "sum". The env adds "fall" for every task.
  step_reduce: ClassVar[dict[str, str]] = {"fall": "max", "success": "last"}

  @property
  def headline_column(self) -> str:
    """The evaluation column of the headline metric in a run's history (metrics.csv)."""
    return "eval/success_max" if self.headline == "success" else "eval/return"

  def reduction(self, metric: str) -> str:
    return self.step_reduce.get(metric, "mean")

  # -- scene -------------------------------------------------------------------------------------
  def scene(self, agent: AgentSpec) -> str:
    return "plane.xml" if agent.family == "nav" else "arena.xml"

  objects: tuple[tuple[str, str], ...] = ()  # (xml file in xml/scenes, prefix) attached to the world
  tools: tuple[tuple[str, str], ...] = ()  # attached at the agent's goal_point site
  rangefinders: int = 0  # rays around a legged agent's torso (Steps)

  def customize(self, spec) -> None:
    """Edit the composed mujoco.MjSpec before compiling (e.g. move a marker)."""

  # -- episodes ----------------------------------------------------------------------------------
  def horizon(self, agent: AgentSpec) -> int:
    return self.hl_horizon * agent.k

  def sample(self, key: jax.Array, agent: AgentSpec, q: Quantities) -> dict[str, Any]:
    """Task randomness at the start of an episode."""
    return {}

  open_arena: ClassVar[bool] = False  # episodes start with the agent's open-arena noise

  def start_noise(self, agent: AgentSpec) -> tuple[float, float]:
    """(qpos half-width, qvel scale) of an episode start: the agent's open-arena noise on an
    ``open_arena`` task (when it has one), else its default."""
    if self.open_arena and agent.open_noise:
      return tuple(agent.open_noise)
    return agent.init_noise, agent.init_vel_noise

  def physics_reset(self, key, agent: AgentSpec, fell, timeout):
    """Whether an ended episode also resets the robot (HL tasks: always)."""
    return jnp.bool_(True)

  def obs_hi(self, q: Quantities, t: dict) -> jax.Array:
    raise NotImplementedError

  def hl_features(self, obs_hi: jax.Array) -> jax.Array:
    """The HL policy's observation of ``obs_hi`` (see ``hl_relative`` / ``hl_absolute``)."""
    if not self.hl_relative and self.hl_absolute:
      return obs_hi
    point = obs_hi[..., :2]
    rel = {i: obs_hi[..., i:i + 2] - point for i in self.hl_relative}
    parts, i = [point] if self.hl_absolute else [], 2
    while i < obs_hi.shape[-1]:
      parts.append(rel[i] if i in rel else obs_hi[..., i:i + 1])
      i += 2 if i in rel else 1
    return jnp.concatenate(parts, axis=-1)

  def ll_observation(self, obs_lo, obs_hi, goal) -> jax.Array:
    """What an LL observes when sent to ``goal``: obs_lo, then g - p for the other points, then g minus
    the goal-space point (insert.py Insert.agent_state_func: [..., g - fingertip, g - peg]; the
    discriminator reads the last two entries)."""
    rel = [goal - obs_hi[..., 2 * i:2 * i + 2] for i in range(1, self.ll_points)]
    return jnp.concatenate([obs_lo, *rel, goal - obs_hi[..., :2]], axis=-1)

  def policy_obs(self, obs_lo, obs_hi, t) -> jax.Array:
    """The flat observation SAC sees on this task (the Full baseline: both levels)."""
    return jnp.concatenate([obs_lo, obs_hi])

  def hl_reward(self, rewards: jax.Array, metrics: dict, last: jax.Array) -> jax.Array:
    """Task reward of an HL step from its per-LL-step rewards and metrics (``last`` indexes the
    last LL step taken): the reward at the end (high_level_reward called once, after the LL loop)."""
    return rewards[last]

  def reward(self, key, agent: AgentSpec, q_prev: Quantities, q: Quantities, action, t, dt):
    """Returns (reward, solved (terminal), task state, metrics)."""
    raise NotImplementedError


@dataclasses.dataclass(frozen=True)
class Reach(Task):
  """LL goal reaching: a relative goal z in the agent's goal box (SPEC 3)."""

  name: str = "reach"
  low_level: bool = True
  headline: ClassVar[str] = "success"
  # "steps": random low barriers and 16 rangefinders (the Steps LL); "insert": the PegInsert scene
  # without the slot wall, the peg tip the goal-space point (insert.py Insert*Low, InsertPMLow)
  terrain: str = "plane"

  def __post_init__(self):
    if self.terrain not in TERRAINS:
      raise ValueError(f"reach terrain must be one of {', '.join(TERRAINS)}, got {self.terrain!r}")
    if self.terrain == "steps":
      object.__setattr__(self, "rangefinders", Steps.rangefinders)
    if self.terrain == "insert":  # what the insert LL shares with the HL task above it
      for name in ("point_sensor", "tools", "hl_eps", "ll_points", "agent_variant"):
        object.__setattr__(self, name, getattr(Insert, name))

  def scene(self, agent):
    if self.terrain != "plane" and agent.family != TERRAINS[self.terrain]:
      raise ValueError(f"terrain={self.terrain!r} is for {TERRAINS[self.terrain]} agents")
    if self.terrain == "steps":
      return "random_steps.xml"
    return super().scene(agent)

  @property
  def open_arena(self):
    # The authors train nav LLs on the Waypoint class (Ant_Low, PointMassLargeMJ_Low).
    return self.terrain == "plane"

  def horizon(self, agent):
    return agent.ll_horizon

  def sample(self, key, agent, q):
    z = jax.random.uniform(key, (2,), minval=-agent.delta_max, maxval=agent.delta_max)
    return {"goal": q["point"] + z, "z": z}

  def physics_reset(self, key, agent, fell, timeout):
    return fell | (jax.random.uniform(key) < agent.reset_prob)

  def obs_hi(self, q, t):
    return q["point"] if self.ll_points == 1 else jnp.concatenate([q["point"], q["tip"]])

  def policy_obs(self, obs_lo, obs_hi, t):
    return self.ll_observation(obs_lo, obs_hi, t["goal"])

  def reward(self, key, agent, q_prev, q, action, t, dt):
    # ``action`` is the raw control (Hierarchical.low_level_step's action_penalty * sum(a^2)).
    ctrl_cost = agent.ctrl_cost * jnp.sum(jnp.square(action))
    dist = jnp.linalg.norm(t["goal"] - q["point"])
    eps = agent.reach_eps if self.hl_eps is None else self.hl_eps  # insert.py: epsilon_low 0.015
    if agent.family == "nav":
      to_goal = t["goal"] - q_prev["point"]
      progress = jnp.dot(q["point"] - q_prev["point"], to_goal) / (jnp.linalg.norm(to_goal) + 1e-8)
      r = progress / dt - ctrl_cost + agent.survive_bonus
    else:
      r = -dist - ctrl_cost + agent.success_bonus * (dist < eps)
    return r, jnp.bool_(False), t, {"goal_dist": dist, "success": (dist < eps).astype(jnp.float32)}


def _disc(key, radius):
  k1, k2 = jax.random.split(key)
  r = radius * jnp.sqrt(jax.random.uniform(k1))
  a = jax.random.uniform(k2, maxval=2 * jnp.pi)
  return jnp.stack([r * jnp.cos(a), r * jnp.sin(a)])


@dataclasses.dataclass(frozen=True)
class Waypoint(Task):
  """Reach waypoints drawn in a disc; a new one appears as soon as one is reached."""

  name: str = "waypoint"
  family: str = "nav"
  hl_horizon: int = 50
  radius: float = 8.0
  # point_mass.py / ant.py post_action: a waypoint is reached when the 3-D distance from the torso
  # origin to the target body (at z = 0.3) is below epsilon_high 0.5; -0.1 * that distance otherwise.
  reach_dist: float = 0.5
  target_z: float = 0.3
  bonus: float = 100.0
  # The HL sees the waypoint relative to the agent, not both absolute positions: measured at 6k HL
  # steps (2 seeds), absolute inputs -243 / 73, relative 1475 / 1551 (see hdt.transfer.hierarchy).
  hl_relative: tuple[int, ...] = (2,)
  hl_absolute: bool = False
  skill_penalty: float = 0.25  # point_mass.py PointMassLargeMJ, ant.py Ant
  open_arena: ClassVar[bool] = True  # PointMassLargeMJ / Ant.reset_func, not the maze classes'
  hl_budget: ClassVar[int] = 200_000
  step_reduce: ClassVar[dict[str, str]] = Task.step_reduce | {"waypoints": "sum"}  # any LL step may hit one

  def sample(self, key, agent, q):
    return {"waypoint": _disc(key, self.radius)}

  def hl_reward(self, rewards, metrics, last):
    # PointMassMJ.post_action flags a reached waypoint on any LL step; high_level_reward then pays
    # 100 once for the HL step, else -0.1 * the distance at its end.
    return jnp.where(jnp.any(metrics["waypoints"] > 0), self.bonus, rewards[last])

  def obs_hi(self, q, t):
    return jnp.concatenate([q["point"], t["waypoint"]])

  def reward(self, key, agent, q_prev, q, action, t, dt):
    dist = jnp.sqrt(jnp.sum(jnp.square(t["waypoint"] - q["point"])) + jnp.square(q["z"] - self.target_z))
    hit = dist < self.reach_dist
    t = {"waypoint": jnp.where(hit, _disc(key, self.radius), t["waypoint"])}
    return jnp.where(hit, self.bonus, -0.1 * dist), jnp.bool_(False), t, {"waypoints": hit.astype(jnp.float32), "dist": dist}


# U-maze path cells (row, col) from the start r to the end g of SPEC 3's layout.
_U_PATH = ((1, 1), (1, 2), (1, 3), (2, 3), (3, 3), (3, 2), (3, 1))


@dataclasses.dataclass(frozen=True)
class Maze(Task):
  """Sparse U-maze: +1000 on entering the goal cell, which ends the episode."""

  name: str = "maze"
  family: str = "nav"
  hl_horizon: int = 100
  cell: float = 8.0
  goal: str = "sample"  # "sample": any of the six cells past the start; "end": the end cell
  bonus: float = 1000.0
  scene_file: str = "maze.xml"
  skill_penalty: float = 0.005  # maze.py PointMaze / AntMaze
  hl_budget: ClassVar[int] = 400_000
  finetune_kl_weight: ClassVar[float] = 0.01
  finetune_lr: ClassVar[float] = 1e-3
  headline: ClassVar[str] = "success"
  agent_variant: ClassVar[str] = "maze"

  def __post_init__(self):
    if self.goal not in ("sample", "end"):
      raise ValueError(f"maze goal must be 'sample' or 'end', got {self.goal!r}")

  def scene(self, agent):
    return self.scene_file

  @property
  def cells(self) -> np.ndarray:
    """Centres (x, y) of the path cells after the start, the end cell last."""
    return np.array([[(c - 1) * self.cell, (r - 1) * self.cell] for r, c in _U_PATH[1:]], np.float32)

  def sample(self, key, agent, q):
    cells = jnp.asarray(self.cells)
    i = jax.random.randint(key, (), 0, len(cells)) if self.goal == "sample" else len(cells) - 1
    return {"goal": cells[i]}

  def obs_hi(self, q, t):
    return jnp.concatenate([q["point"], t["goal"]])

  def reward(self, key, agent, q_prev, q, action, t, dt):
    inside = jnp.all(jnp.abs(q["point"] - t["goal"]) < self.cell / 2)
    return self.bonus * inside, inside, t, {"success": inside.astype(jnp.float32),
                                            "dist": jnp.linalg.norm(q["point"] - t["goal"])}


@dataclasses.dataclass(frozen=True)
class Steps(Maze):
  """The half-size U-maze with low barriers; legged agents see 16 rangefinders."""

  name: str = "steps"
  cell: float = 4.0
  goal: str = "end"
  scene_file: str = "steps.xml"
  rangefinders: int = 16


@dataclasses.dataclass(frozen=True)
class Push(Task):
  """Push the block to its destination: -distance per step, +200 and done within 0.025 m."""

  name: str = "push1"
  family: str = "manip"
  hl_horizon: int = 60
  destination: tuple[float, float] = (-0.10, -0.08)
  tolerance: float = 0.025
  bonus: float = 200.0
  objects: tuple = (("block.xml", "block/"),)
  hl_budget: ClassVar[int] = 500_000
  headline: ClassVar[str] = "success"
  sensors: ClassVar[dict[str, str]] = {"block": "block/block_pos", "block_vel": "block/block_vel"}

  def customize(self, spec):
    spec.site("block/destination").pos = [*self.destination, 0.001]

  def obs_hi(self, q, t):
    return jnp.concatenate([q["point"], q["block"], q["block_vel"]])

  def reward(self, key, agent, q_prev, q, action, t, dt):
    dist = jnp.linalg.norm(q["block"] - jnp.asarray(self.destination))
    solved = dist < self.tolerance
    # reacher.py Reacher.high_level_reward: 200 within epsilon_high, else -distance.
    return jnp.where(solved, self.bonus, -dist), solved, t, {"success": solved.astype(jnp.float32), "dist": dist}


@dataclasses.dataclass(frozen=True)
class Insert(Task):
  """Insert the peg on the end effector through the slot in the wall at y = -0.18."""

  name: str = "insert"
  family: str = "manip"
  hl_horizon: int = 50
  point_sensor: str = "peg/peg_tip"
  objects: tuple = (("slot_wall.xml", "slot/"),)
  tools: tuple = (("peg.xml", "peg/"),)
  hl_eps: float | None = 0.015  # insert.py Insert: epsilon_low
  target: tuple[float, float] = (0.0, -0.19)
  # Its LL is trained on the insert scene (the authors' Insert*Low) and sees g - tip and g - peg.
  ll_points: ClassVar[int] = 2
  agent_variant: ClassVar[str] = "insert"
  ll_terrain: ClassVar[str] = "insert"
  hl_budget: ClassVar[int] = 500_000
  headline: ClassVar[str] = "success"

  def obs_hi(self, q, t):
    return jnp.concatenate([q["point"], q["tip"]])

  def reward(self, key, agent, q_prev, q, action, t, dt):
    peg = q["point"]
    solved = (jnp.abs(peg[0]) < 0.05) & (peg[1] < self.target[1])
    d2 = jnp.sum(jnp.square(peg - jnp.asarray(self.target)))
    return -20.0 * d2 + 50.0 * solved, solved, t, {"success": solved.astype(jnp.float32),
                                                   "dist": jnp.sqrt(d2)}


# Reach terrains and the family each is for ("plane": any).
TERRAINS = {"plane": "", "steps": "nav", "insert": "manip"}

TASKS = {
    "reach": Reach,
    "waypoint": Waypoint,
    "maze": Maze,
    "steps": Steps,
    "push1": Push,
    "push2": lambda **kw: Push(**{"name": "push2", "destination": (-0.12, -0.13), **kw}),
    "insert": Insert,
}


def get_task(name: str, **overrides) -> Task:
  """The task registered as ``name`` (unknown names are refused with the list of valid ones)."""
  if name not in TASKS:
    raise ValueError(f"unknown task {name!r}; choose one of {', '.join(TASKS)}")
  return TASKS[name](**overrides)
