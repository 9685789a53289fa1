"""The LL reach task of hdt as a plain gymnasium env (one env, native ``mujoco.MjData`` in numpy).

This is what a reference user of stable-baselines / SBX would write: one ``MjData``, ``mj_step``
``frame_skip`` times per env step, observations and rewards in numpy. It reproduces hdt's
``make(agent, "reach")`` (hdt/envs/env.py + tasks.Reach) rule for rule, on the very ``MjModel`` hdt
compiled (taken from the hdt env object):

* obs = [obs_lo, goal - point], obs_lo = agent joint positions (cos/sin for the arms, without the
  global x, y for the point mass and the legged robots), joint velocities, for the legged robots the
  clipped ``cfrc_ext`` rows in the authors' layout (+ clipped touch sensors, rangefinders if any); read
  after the step, as hdt (``mj_forward``, and ``mj_rnePostConstraint`` for the contact forces);
* physics reset (hdt's ``AgentTaskEnv.initial_physics``, redrawn at every physics reset): qpos0 + the LL
  offset + half-widths x U(-1, 1) (hdt's ``_start_half``, ``_start_offset``), clipped to the joint limits,
  free-joint quaternions normalised; qvel = noise x N(0, 1) for legged agents, x U(-1, 1) otherwise;
  goal = point + U(-delta_max, delta_max)^2;
* reward: nav ``progress / dt - ctrl_cost |u|^2 (+ survive bonus)``; manip
  ``-|g - tip| - ctrl_cost |u|^2 + c 1{|g - tip| < eps}``, u the raw control (the action scaled to the
  actuators' control range);
* an episode lasts ``ll_horizon`` steps (gymnasium ``truncated``; SB3 bootstraps through it, as hdt's
  discount 1 does); a fall is ``terminated``. At the next ``reset()`` the robot goes back to its
  initial physics only after a fall or with probability ``reset_prob``, otherwise it keeps its
  state and gets a new goal (hdt's auto-reset).

Run ``python benchmarks/time_to_quality.py --check`` after any change of hdt's env: it steps both from
the same state and prints the largest observation and reward differences.

Differences from hdt that remain: hdt stores the physics state in float32 between env steps (this
env keeps MuJoCo's float64), and the random streams differ (numpy vs jax keys).
"""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np


