"""The LL reach task of hdt as a plain gymnasium env (one env, native ``mujoco.MjData`` in numpy).

This is what a reference user of stable-baselines / SBX would write: one ``MjData``, ``mj_step``
``frame_skip`` times per env step, observations and rewards in numpy. It reproduces hdt's
``make(agent, "reach")`` (hdt/envs/env.py + tasks.Reach) rule for rule, on the very ``MjModel`` hdt
compiled (taken from the hdt env object):

* obs = [obs_lo, goal - point], obs_lo = agent joint positions (cos/sin for the arms, without the
  global x, y for the point mass), joint velocities (+ clipped touch sensors, rangefinders if any);
* reset: qpos0 (clipped to the joint limits) + U(-n, n) on hinge/slide joints, qvel ~ n N(0, 1);
  goal = point + U(-delta_max, delta_max)^2;
* reward: nav ``progress / dt - ctrl_cost |a|^2 (+ survive bonus)``; manip
  ``-|g - tip| - ctrl_cost |a|^2 + c 1{|g - tip| < eps}``;
* an episode lasts ``ll_horizon`` steps (gymnasium ``truncated``; SB3 bootstraps through it, as hdt's
  discount 1 does); a fall is ``terminated``. At the next ``reset()`` the robot goes back to its
  initial physics only after a fall or with probability ``reset_prob``, otherwise it keeps its
  state and gets a new goal (hdt's auto-reset).

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
    self._qpos_noise = np.asarray(e._qpos_noise, np.float64)
    self._qvel_noise = np.asarray(e._qvel_noise, np.float64)
    self._qpos_lo, self._qpos_hi = np.asarray(e._qpos_lo, np.float64), np.asarray(e._qpos_hi, np.float64)
    self._qpos0 = np.asarray(e._qpos0, np.float64)
    self._point = e._sensor["point"][:2]
    self._tip_z = e._sensor["tip"][2]
    self._touch, self._rays = e._touch, e._rays
    self._ctrl_lo, self._ctrl_hi = np.float64(e._ctrl_lo), np.float64(e._ctrl_hi)
    n_obs = int(e.observation_size)
    self.observation_space = gym.spaces.Box(-np.inf, np.inf, (n_obs,), np.float32)
    self.action_space = gym.spaces.Box(-1.0, 1.0, (int(e.action_size),), np.float32)
    self._init_state = None  # (qpos, qvel) of the first reset: hdt's cached initial physics
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
    lo = np.concatenate([qp, qv, touch, d.sensordata[self._rays]])
    return np.concatenate([lo, self.goal - self.point()]).astype(np.float32)

  def _sample_goal(self):
    dm = self.spec_.delta_max
    self.goal = self.point() + self.np_random.uniform(-dm, dm, size=2)

  def set_state(self, qpos, qvel, goal):
    """For the equivalence check against hdt: put the robot and the goal somewhere."""
    self.data.qpos[:], self.data.qvel[:] = qpos, qvel
    self.data.time = 0.0
    mujoco.mj_forward(self.model, self.data)
    self._init_state = (np.array(qpos, np.float64), np.array(qvel, np.float64))
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
    if self._init_state is None:
      n = a.init_noise
      qpos = self._qpos0 + self._qpos_noise * self.np_random.uniform(-n, n, size=self._qpos0.shape)
      qpos = np.clip(qpos, self._qpos_lo, self._qpos_hi)
      qvel = self._qvel_noise * n * self.np_random.standard_normal(self._qvel_noise.shape)
      self._init_state = (qpos, qvel)
      self._need_physics_reset = True
    if self._need_physics_reset:
      d.qpos[:], d.qvel[:] = self._init_state
      d.time = 0.0
      mujoco.mj_forward(self.model, d)
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
    p = self.point()
    ctrl_cost = a.ctrl_cost * float(np.sum(np.square(action)))
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
