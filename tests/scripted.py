"""Scripted controllers: a PD low level per morphology and sub-goal scripts per task. They show that a
scene is solvable through hdt's HL step (sub-goals in the goal box, the LL stopping at epsilon)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from hdt.transfer.hierarchy import HighLevelEnv


def point_ll(kp: float, kd: float):
  """PD on (g - xy) for slide-joint point masses: obs = qvel(2) ++ (g - xy)."""
  def policy(params, obs):
    return jnp.clip(kp * obs[-2:] - kd * obs[:2], -1.0, 1.0)
  return policy


def arm_ll(env, kp: float = 20.0, kd: float = 2.0, damping: float = 1e-3, tool: float = 0.0,
           tool_dir=None):
  """Damped least-squares PD for a planar chain: joint targets J^T (J J^T + damping)^-1 (g - p), p the
  point ``tool`` m beyond the fingertip along the last link (the peg tip: 0.05);
  obs = cos(n) ++ sin(n) ++ qvel(n) ++ ... ++ (g - p). With ``tool_dir`` (a unit xy vector) the
  fingertip is also driven to g - tool * tool_dir, so that the tool points along tool_dir (the insert
  LL's obs ends with g - fingertip, g - peg tip)."""
  m = env.mj_model
  n = env.action_size
  names = [m.body(i).name for i in range(m.nbody)]
  chain = [i for i, nm in enumerate(names) if nm.startswith("agent/") and nm != "agent/fingertip"]
  lengths = np.array([np.linalg.norm(m.body_pos[j]) for j in chain[1:]]
                     + [np.linalg.norm(m.body_pos[names.index("agent/fingertip")]) + tool], np.float32)

  def jacobian(lengths, phi):
    dx, dy = -lengths * jnp.sin(phi), lengths * jnp.cos(phi)
    return jnp.stack([jnp.cumsum(dx[::-1])[::-1], jnp.cumsum(dy[::-1])[::-1]])  # (2, n)

  def policy(params, obs):
    th = jnp.arctan2(obs[n:2 * n], obs[:n])
    phi = jnp.cumsum(th)
    jac, err = jacobian(lengths, phi), obs[-2:]
    if tool_dir is not None:  # and the fingertip to g - tool * tool_dir
      to_tip = lengths - np.eye(n, dtype=np.float32)[-1] * tool
      jac = jnp.concatenate([jac, jacobian(to_tip, phi)])
      err = jnp.concatenate([err, obs[-4:-2] - tool * jnp.asarray(tool_dir, jnp.float32)])
    dq = jac.T @ jnp.linalg.solve(jac @ jac.T + damping * jnp.eye(jac.shape[0]), err)
    tau = kp * dq - kd * obs[2 * n:3 * n]
    return jnp.clip(tau, -1.0, 1.0)
  return policy


def run_script(hl: HighLevelEnv, script, key=0, max_steps=None):
  """Runs ``script(obs_hi) -> sub-goal target (absolute, goal space)`` through the HL env until done.
  Returns (solved, number of HL steps, final state)."""
  reset, step = jax.jit(hl.reset), jax.jit(hl.step)
  s = reset(jax.random.PRNGKey(key))
  for i in range(max_steps or hl.horizon):
    hi = np.asarray(s.obs_hi)
    z = np.clip((np.asarray(script(hi)) - hi[:2]) / hl.delta_max, -1.0, 1.0)
    s = step(s, jnp.asarray(z, jnp.float32))
    if float(s.done):
      return bool(s.discount == 0.0 and s.metrics.get("fall", 0.0) == 0.0), i + 1, s
  return False, max_steps or hl.horizon, s


def path_script(points, tol):
  """Follow waypoints (absolute goal-space points); move on within ``tol`` of the current one."""
  state = {"i": 0}

  def script(hi):
    p = hi[:2]
    while state["i"] < len(points) - 1 and np.linalg.norm(np.asarray(points[state["i"]]) - p) < tol:
      state["i"] += 1
    return points[state["i"]]
  return script


def push_script(destination, stand_off=0.045):
  """Pushes the block along x to the destination's x, then along y (obs_hi = tip, block, block vel).
  Each phase first goes round to the block's far side, then drives through it."""
  dest = np.asarray(destination, np.float32)

  def script(hi):
    tip, block = hi[:2], hi[2:4]
    err = dest - block
    axis = 0 if abs(err[0]) > 0.012 else 1
    d = np.sign(err[axis]) if err[axis] != 0 else 1.0
    u = np.zeros(2, np.float32); u[axis] = d
    behind = block - stand_off * u
    side = tip - block
    along = side @ u  # < 0: the tip is on the pushing side
    if along < -0.03 and abs(side[1 - axis]) < 0.015:
      return block + 0.06 * u  # in line behind the block: push through it
    if along > -0.03:  # on the wrong side or level with the block: go round it
      lateral = np.zeros(2, np.float32); lateral[1 - axis] = 0.06 * (np.sign(side[1 - axis]) or 1.0)
      if abs(side[1 - axis]) < 0.04:
        return tip + lateral  # step sideways first
      return block + lateral - stand_off * u
    return behind
  return script
