"""Environments: sizes, rewards, episode logic, walls, success tests, vmap."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hdt.envs as E
from hdt.envs.tasks import Insert, Maze, Push, Reach, Waypoint

# obs_lo sizes of the authors' state() minus the goal terms: PM qvel (2); legged qpos[2:] + qvel +
# clipped cfrc_ext of their models' bodies (ant.py: 16 bodies, 96; quadruped.py: 20 bodies, 120;
# their ant + 2 = 125 and quadruped + 2 = 165 numbers with g - xy); arms cos, sin, vel.
OBS_LO = {"point": 2, "ant": 13 + 14 + 96, "ant3": 11 + 12 + 96, "ant2": 9 + 10 + 96,
          "quadruped": 21 + 22 + 120, "arm_point": 2, "arm2": 6, "arm3": 9, "arm4": 12}
ACTIONS = {"point": 2, "ant": 8, "ant3": 6, "ant2": 4, "quadruped": 12, "arm_point": 2, "arm2": 2,
           "arm3": 3, "arm4": 4}


@pytest.mark.parametrize("agent", list(E.AGENTS))
def test_observation_sizes(agent):
  env = E.make(agent, "reach")
  assert env.obs_lo_size == OBS_LO[agent]
  assert env.action_size == ACTIONS[agent]
  assert env.obs_hi_size == 2 and env.observation_size == OBS_LO[agent] + 2
  s = jax.jit(env.reset)(jax.random.PRNGKey(0))
  s = jax.jit(env.step)(s, jnp.zeros(env.action_size))
  assert s.obs.shape == (env.observation_size,) and bool(jnp.all(jnp.isfinite(s.obs)))


def test_hl_observation_sizes():
  assert E.make("ant", "steps").obs_lo_size == OBS_LO["ant"] + 16  # 16 rangefinders
  assert E.make("arm3", "push1").obs_hi_size == 6  # tip, block, block velocity
  assert E.make("arm3", "insert").obs_hi_size == 4  # peg tip, end effector


def test_registry_errors_list_valid_names():
  with pytest.raises(ValueError, match="valid agents: point, ant"):
    E.make("spider", "reach")
  with pytest.raises(ValueError, match="valid tasks"):
    E.make("ant", "fly")
  with pytest.raises(ValueError, match="cannot reach the PegInsert"):
    E.make("arm2", "insert")
  with pytest.raises(ValueError, match="push1 is a manip task, point a nav agent"):
    E.make("point", "push1")
  with pytest.raises(ValueError, match="unknown override"):
    E.make("point", "reach", gear=3)


def q(point, z=0.0, **kw):
  """Quantities at goal-space point ``point`` (torso or tip) of height ``z``."""
  return {"point": jnp.asarray(point, jnp.float32), "z": jnp.float32(z),
          **{k: jnp.asarray(v, jnp.float32) for k, v in kw.items()}}


def test_reach_rewards_by_hand():
  key = jax.random.PRNGKey(0)
  ant = E.AGENTS["ant"]
  t = {"goal": jnp.array([3.0, 4.0])}
  # Moving 0.1 m straight toward the goal in dt = 0.05 s is 2 m/s of progress.
  step = 0.1 * np.array([3.0, 4.0]) / 5.0
  a = jnp.full(8, 0.5)
  r, solved, _, m = Reach().reward(key, ant, q([0, 0]), q(step), a, t, 0.05)
  assert np.isclose(r, 0.1 / 0.05 - 0.5 * 8 * 0.25 + 0.7, atol=1e-5)
  assert not solved
  # Sideways motion makes no progress.
  r, *_ = Reach().reward(key, ant, q([0, 0]), q([0.4, -0.3]), jnp.zeros(8), t, 0.05)
  assert np.isclose(r, 0.7, atol=1e-5)
  arm = E.AGENTS["arm3"]
  t = {"goal": jnp.array([0.1, 0.0])}
  r, _, _, m = Reach().reward(key, arm, q([0, 0]), q([0.1, 0.005]), jnp.array([0.2, 0, 0]), t, 0.03)
  assert np.isclose(r, -0.005 - 0.05 * 0.04 + 4.0, atol=1e-5) and m["success"] == 1.0
  r, _, _, m = Reach().reward(key, arm, q([0, 0]), q([0.0, 0.0]), jnp.zeros(3), t, 0.03)
  assert np.isclose(r, -0.1, atol=1e-6) and m["success"] == 0.0


def test_hl_rewards_by_hand():
  key = jax.random.PRNGKey(0)
  pm = E.AGENTS["point"]
  t = {"waypoint": jnp.array([3.0, 4.0])}
  # point_mass.py PointMassMJ.post_action / high_level_reward: the 3-D distance from the torso
  # origin (z = 0 for the point mass) to the target body at z = 0.3
  r, _, t2, _ = Waypoint().reward(key, pm, q([0, 0]), q([0, 0]), jnp.zeros(2), t, 0.06)
  assert np.isclose(r, -0.1 * np.sqrt(25 + 0.09)) and np.allclose(t2["waypoint"], [3, 4])
  r, _, t2, m = Waypoint().reward(key, pm, q([0, 0]), q([3.0, 3.62]), jnp.zeros(2), t, 0.06)
  # exactly 100 when reached (no distance term): 0.38 m in the plane is 0.48 m in 3-D
  assert np.isclose(r, 100.0) and m["waypoints"] == 1.0
  assert not np.allclose(t2["waypoint"], [3, 4])  # a new waypoint appeared
  r, _, _, m = Waypoint().reward(key, pm, q([0, 0]), q([3.0, 3.58]), jnp.zeros(2), t, 0.06)
  assert m["waypoints"] == 0.0  # 0.42 m in the plane is 0.52 m in 3-D: not reached
  r, _, _, m = Waypoint().reward(key, pm, q([0, 0]), q([3.0, 3.62], z=0.7), jnp.zeros(2), t, 0.06)
  assert m["waypoints"] == 0.0  # an ant torso 0.4 m above the target is not there yet
  maze = Maze(goal="end")
  t = maze.sample(key, pm, q([0, 0]))
  assert np.allclose(t["goal"], [0, 16])
  r, solved, *_ = maze.reward(key, pm, q([0, 0]), q([1.0, 13.0]), jnp.zeros(2), t, 0.06)
  assert r == 1000 and solved
  r, solved, *_ = maze.reward(key, pm, q([0, 0]), q([1.0, 11.0]), jnp.zeros(2), t, 0.06)
  assert r == 0 and not solved
  arm = E.AGENTS["arm3"]
  push = Push()
  r, solved, *_ = push.reward(key, arm, q([0, 0]), q([0, 0], block=[0.0, -0.08], block_vel=[0, 0]),
                              jnp.zeros(3), {}, 0.03)
  assert np.isclose(r, -0.1) and not solved
  r, solved, *_ = push.reward(key, arm, q([0, 0]), q([0, 0], block=[-0.11, -0.08], block_vel=[0, 0]),
                              jnp.zeros(3), {}, 0.03)
  assert np.isclose(r, 200.0) and solved  # reacher.py Reacher.high_level_reward
  r, solved, *_ = Insert().reward(key, arm, q([0, 0]), q([0.01, -0.2], tip=[0, 0]), jnp.zeros(3), {}, 0.03)
  assert solved and np.isclose(r, 50 - 20 * (0.01 ** 2 + 0.01 ** 2), atol=1e-5)


def _with_qpos(env, state, qpos):
  ps = env.physics.forward(state.physics.time, jnp.asarray(qpos, jnp.float32), state.physics.qvel * 0)
  return state.replace(physics=ps)


def test_fall_ends_episode():
  env = E.make("ant", "reach")
  s = env.reset(jax.random.PRNGKey(0))
  qpos = np.array(s.physics.qpos)
  qpos[2] = 1.2  # torso above the 1.0 m bound (thrown up: Gym ant's unhealthy case)
  s = jax.jit(env.step)(_with_qpos(env, s, qpos), jnp.zeros(8))
  assert s.metrics["fall"] == 1.0 and s.done == 1.0 and s.discount == 0.0
  assert s.task["steps"] == 0 and s.physics.qpos[2] > 0.5  # back at the initial state


def test_a_fall_does_not_end_a_task_episode_of_the_full_baseline():
  """The authors' FullEnv ends an episode on high_level_is_done only, which ignores falls (ant.py
  Ant.high_level_is_done: False; maze.py MazeMJ: the goal cell): a fallen ant stays down and keeps
  paying the task reward until the time limit."""
  for task in ("waypoint", "maze"):
    env = E.make("ant", task)
    s = env.reset(jax.random.PRNGKey(0))
    qpos = np.array(s.physics.qpos)
    qpos[2] = 1.2
    s = jax.jit(env.step)(_with_qpos(env, s, qpos), jnp.zeros(8))
    assert s.metrics["fall"] == 1.0 and s.done == 0.0 and s.discount == 1.0, task
    assert s.task["steps"] == 1, task


def test_reach_keeps_robot_between_episodes():
  env = E.make("point", "reach", reset_prob=0.0, ll_horizon=5)
  s = env.reset(jax.random.PRNGKey(0))
  step = jax.jit(env.step)
  goal0 = s.task["t"]["goal"]
  for _ in range(5):
    s = step(s, jnp.array([1.0, 0.0]))
  assert s.done == 1.0 and s.discount == 1.0  # time limit: not a fall (SACConfig decides the target)
  assert s.physics.qpos[0] > 0.1  # robot kept where it was (0.126 m at 2.8 m/s^2 for 0.3 s) ...
  assert not np.allclose(s.task["t"]["goal"], goal0)  # ... with a new goal
  np.testing.assert_allclose(s.obs[-2:], s.task["t"]["goal"] - s.obs_hi[:2], atol=1e-6)


def test_walls_stop_point_in_maze():
  env = E.make("point", "maze", goal="end")
  s = env.reset(jax.random.PRNGKey(0))
  step = jax.jit(env.step)
  ys = []
  for _ in range(150):  # full force toward the middle wall (its face is at y = 4)
    s = step(s, jnp.array([0.0, 1.0]))
    ys.append(float(s.obs_hi[1]))
  assert max(ys) < 4.0 - 0.4 and max(ys) > 3.0  # pressed against the wall, not through it


def test_success_in_goal_cell():
  env = E.make("point", "maze", goal="end")
  s = env.reset(jax.random.PRNGKey(0))
  s = jax.jit(env.step)(_with_qpos(env, s, [0.0, 15.0]), jnp.zeros(2))
  assert s.metrics["success"] == 1.0 and s.reward == 1000.0 and s.done == 1.0 and s.discount == 0.0


def test_block_reaches_destination():
  env = E.make("arm3", "push1")
  s = env.reset(jax.random.PRNGKey(0))
  qpos = np.array(s.physics.qpos)
  names = [env.mj_model.joint(j).name for j in range(env.mj_model.njnt)]
  qpos[env.mj_model.jnt_qposadr[names.index("block/block_x")]] = -0.09  # qpos is world x (joint ref)
  s = jax.jit(env.step)(_with_qpos(env, s, qpos), jnp.zeros(3))
  assert s.metrics["success"] == 1.0 and s.done == 1.0 and s.reward > 199


def test_peg_inserted():
  env = E.make("arm_point", "insert")
  s = env.reset(jax.random.PRNGKey(0))
  # arm_point's slide qpos is its world position (joint ref); its peg points 0.05 m along -y.
  s = jax.jit(env.step)(_with_qpos(env, s, [0.0, -0.15]), jnp.zeros(2))
  assert s.metrics["success"] == 1.0 and s.done == 1.0
  s2 = env.reset(jax.random.PRNGKey(0))
  assert jax.jit(env.step)(s2, jnp.zeros(2)).metrics["success"] == 0.0


@pytest.mark.parametrize("agent,task", [("ant", "reach"), ("arm3", "push1")])
def test_vmap_equals_single_runs(agent, task):
  env = E.make(agent, task)
  keys = jax.random.split(jax.random.PRNGKey(3), 64)
  actions = jax.random.uniform(jax.random.PRNGKey(4), (10, 64, env.action_size), minval=-1, maxval=1)

  def run(key, acts):
    s = env.reset(key)
    def f(s, a):
      s = env.step(s, a)
      return s, s.obs
    return jax.lax.scan(f, s, acts)[1]

  batched = jax.jit(jax.vmap(run, in_axes=(0, 1)))(keys, actions)
  single = jax.jit(run)
  for i in range(0, 64, 9):
    np.testing.assert_allclose(batched[i], single(keys[i], actions[:, i]), rtol=1e-5, atol=1e-5)


def test_steps_ll_pretraining_terrain_matches_steps_observations():
  # The Steps LL is pretrained on random barriers with the same 16 rangefinders it has on Steps.
  pre = E.make("ant", "reach", terrain="steps")
  assert pre.obs_lo_size == E.make("ant", "steps").obs_lo_size == OBS_LO["ant"] + 16
  s = jax.jit(pre.step)(jax.jit(pre.reset)(jax.random.PRNGKey(0)), jnp.zeros(8))
  rays = s.obs_lo[-16:]
  assert bool(jnp.all((rays > 0) & (rays < 4.0)))  # every ray sees the floor (or a leg) in range
  with pytest.raises(ValueError, match="terrain"):
    E.make("ant", "reach", terrain="lava")


def test_tasks_declare_the_sensors_they_read():
  from hdt.envs.env import AgentTaskEnv
  from hdt.envs.registry import agent_spec
  q = lambda env: env.quantities(env.reset(jax.random.PRNGKey(0)).physics)
  assert {"block", "block_vel"} <= set(q(E.make("arm3", "push1")))
  assert "block" not in q(E.make("arm3", "insert"))  # declared by Push only
  bad = type("BadPush", (Push,), {"sensors": {"block": "block/no_such_sensor"}})
  with pytest.raises(ValueError, match="no_such_sensor"):
    AgentTaskEnv(agent_spec("arm3"), bad())


@pytest.mark.parametrize("agent,task", [(a, "reach") for a in E.AGENTS] + [("arm3", "push1")])
def test_observed_point_is_forward_kinematics_of_the_final_qpos(agent, task):
  """The observed goal-space point (and every position sensor) describes the state the step returned
  (native backend; tests/test_backends.py checks MJX too)."""
  import mujoco
  env = E.make(agent, task, backend="native")
  s = env.reset(jax.random.PRNGKey(0))
  step = jax.jit(env.step)
  acts = jax.random.uniform(jax.random.PRNGKey(1), (6, env.action_size), minval=-1, maxval=1)
  m, d = env.mj_model, mujoco.MjData(env.mj_model)
  site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "agent/goal_point")
  for a in acts:
    s = step(s, a)
    d.qpos[:] = np.asarray(s.physics.qpos, np.float64)
    mujoco.mj_kinematics(m, d)
    tip = np.concatenate([np.asarray(env.quantities(s.physics)["tip"]), [float(env.quantities(s.physics)["z"])]])
    np.testing.assert_allclose(tip, d.site_xpos[site], atol=1e-6, rtol=0)
    np.testing.assert_allclose(s.obs_hi[:2], d.site_xpos[site][:2], atol=1e-6, rtol=0)


@pytest.mark.parametrize("agent", ["ant", "quadruped"])
def test_legged_observation_is_the_authors_state(agent):
  """ant.py Ant.state / quadruped.py Quadruped.state then agent_state_func: qpos[2:], qvel,
  clip(cfrc_ext, -1, 1) of their model's bodies (world, robot, target, highlevel), g - xy; here
  recomputed with plain MuJoCo from the state the step returned."""
  import mujoco
  env = E.make(agent, "reach", backend="native")
  s = env.reset(jax.random.PRNGKey(0))
  step = jax.jit(env.step)
  a = 0.5 * jnp.ones(env.action_size)
  for _ in range(15):  # standing on the floor: contact forces are not zero
    s = step(s, a)
  m, d = env.mj_model, mujoco.MjData(env.mj_model)
  d.qpos[:], d.qvel[:] = np.asarray(s.physics.qpos, np.float64), np.asarray(s.physics.qvel, np.float64)
  if m.na:
    d.act[:] = np.asarray(s.physics.act, np.float64)
  d.ctrl[:] = np.asarray(env.ctrl(a))
  mujoco.mj_forward(m, d)
  mujoco.mj_rnePostConstraint(m, d)
  robot = [b for b in range(m.nbody) if m.body_rootid[b] == m.body("agent/root").id]
  cfrc = np.concatenate([np.zeros(6), np.clip(d.cfrc_ext[robot], -1, 1).ravel(), np.zeros(12)])
  goal = np.asarray(s.task["t"]["goal"])
  want = np.concatenate([d.qpos[2:], d.qvel, cfrc, goal - d.qpos[:2]])
  assert s.obs.shape == want.shape == ({"ant": 125, "quadruped": 165}[agent],)
  assert np.abs(cfrc).sum() > 1.0  # feet on the floor
  np.testing.assert_allclose(np.asarray(s.obs), want, atol=2e-3)
