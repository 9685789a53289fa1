"""MJX and native MuJoCo agree on every agent's scene and both run under vmap inside jit(scan),
the robots brought as one MJCF file (examples/robots, ROBOTS.md) included."""

from pathlib import Path

import jax
import mujoco
import jax.numpy as jnp
import numpy as np
import pytest

import hdt.envs as E

# Tolerances on qpos (m or rad). MJX runs in float32 and native MuJoCo in float64: on smooth scenes
# the two agree to float32 precision; legged robots in contact are chaotic, so after the first
# landing differences grow (measured: ants 1e-2 at step 5 and up to 0.8 by step 100; quadruped 3e-2).
# There we hold the first steps tight and the torso within a bound at step 100.
SMOOTH = 1e-4
ROBOTS = Path(__file__).resolve().parents[1] / "examples" / "robots"
HEXAPOD, ARM5 = str(ROBOTS / "hexapod.xml"), str(ROBOTS / "arm5.xml")
SCENES = [("point", "maze"), ("arm_point", "push1"), ("arm2", "push1"), ("arm3", "insert"),
          ("arm4", "push1"), ("quadruped", "reach"), ("ant", "reach"), ("ant3", "reach"),
          ("ant2", "reach"), (HEXAPOD, "reach"), (ARM5, "push1")]
# Tracing MJX under vmap is most of each case's 20-40 s; the variants of an agent family already
# covered here (arm2 and arm4 beside arm3 and arm5, their block scene beside arm_point's and arm5's;
# ant3 and ant2 beside ant) run with `-m slow` only.
VARIANTS = {"arm2", "arm4", "ant3", "ant2"}
LEGGED = {"ant": (0.05, 1.5), "ant3": (0.05, 1.5), "ant2": (0.05, 1.5), "quadruped": (0.01, 0.1),
          HEXAPOD: (0.05, 1.5)}


def _rollouts(agent, task, backend, nenv=2, nstep=100, perturb=0.0):
  return _rollouts_with_obs(agent, task, backend, nenv, nstep, perturb)[0]


def _rollouts_with_obs(agent, task, backend, nenv=2, nstep=100, perturb=0.0):
  """(qpos, sensordata) per step, env and state; and the env."""
  env = E.make(agent, task, backend=backend)
  acts = 0.5 * jax.random.uniform(jax.random.PRNGKey(1), (nstep, nenv, env.action_size), minval=-1, maxval=1)
  acts = acts + perturb * jax.random.normal(jax.random.PRNGKey(2), acts.shape)

  def run(keys):
    s = jax.vmap(env.reset)(keys)

    def f(s, a):
      s = jax.vmap(env.step)(s, a)
      return s, (s.physics.qpos, s.physics.sensordata)
    return jax.lax.scan(f, s, acts)[1]
  qpos, sens = jax.jit(run)(jax.random.split(jax.random.PRNGKey(0), nenv))
  return np.asarray(qpos), np.asarray(sens), env


def _assert_positions_are_of_the_final_qpos(env, qpos, sens, atol=1e-6):
  """Every position sensor (the goal-space point, a block, a peg tip) is forward kinematics of the
  qpos the step returned, not of the state one substep before (mj_step computes sensors before it
  integrates)."""
  m = env.mj_model
  d = mujoco.MjData(m)
  idx = np.concatenate([np.arange(m.sensor_adr[i], m.sensor_adr[i] + 3) for i in range(m.nsensor)
                        if m.sensor_type[i] == mujoco.mjtSensor.mjSENS_FRAMEPOS])
  worst = 0.0
  for q, sd in zip(qpos.reshape(-1, m.nq)[::7], sens.reshape(-1, m.nsensordata)[::7]):
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    mujoco.mj_sensorPos(m, d)
    worst = max(worst, float(np.abs(d.sensordata[idx] - sd[idx]).max()))
  assert worst < atol, worst


@pytest.mark.parametrize("agent,task", [
    pytest.param(a, t, id=f"{Path(a).stem}-{t}", marks=pytest.mark.slow if a in VARIANTS else ()) for a, t in SCENES])
def test_backends_agree(agent, task):
  nat, nat_sens, nat_env = _rollouts_with_obs(agent, task, "native")
  mjx, mjx_sens, mjx_env = _rollouts_with_obs(agent, task, "mjx")
  _assert_positions_are_of_the_final_qpos(nat_env, nat, nat_sens)
  _assert_positions_are_of_the_final_qpos(mjx_env, mjx, mjx_sens)
  assert np.isfinite(mjx).all() and np.isfinite(nat).all()
  d = np.abs(nat - mjx)
  if agent in LEGGED:
    early, late = LEGGED[agent]
    assert d[:5].max() < early, d[:5].max()
    # Legged contacts are chaotic: over 100 steps a 1e-5 change of the actions moved the native ant's torso
    # 1.53 m away from its own rollout, as far as MJX's (1.51 m, past the fixed 1.5 m bound on 2026-12-03's
    # hardware with unchanged code). Late on, MJX need only stay within native's own spread under a 1e-4
    # change; `early` is where the backends must agree.
    spread = np.abs(nat - _rollouts(agent, task, "native", perturb=1e-4))[:, :, :2].max()
    assert d[:, :, :2].max() < max(late, 1.5 * spread), (d[:, :, :2].max(), spread)  # torso xy
  else:
    assert d.max() < SMOOTH, d.max()
