"""AgentTaskEnv: one agent on one task, over either physics backend, with pure reset/step."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from hdt.envs.core import State
from hdt.envs.model import AGENT_PREFIX, build_model
from hdt.envs.physics import Backend, PhysicsState, make_physics
from hdt.envs.spec import AgentSpec
from hdt.envs.tasks import Task


def _where(c, a, b):
  return jax.tree.map(lambda x, y: jnp.where(c, x, y), a, b)


class AgentTaskEnv:
  """Pure, vmappable environment. Episodes end on a time limit or a solved task, and on the LL reach
  task also on a fall, and reset inside ``step`` (the LL reach task keeps the robot's state unless it
  fell or a ``reset_prob`` coin says otherwise, and draws a new goal)."""

  def __init__(self, agent: AgentSpec, task: Task, backend: Backend = "auto"):
    if task.family and task.family != agent.family:
      raise ValueError(f"task {task.name!r} is a {task.family} task but agent {agent.name!r} is a "
                       f"{agent.family} agent")
    self.agent, self.task = agent, task
    self.mj_model = m = build_model(agent, task)
    self.physics = make_physics(m, agent.frame_skip, backend, contact_forces=agent.contact_forces)
    self.backend = self.physics.name
    self.dt = float(m.opt.timestep * agent.frame_skip)
    self.horizon = task.horizon(agent)
    self.action_size = m.nu

    # Agent degrees of freedom and sensors, found by the prefix the composition gave them.
    joints = [j for j in range(m.njnt) if m.joint(j).name.startswith(AGENT_PREFIX)]
    qpos_idx, qvel_idx, movable, free = [], [], [], []
    for j in joints:
      nq = {0: 7, 1: 4, 2: 1, 3: 1}[int(m.jnt_type[j])]
      nv = {0: 6, 1: 3, 2: 1, 3: 1}[int(m.jnt_type[j])]
      qpos_idx += range(m.jnt_qposadr[j], m.jnt_qposadr[j] + nq)
      qvel_idx += range(m.jnt_dofadr[j], m.jnt_dofadr[j] + nv)
      movable += [m.jnt_qposadr[j]] if m.jnt_type[j] in (2, 3) else []
      free += [int(m.jnt_qposadr[j])] if m.jnt_type[j] == 0 else []
    self._qpos_idx, self._qvel_idx = np.array(qpos_idx), np.array(qvel_idx)
    # Start inside the joint limits (the Gym ant's ankles rest outside theirs at qpos0, which makes
    # the first landing violent and chaotic).
    self._qpos_lo = np.full(m.nq, -np.inf, np.float32)
    self._qpos_hi = np.full(m.nq, np.inf, np.float32)
    for j in joints:
      if m.jnt_limited[j] and m.jnt_type[j] in (2, 3):
        self._qpos_lo[m.jnt_qposadr[j]], self._qpos_hi[m.jnt_qposadr[j]] = m.jnt_range[j]
    self._qpos0 = np.clip(np.array(m.qpos0, np.float32), self._qpos_lo, self._qpos_hi)
    # Episode starts (redrawn every episode): uniform qpos noise on the agent's hinge/slide joints and
    # qvel noise on its dofs; the LL reach task has its own distribution (AgentSpec.ll_qpos_*).
    low = task.low_level
    qpos_noise, qvel_noise = task.start_noise(agent)
    self._start_half = np.zeros(m.nq, np.float32)
    self._start_half[movable] = qpos_noise
    self._quats = np.array([a + 3 for a in free], np.int32)  # each free joint's quaternion (w, x, y, z)
    if agent.free_joint_noise:
      for a in free:
        self._start_half[a:a + 7] = qpos_noise
    self._start_offset = np.zeros(m.nq, np.float32)
    self._hl_start = (self._start_half.copy(), self._start_offset.copy())  # without the LL's own start
    if low and agent.ll_qpos_noise:
      if len(agent.ll_qpos_noise) != len(movable):
        raise ValueError(f"{agent.name}: ll_qpos_noise has {len(agent.ll_qpos_noise)} entries for "
                         f"{len(movable)} hinge/slide joints")
      self._start_half[movable] = agent.ll_qpos_noise
    if low and agent.ll_qpos_offset:
      self._start_offset[np.array(qpos_idx)[:len(agent.ll_qpos_offset)]] = agent.ll_qpos_offset
    self._qvel_noise = np.zeros(m.nv, np.float32)
    self._qvel_noise[self._qvel_idx] = qvel_noise

    def sensor(name):
      i = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, name)
      return None if i < 0 else np.arange(m.sensor_adr[i], m.sensor_adr[i] + m.sensor_dim[i])
    found = {name: sensor(s) for name, s in [
        ("point", task.point_sensor), ("tip", AGENT_PREFIX + "goal_point"), *task.sensors.items()]}
    missing = [s for name, s in task.sensors.items() if found[name] is None]
    if missing:
      raise ValueError(f"task {task.name!r} reads sensors {missing} that its scene does not define; add them "
                       f"to the task's scene XML")
    self._sensor = {name: idx for name, idx in found.items() if idx is not None}
    names = [m.sensor(i).name for i in range(m.nsensor)]
    self._touch = np.concatenate([sensor(n) for n in names if n.startswith(AGENT_PREFIX + "touch")]
                                 or [np.zeros(0, int)])
    self._rays = np.concatenate([sensor(n) for n in names if n.startswith(AGENT_PREFIX + "ray")]
                                or [np.zeros(0, int)])
    root = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, AGENT_PREFIX + "root")
    self._bodies = np.flatnonzero(m.body_rootid == root)  # the robot's bodies, in tree order
    lo, hi = m.actuator_ctrlrange.T
    self._ctrl_lo, self._ctrl_hi = np.float32(lo), np.float32(hi)

    s = jax.eval_shape(self.reset, jax.random.PRNGKey(0))
    self.observation_size = s.obs.shape[-1]
    self.obs_lo_size, self.obs_hi_size = s.obs_lo.shape[-1], s.obs_hi.shape[-1]

  # -- observations ------------------------------------------------------------------------------
  def quantities(self, ps: PhysicsState) -> dict[str, jax.Array]:
    q = {k: ps.sensordata[idx] for k, idx in self._sensor.items()}
    q["z"] = q["tip"][2]
    q = {k: (v[:2] if k != "z" else v) for k, v in q.items()}
    return q

  def obs_lo(self, ps: PhysicsState) -> jax.Array:
    qp, qv = ps.qpos[self._qpos_idx], ps.qvel[self._qvel_idx]
    qp = jnp.concatenate([jnp.cos(qp), jnp.sin(qp)]) if self.agent.trig_angles else qp[self.agent.qpos_skip:]
    touch = jnp.clip(ps.sensordata[self._touch] / self.agent.contact_clip, 0.0, 1.0)
    return jnp.concatenate([qp, qv, self.contact_obs(ps), touch, ps.sensordata[self._rays]])

  def contact_obs(self, ps: PhysicsState) -> jax.Array:
    """The robot's clipped cfrc_ext rows between the authors' zero rows (AgentSpec.contact_rows)."""
    if not self.agent.contact_forces:
      return jnp.zeros((0,), jnp.float32)
    before, after = self.agent.contact_rows
    rows = jnp.clip(ps.cfrc_ext.reshape(-1, 6)[self._bodies], -1.0, 1.0).reshape(-1)
    return jnp.concatenate([jnp.zeros(6 * before), rows, jnp.zeros(6 * after)])

  def observe(self, ps, q, t):
    """(obs_lo, obs_hi, policy obs) of physics state ``ps`` with quantities ``q`` and task state ``t``."""
    lo, hi = self.obs_lo(ps), self.task.obs_hi(q, t)
    return lo, hi, self.task.policy_obs(lo, hi, t)

  def fell(self, q) -> jax.Array:
    if self.agent.fall_z is None:
      return jnp.bool_(False)
    lo, hi = self.agent.fall_z
    return (q["z"] < lo) | (q["z"] > hi)

  # -- reset / step ------------------------------------------------------------------------------
  def initial_physics(self, key: jax.Array, hl_start: bool = False) -> PhysicsState:
    """A fresh episode start: qpos0 (+ the LL offset) with uniform noise, clipped to the joint limits.
    ``hl_start``: in a reach env, the start of the agent's HL episodes instead (no LL offset or joint
    draw; the authors' ``reset(low=False)``)."""
    k_pos, k_vel = jax.random.split(key)
    half, offset = self._hl_start if hl_start else (self._start_half, self._start_offset)
    qpos = self._qpos0 + offset + half * jax.random.uniform(k_pos, half.shape, minval=-1.0, maxval=1.0)
    qpos = jnp.clip(qpos, self._qpos_lo, self._qpos_hi)
    for a in self._quats:
      qpos = qpos.at[a:a + 4].set(qpos[a:a + 4] / jnp.linalg.norm(qpos[a:a + 4]))
    if self.agent.legged:
      qvel = self._qvel_noise * jax.random.normal(k_vel, self._qvel_noise.shape)
    else:
      qvel = self._qvel_noise * jax.random.uniform(k_vel, self._qvel_noise.shape, minval=-1.0, maxval=1.0)
    return self.physics.forward(jnp.float32(0.0), qpos, qvel)

  def reset(self, key: jax.Array) -> State:
    key, k_phys, k_task = jax.random.split(key, 3)
    ps = self.initial_physics(k_phys)
    q = self.quantities(ps)
    t = self.task.sample(k_task, self.agent, q)
    lo, hi, obs = self.observe(ps, q, t)
    zero = jnp.float32(0.0)
    _, _, _, metrics = self.task.reward(k_task, self.agent, q, q, jnp.zeros(self.action_size), t, self.dt)
    metrics = {k: jnp.zeros_like(v, jnp.float32) for k, v in metrics.items()} | {"fall": zero}
    return State(physics=ps, obs=obs, obs_hi=hi, obs_lo=lo, next_obs=obs, next_obs_hi=hi,
                 reward=zero, done=zero,
                 discount=jnp.float32(1.0), task={"t": t, "steps": jnp.int32(0), "kept": jnp.int32(0),
                       "solved": jnp.bool_(False)},
                 metrics=metrics, key=key)

  def ctrl(self, action: jax.Array) -> jax.Array:
    """Actuator controls of a policy action in [-1, 1] (SB2's SAC rescales to the ctrl range too)."""
    action = jnp.clip(action, -1.0, 1.0)
    return self._ctrl_lo + (action + 1.0) * 0.5 * (self._ctrl_hi - self._ctrl_lo)

  def step(self, state: State, action: jax.Array, auto_reset: bool = True,
           active: jax.Array | None = None) -> State:
    """One step. ``auto_reset=False`` (the HL env, which owns episodes) never ends an episode on the
    task or the time limit and never resets; ``done`` then only flags a fall. ``active`` (optional,
    a bool per env) lets the physics skip envs whose result the caller discards."""
    key, k_task, k_reset, k_new, k_phys = jax.random.split(state.key, 5)
    ctrl = self.ctrl(action)
    ps = self.physics.step(state.physics, ctrl, active)
    q_prev, q = self.quantities(state.physics), self.quantities(ps)
    # The control cost is on the raw controls, as the authors' low_level_step.
    reward, solved, t, metrics = self.task.reward(k_task, self.agent, q_prev, q, ctrl,
                                                  state.task["t"], self.dt)
    fell = self.fell(q)
    metrics = {k: jnp.asarray(v, jnp.float32) for k, v in metrics.items()} | {"fall": fell.astype(jnp.float32)}
    steps = state.task["steps"] + 1
    next_lo, next_hi, next_obs = self.observe(ps, q, t)
    if not auto_reset:
      return State(physics=ps, obs=next_obs, obs_hi=next_hi, obs_lo=next_lo, next_obs=next_obs, next_obs_hi=next_hi,
                   reward=jnp.asarray(reward, jnp.float32), done=fell.astype(jnp.float32),
                   discount=1.0 - fell.astype(jnp.float32),
                   task=dict(state.task, t=t, steps=steps, solved=solved), metrics=metrics, key=key)
    # The LL task ends on a fall (the authors' low_level_is_done); a task's flat episode (the Full
    # baseline, FullEnv) ends as their high_level_is_done: on solving it, never on a fall.
    terminal = (fell & self.task.low_level) | solved
    timeout = steps >= self.horizon
    done = terminal | timeout

    # Auto-reset: a new episode starts from a fresh draw or, for the LL reach task, from where the
    # robot is unless it fell, a reset_prob coin says so or max_ll_episodes went by without a reset
    # (the authors' Hierarchical.reset).
    forced = state.task["kept"] >= self.agent.max_ll_episodes
    reset_physics = done & (self.task.physics_reset(k_reset, self.agent, fell, timeout) | forced)
    kept = jnp.where(done, jnp.where(reset_physics, 0, state.task["kept"] + 1), state.task["kept"])
    ps = _where(reset_physics, self.initial_physics(k_phys), ps)
    q = self.quantities(ps)
    t = _where(done, self.task.sample(k_new, self.agent, q), t)
    lo, hi, obs = self.observe(ps, q, t)
    return State(physics=ps, obs=obs, obs_hi=hi, obs_lo=lo, next_obs=next_obs, next_obs_hi=next_hi,
                 reward=jnp.asarray(reward, jnp.float32), done=done.astype(jnp.float32),
                 discount=1.0 - terminal.astype(jnp.float32),
                 task={"t": t, "steps": jnp.where(done, 0, steps), "kept": kept, "solved": solved},
                 metrics=metrics, key=key)