class ReachGymEnv(gym.Env):
  metadata = {"render_modes": []}

  def __init__(self, hdt_env, seed: int | None = None):
    e = hdt_env
    self.hdt_env = e
    self.spec_ = a = e.agent
    self.model = e.mj_model
    self.data = mujoco.MjData(self.model)
    self.frame_skip = a.frame_skip
    self.dt = float(self.model.opt.timestep * a.frame_skip)
    self.horizon = a.ll_horizon
    self._qpos_idx, self._qvel_idx = e._qpos_idx, e._qvel_idx
    self._start_half = np.asarray(e._start_half, np.float64)
    self._start_offset = np.asarray(e._start_offset, np.float64)
    self._quats = [int(i) for i in e._quats]
    self._qvel_noise = np.asarray(e._qvel_noise, np.float64)
    self._qpos_lo, self._qpos_hi = np.asarray(e._qpos_lo, np.float64), np.asarray(e._qpos_hi, np.float64)
    self._qpos0 = np.asarray(e._qpos0, np.float64)
    self._point = e._sensor["point"][:2]
    self._tip_z = e._sensor["tip"][2]
    self._touch, self._rays, self._bodies = e._touch, e._rays, e._bodies
    self._ctrl_lo, self._ctrl_hi = np.float64(e._ctrl_lo), np.float64(e._ctrl_hi)
    n_obs = int(e.observation_size)
    self.observation_space = gym.spaces.Box(-np.inf, np.inf, (n_obs,), np.float32)
    self.action_space = gym.spaces.Box(-1.0, 1.0, (int(e.action_size),), np.float32)
    self._need_physics_reset = True
    self._steps = 0
    self.goal = np.zeros(2)
    if seed is not None:
      self.reset(seed=seed)

  # -- helpers -------------------------------------------------------------------------------------
  def point(self):
    return self.data.sensordata[self._point].copy()

  def _obs(self):
    d, a = self.data, self.spec_
    qp, qv = d.qpos[self._qpos_idx], d.qvel[self._qvel_idx]
    qp = np.concatenate([np.cos(qp), np.sin(qp)]) if a.trig_angles else qp[a.qpos_skip:]
    touch = np.clip(d.sensordata[self._touch] / a.contact_clip, 0.0, 1.0)
    contacts = np.zeros(0)
    if a.contact_forces:
      before, after = a.contact_rows
      rows = np.clip(d.cfrc_ext[self._bodies], -1.0, 1.0).reshape(-1)
      contacts = np.concatenate([np.zeros(6 * before), rows, np.zeros(6 * after)])
    lo = np.concatenate([qp, qv, contacts, touch, d.sensordata[self._rays]])
    return np.concatenate([lo, self.goal - self.point()]).astype(np.float32)

  def _sample_goal(self):
    dm = self.spec_.delta_max
    self.goal = self.point() + self.np_random.uniform(-dm, dm, size=2)

  def _forward(self):
    """Positions, sensors (and contact forces) of the current state, as hdt reads them after a step."""
    mujoco.mj_forward(self.model, self.data)
    if self.spec_.contact_forces:
      mujoco.mj_rnePostConstraint(self.model, self.data)

  def set_state(self, qpos, qvel, goal, act=None):
    """For the equivalence check against hdt: put the robot (and its actuators' activations) and the
    goal somewhere."""
    self.data.qpos[:], self.data.qvel[:] = qpos, qvel
    if act is not None and self.model.na:
      self.data.act[:] = act
    self.data.time = 0.0
    self._forward()
    self.goal = np.asarray(goal, np.float64)
    self._steps = 0
    self._need_physics_reset = False
    return self._obs()

  def _fell(self):
    if self.spec_.fall_z is None:
      return False
    lo, hi = self.spec_.fall_z
    z = self.data.sensordata[self._tip_z]
    return bool(z < lo or z > hi)

  # -- gymnasium API -------------------------------------------------------------------------------
  def reset(self, *, seed=None, options=None):
    super().reset(seed=seed)
    a, d = self.spec_, self.data
    if self._need_physics_reset:
      qpos = self._qpos0 + self._start_offset + self._start_half * self.np_random.uniform(-1, 1, self._qpos0.shape)
      qpos = np.clip(qpos, self._qpos_lo, self._qpos_hi)
      for i in self._quats:
        qpos[i:i + 4] /= np.linalg.norm(qpos[i:i + 4])
      draw = self.np_random.standard_normal if a.legged else (lambda n: self.np_random.uniform(-1, 1, n))
      d.qpos[:], d.qvel[:] = qpos, self._qvel_noise * draw(self._qvel_noise.shape)
      if m_na := self.model.na:
        d.act[:] = np.zeros(m_na)
      d.time = 0.0
      self._forward()
    self._sample_goal()
    self._steps = 0
    return self._obs(), {}

  def step(self, action):
    a, d, m = self.spec_, self.data, self.model
    action = np.clip(np.asarray(action, np.float64), -1.0, 1.0)
    prev = self.point()
    d.ctrl[:] = self._ctrl_lo + (action + 1.0) * 0.5 * (self._ctrl_hi - self._ctrl_lo)
    for _ in range(self.frame_skip):
      mujoco.mj_step(m, d)
    self._forward()
    p = self.point()
    ctrl_cost = a.ctrl_cost * float(np.sum(np.square(d.ctrl)))  # of the raw control, as hdt's Reach.reward
    dist = float(np.linalg.norm(self.goal - p))
    if a.family == "nav":
      to_goal = self.goal - prev
      progress = float(np.dot(p - prev, to_goal) / (np.linalg.norm(to_goal) + 1e-8))
      reward = progress / self.dt - ctrl_cost + a.survive_bonus
    else:
      reward = -dist - ctrl_cost + a.success_bonus * float(dist < a.reach_eps)
    self._steps += 1
    fell = self._fell()
    truncated = self._steps >= self.horizon
    if fell or truncated:
      self._need_physics_reset = fell or bool(self.np_random.uniform() < a.reset_prob)
    return self._obs(), reward, fell, truncated and not fell, {"goal_dist": dist}
