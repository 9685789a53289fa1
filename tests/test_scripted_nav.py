"""The navigation point mass (the authors' ball) and the Waypoint task under scripted control: the body's
dynamics, and that the task is solvable through hdt's own HL step."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from hdt.agents import acting
from hdt.envs.registry import make
from hdt.transfer.hierarchy import HighLevelEnv
from scripted import point_ll

MASS = 26.81  # sphere r 0.4, density 100 (PointMassLargeMJ: agent_size 0.4 in point_gather.xml)
GEAR = 75.0


def test_point_mass_is_the_authors_ball_free_under_full_force():
  env = make("point", "reach")
  m = env.mj_model
  root = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "agent/root")
  mass = float(m.body_subtreemass[root])
  assert abs(mass - MASS) < 0.01
  dofs = [m.jnt_dofadr[j] for j in range(m.njnt) if m.joint(j).name.startswith("agent/")]
  assert len(dofs) == 2 and np.all(m.dof_damping[dofs] == 0.0)
  assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4

  # Full force on both axes for 10 env steps: velocity grows by gear / mass per second, nothing else
  # acts (the floor contact carries no load: z is not a degree of freedom).
  step = jax.jit(lambda s: env.step(s, jnp.array([1.0, -1.0])))
  s = env.reset(jax.random.PRNGKey(0))
  v0 = np.asarray(s.obs_lo[:2])
  n = 10
  for _ in range(n):
    s = step(s)
  acc = (np.asarray(s.obs_lo[:2]) - v0) / (n * env.dt)
  np.testing.assert_allclose(acc, [GEAR / MASS, -GEAR / MASS], rtol=0.01)
  np.testing.assert_allclose(np.abs(acc), 2.80, rtol=0.01)


def test_scripted_hierarchy_reaches_waypoints():
  # A PD LL under a greedy HL (sub-goal = the waypoint relative to the ball, clipped to the +-4 m box),
  # through HighLevelEnv and hdt's evaluation rollout: if the body or the task broke, this rate drops.
  env = make("point", "waypoint")
  assert env.task.hl_relative == (2,) and not env.task.hl_absolute  # obs = waypoint - position
  hl = HighLevelEnv(env, point_ll(kp=1.0, kd=0.85), None)
  greedy = lambda params, obs: jnp.clip(obs, -hl.delta_max, hl.delta_max) / hl.delta_max
  out = jax.device_get(jax.jit(lambda k: acting.evaluate(hl, greedy, None, k, 8))(jax.random.PRNGKey(0)))
  per_episode = float(out["waypoints"] * out["length"])  # the metric is a mean over the 50 HL steps
  # measured 23.1 per episode (22.6 over 32 episodes; the trained HL over the trained LL: ~14)
  assert per_episode > 20.0, per_episode
  assert out["length"] == 50
