"""hdt against the authors' code (bot_transfer/): scenes, starts, actuators, the HL step, and
solvability of every HL task by scripted controllers (tests/scripted.py)."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import scripted as S
from hdt import envs as E
from hdt.envs.tasks import Push
from hdt.transfer.hierarchy import HighLevelEnv


def _starts(env, n=64, seed=0):
  return jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(seed), n))


def test_arm_point_starts_beyond_the_block_with_fresh_noise():
  # reacher.py ReacherPM.reset: HL episodes start at (0.2, 0) +- 0.05, the block at (0.12, -0.08).
  env = E.make("arm_point", "push1", hl_horizon=1)
  s = _starts(env)
  tip, block = np.asarray(s.obs_hi[:, :2]), np.asarray(s.obs_hi[:, 2:4])
  assert np.all(np.abs(tip - [0.2, 0.0]) <= 0.05 + 1e-6) and tip[:, 0].std() > 0.02
  np.testing.assert_allclose(block, np.tile([0.12, -0.08], (len(block), 1)), atol=1e-6)
  assert np.all(tip[:, 0] > block[:, 0] + 0.02)  # the fingertip centre is past the block's far edge
  # A new episode draws a new start (no replayed fixed starts).
  one = jax.tree.map(lambda x: x[0], s)
  step = jax.jit(env.step)
  for _ in range(env.horizon):
    one = step(one, jnp.zeros(2))
  assert one.task["steps"] == 0 and not np.allclose(one.obs_hi[:2], tip[0], atol=1e-4)
  # LL episodes start at (0, 0) +- 0.05 (qpos[0] -= 0.2).
  ll = np.asarray(_starts(E.make("arm_point", "reach")).obs_hi[:, :2])
  assert np.all(np.abs(ll) <= 0.05 + 1e-6)


@pytest.mark.parametrize("agent,limit", [("arm2", 3.0), ("arm3", 2.7), ("arm4", 2.0)])
def test_arm_ll_starts_at_random_joint_angles(agent, limit):
  # reacher.py Reacher.reset_func(low=True): joint0 in +-pi, the others in +-RAND_LIMITS.
  q = np.asarray(_starts(E.make(agent, "reach"), n=256).physics.qpos)
  assert q[:, 0].min() < -2.5 and q[:, 0].max() > 2.5
  assert np.abs(q[:, 1:]).max() <= limit + 1e-6 and np.abs(q[:, 1:]).max() > 0.8 * limit
  # HL episodes: +-0.1 around qpos0.
  q = np.asarray(_starts(E.make(agent, "push1"), n=64).physics.qpos)
  arm = q[:, 2:]  # after the block's two slides
  assert np.abs(arm).max() <= 0.1 + 1e-6 and np.abs(arm).max() > 0.05


def test_ll_forces_a_physics_reset_after_ten_kept_episodes():
  # hierarchical.py Hierarchical.reset: max_sequential_low = 10.
  env = E.make("arm3", "reach", reset_prob=0.0, ll_horizon=2)
  s = env.reset(jax.random.PRNGKey(0))
  step = jax.jit(env.step)
  kept = []
  for _ in range(2 * 12):
    s = step(s, jnp.zeros(3))
    kept.append(int(s.task["kept"]))
  assert max(kept) == 10 and kept[-1] < 10 and 0 in kept[4:]


@pytest.mark.parametrize("agent", ["arm2", "arm3", "arm4"])
def test_arm_motor_force_limits(agent):
  # reacher_push*.xml: gear 100, ctrl +-0.5, forcelimited forcerange +-0.1: at most 10 N m.
  m = E.make(agent, "push1").mj_model
  np.testing.assert_allclose(m.actuator_gear[:, 0], 100.0)
  np.testing.assert_allclose(m.actuator_forcerange, np.tile([-0.1, 0.1], (m.nu, 1)))
  assert np.all(m.actuator_forcelimited == 1)
  d = mujoco.MjData(m)
  d.ctrl[:] = m.actuator_ctrlrange[:, 1]
  mujoco.mj_forward(m, d)
  assert np.abs(d.qfrc_actuator).max() == pytest.approx(10.0, rel=1e-6)


def test_arm_point_dynamics():
  # reacher_pm.xml: r 0.015 sphere (0.0141 kg), gear 10, ctrl +-0.7, damping 1: about 0.76 m/s at full ctrl.
  env = E.make("arm_point", "reach")
  m = env.mj_model
  tip = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "agent/root")
  assert m.body_mass[tip] == pytest.approx(4 / 3 * np.pi * 0.015 ** 3 * 1000, rel=1e-4)
  np.testing.assert_allclose(m.actuator_gear[:, 0], 10.0)
  np.testing.assert_allclose(m.actuator_ctrlrange, np.tile([-0.7, 0.7], (2, 1)))
  s = env.reset(jax.random.PRNGKey(0))
  step = jax.jit(lambda s: env.step(s, jnp.array([1.0, 0.0]), auto_reset=False))
  for _ in range(8):
    s = step(s)
  assert float(s.physics.qvel[0]) == pytest.approx(0.76, abs=0.03)


def test_control_cost_is_on_raw_controls():
  # Hierarchical.low_level_step: action_penalty * sum(a^2) with a the raw ctrl (ctrl +-0.5 for arms).
  env = E.make("arm3", "reach")
  s = env.reset(jax.random.PRNGKey(0))
  s0 = jax.jit(lambda s, a: env.step(s, a, auto_reset=False))
  n1, n0 = s0(s, jnp.ones(3)), s0(s, jnp.zeros(3))
  (r1, d1), (r0, d0) = (n1.reward, n1.metrics["goal_dist"]), (n0.reward, n0.metrics["goal_dist"])
  bonus = lambda d: 4.0 * (d < 0.01)
  np.testing.assert_allclose((r1 + d1 - bonus(d1)) - (r0 + d0 - bonus(d0)), -0.05 * 3 * 0.25, atol=1e-5)


def _hl(agent, task, ll, **kw):
  return HighLevelEnv(E.make(agent, task, **kw), ll, None)


def test_hl_step_stops_at_epsilon_and_pays_end_reward_minus_skill_penalty():
  hl = _hl("arm_point", "push1", S.point_ll(30.0, 0.5))
  s = jax.jit(hl.reset)(jax.random.PRNGKey(0))
  z = jnp.array([0.0, 0.5])  # 0.035 m up, away from the block
  n = jax.jit(hl.step)(s, z)
  assert 0 < n.metrics["ll_steps"] < hl.k  # stopped early ...
  assert float(n.metrics["sub_goal_dist"]) < 0.01  # ... within epsilon_low of the sub-goal
  dist = np.linalg.norm(np.asarray(n.next_obs_hi[2:4]) - np.array(Push().destination))
  assert float(n.reward) == pytest.approx(-dist - 0.05 * 0.035, abs=1e-5)
  # Without early stopping the LL runs all k steps.
  hl_k = HighLevelEnv(hl.env, hl.low_policy, None, early_stop=False)
  assert float(jax.jit(hl_k.step)(s, z).metrics["ll_steps"]) == hl.k


def test_vmapped_hl_step_is_the_authors_loop_per_env():
  """Each env of a vmapped HL step equals the authors' high_level_step on its own: LL steps one at a
  time until within epsilon_low of the sub-goal or k steps, whatever its neighbours still do."""
  hl = _hl("arm_point", "push1", S.point_ll(30.0, 0.5))
  s = jax.jit(jax.vmap(hl.reset))(jax.random.split(jax.random.PRNGKey(3), 6))
  z = jnp.array([[0.0, 0.5], [1.0, 1.0], [-1.0, 0.2], [0.1, 0.0], [0.3, -1.0], [-0.6, -0.6]])
  n = jax.jit(jax.vmap(hl.step))(s, z)
  inner_step = jax.jit(lambda st, a: hl.env.step(st, a, auto_reset=False))
  task, taken = hl.env.task, []
  for e in range(len(z)):
    st = jax.tree.map(lambda x: x[e], s.physics)
    goal = st.obs_hi[:2] + hl.delta_max * z[e]
    for i in range(hl.k):
      st = inner_step(st, hl.low_policy(None, task.ll_observation(st.obs_lo, st.obs_hi, goal)))
      if st.done or np.linalg.norm(np.asarray(st.obs_hi[:2] - goal)) < hl.eps:
        break
    taken.append(i + 1)
    assert int(n.metrics["ll_steps"][e]) == i + 1
    np.testing.assert_allclose(np.asarray(n.next_obs_hi[e]), np.asarray(st.obs_hi), atol=1e-6)
    want = float(st.reward) - task.skill_penalty * float(jnp.linalg.norm(hl.delta_max * z[e]))
    assert float(n.reward[e]) == pytest.approx(want, abs=1e-5)
  assert min(taken) < max(taken)  # envs stopped at different LL steps


def test_waypoint_hl_reward_is_100_once_when_reached_within_the_step():
  hl = _hl("point", "waypoint", S.point_ll(1.0, 0.3))
  s = jax.jit(hl.reset)(jax.random.PRNGKey(1))
  wp = np.asarray(s.obs_hi[2:4])
  z = np.clip((wp - np.asarray(s.obs_hi[:2])) / hl.delta_max, -1, 1)
  n = jax.jit(hl.step)(s, jnp.asarray(z, jnp.float32))
  if float(n.metrics["waypoints"]) > 0:
    assert float(n.reward) == pytest.approx(100.0 - 0.25 * np.linalg.norm(z * hl.delta_max), abs=1e-4)
  else:  # too far for one HL step: -0.1 * the 3-D distance at the end (torso origin z 0, target z 0.3)
    d = np.hypot(np.linalg.norm(np.asarray(n.next_obs_hi[:2]) - wp), 0.3)
    assert float(n.reward) == pytest.approx(-0.1 * d - 0.25 * np.linalg.norm(z * hl.delta_max), abs=1e-4)


def _u_path(cell):
  return [((c - 1) * cell, (r - 1) * cell) for r, c in ((1, 1), (1, 2), (1, 3), (2, 3), (3, 3), (3, 2), (3, 1))]


@pytest.mark.parametrize("task,cell,kw", [("maze", 8.0, dict(goal="end")), ("steps", 4.0, {})])
def test_scripted_point_mass_solves_the_u_maze_and_cannot_cut_it(task, cell, kw):
  hl = _hl("point", task, S.point_ll(1.0, 0.3), **kw)
  solved, n, _ = S.run_script(hl, S.path_script(_u_path(cell), 1.0))
  assert solved, f"{task}: the scripted point mass did not reach the end cell"
  # The middle wall (Maze) or the steps (Steps) block the direct way for a point mass.
  solved, _, _ = S.run_script(hl, S.path_script([(0.0, 0.0), (0.0, 2 * cell)], 1.0), max_steps=30)
  assert not solved


@pytest.mark.parametrize("agent", ["arm_point", "arm3"])
@pytest.mark.parametrize("task", ["push1", "push2"])
def test_scripted_blockpush(agent, task):
  env = E.make(agent, task)
  ll = S.point_ll(30.0, 0.5) if agent == "arm_point" else S.arm_ll(env)
  solved, n, _ = S.run_script(HighLevelEnv(env, ll, None), S.push_script(env.task.destination))
  assert solved, f"{agent} {task}: not solved in {n} HL steps"


@pytest.mark.parametrize("agent", ["arm_point", "arm4"])
def test_scripted_peg_insert(agent):
  env = E.make(agent, "insert")
  ll = S.point_ll(30.0, 0.5) if agent == "arm_point" else S.arm_ll(env)
  path = [(0.0, -0.10), (0.0, -0.14), (0.0, -0.2)]
  solved, n, _ = S.run_script(HighLevelEnv(env, ll, None), S.path_script(path, 0.012))
  assert solved, f"{agent}: peg not inserted in {n} HL steps"


@pytest.mark.parametrize("agent,qpos,qvel,normal", [("point", 0.4, 0.1, False), ("ant", 0.13, 0.13, True)])
def test_waypoint_start_noise_is_the_open_arena_classes(agent, qpos, qvel, normal):
  # point_mass.py PointMassLargeMJ.reset_func: qpos +-0.05 * arena_width (8), qvel +-0.1 uniform;
  # ant.py Ant.reset_func: qpos +-0.13, qvel 0.13 N(0, 1). The nav LL trains on the same classes.
  # The mazes keep maze.py's +-0.1 (PointMaze / AntMaze.reset_func).
  for task, half, vel in [("waypoint", qpos, qvel), ("reach", qpos, qvel), ("maze", 0.1, 0.1)]:
    env = E.make(agent, task)
    s = _starts(env, n=512)
    q = np.asarray(s.physics.qpos)[:, env._qpos_idx] - env._qpos0[env._qpos_idx]
    q = q if agent == "point" else q[:, 7:]  # the ant's hinges (no noise on its free joint)
    q = q[:, np.abs(q).max(0) > 1e-6]  # joints at a limit stay clipped there
    assert np.abs(q).max() <= half + 1e-5 and np.abs(q).max() > 0.95 * half, (task, np.abs(q).max())
    v = np.asarray(s.physics.qvel)[:, env._qvel_idx]
    if normal:
      assert abs(v.std() - vel) < 0.1 * vel, (task, v.std())
    else:
      assert np.abs(v).max() <= vel + 1e-6 and np.abs(v).max() > 0.95 * vel, (task, np.abs(v).max())


@pytest.mark.parametrize("agent,task,half", [("ant", "waypoint", 0.13), ("ant", "maze", 0.1), ("quadruped", "reach", 0.1)])
def test_legged_starts_perturb_the_free_joint_too(agent, task, half):
  # ant.py Ant.reset_func / maze.py AntMaze.reset_func / quadruped.py: uniform noise on every qpos entry,
  # the free joint's position and quaternion included (MuJoCo renormalises the quaternion).
  env = E.make(agent, task)
  s = _starts(env, n=512)
  q = np.asarray(s.physics.qpos)[:, env._qpos_idx]
  q0 = env._qpos0[env._qpos_idx]
  dpos = q[:, :3] - q0[:3]
  assert np.abs(dpos).max() <= half + 1e-5 and np.abs(dpos).min(0).max() < 0.05 * half
  assert np.all(np.abs(dpos).max(0) > 0.9 * half), np.abs(dpos).max(0)
  np.testing.assert_allclose(np.linalg.norm(q[:, 3:7], axis=1), 1.0, atol=1e-5)
  tilt = np.degrees(2 * np.arccos(np.clip(np.abs(q[:, 3]), 0, 1)))
  assert 3.0 < np.median(tilt) < 20.0, np.median(tilt)
  off = E.make(agent, task, free_joint_noise=False)
  q = np.asarray(_starts(off, n=64).physics.qpos)[:, off._qpos_idx]
  np.testing.assert_allclose(q[:, :7], np.tile(q0[:7], (64, 1)), atol=1e-6)


# -- PegInsert's own LL (insert.py Insert*Low, InsertPMLow) -------------------------------------------

def _insert_reach(agent, policy, n=128, seed=0):
  """(success rate, states) of ``policy`` over ``n`` LL episodes of the insert reach task."""
  env = E.make(agent, "reach", terrain="insert")
  s = _starts(env, n, seed)
  step = jax.jit(jax.vmap(lambda s: env.step(s, policy(None, s.obs))))
  for _ in range(env.horizon):
    s = step(s)  # the metrics of the last step are the episode's end, before the auto-reset
  return float(np.mean(np.asarray(s.metrics["success"]))), env


@pytest.mark.parametrize("agent,rate", [("arm_point", 1.0), ("arm3", 0.8), ("arm4", 0.8)])
def test_scripted_insert_ll_reaches_peg_tip_goals(agent, rate):
  # The insert LL's goal-space point is the peg tip, reached within insert.py's epsilon_low 0.015.
  # (Some arm goals lie beyond the arm's reach: the measured rates are 0.84 arm3, 0.92 arm4.)
  env = E.make(agent, "reach", terrain="insert")
  ll = S.point_ll(30.0, 0.5) if agent == "arm_point" else S.arm_ll(env, tool=0.05)
  got, _ = _insert_reach(agent, ll)
  assert got >= rate, (agent, got)
  # No slot wall in the LL scene (reacher_insert*_low.xml), the peg on the end effector.
  names = [env.mj_model.geom(i).name for i in range(env.mj_model.ngeom)]
  assert "peg/peg" in names and not any(n.startswith("slot/") for n in names)


def test_insert_pm_is_the_authors_insert_point_mass():
  # reacher_insert_pm.xml: gear 125, ctrl +-1, armature 1, damping 1, slides limited to +-0.3;
  # InsertPM.reset: HL starts (0.2, 0) +- 0.1, LL starts (0, 0) +- 0.1 (qpos[0] -= 0.2).
  for task, kw, centre in [("insert", {}, (0.2, 0.0)), ("reach", {"terrain": "insert"}, (0.0, 0.0))]:
    env = E.make("arm_point", task, **kw)
    m = env.mj_model
    np.testing.assert_allclose(m.actuator_gear[:, 0], [125, 125])
    np.testing.assert_allclose(m.actuator_ctrlrange, [[-1, 1], [-1, 1]])
    np.testing.assert_allclose(m.dof_armature, [1, 1])
    np.testing.assert_allclose(m.dof_damping, [1, 1])
    tip = np.asarray(_starts(env, n=256).obs_hi[:, 2:4])
    assert np.abs(tip - centre).max() <= 0.1 + 1e-5 and np.abs(tip - centre).max() > 0.09, task
  assert E.make("arm_point", "push1").mj_model.actuator_gear[0, 0] == 10  # the push PM is unchanged


@pytest.mark.parametrize("agent", ["arm_point", "arm3"])
def test_insert_ll_observation_and_reward_by_hand(agent):
  # insert.py Insert.agent_state_func: [..., g - fingertip, g - peg]; low_level_reward:
  # -|peg - g| (+4 within 0.015), minus action_penalty 0.05 * sum(ctrl^2) (Hierarchical.low_level_step).
  env = E.make(agent, "reach", terrain="insert")
  step = jax.jit(env.step)
  s0 = env.reset(jax.random.PRNGKey(1))
  a = jnp.full(env.action_size, 0.3)
  for offset in (np.zeros(2), np.array([0.0, 0.04])):
    nxt = step(s0, a)  # where the peg tip goes in one step; a goal there (+ offset)
    goal = nxt.obs_hi[:2] + offset
    s = s0.replace(task=dict(s0.task, t=dict(s0.task["t"], goal=goal)))
    nxt = step(s, a)
    peg, tip = np.asarray(nxt.next_obs_hi[:2]), np.asarray(nxt.next_obs_hi[2:4])
    d = np.linalg.norm(np.asarray(goal) - peg)
    want = -d - 0.05 * np.sum(np.square(np.asarray(env.ctrl(a)))) + 4.0 * (d < 0.015)
    assert float(nxt.reward) == pytest.approx(want, abs=1e-5)
    assert (d < 0.015) == (offset[1] == 0)
    obs = np.asarray(nxt.next_obs)
    np.testing.assert_allclose(obs[-4:], np.concatenate([goal - tip, goal - peg]), atol=1e-6)
    assert obs.shape[-1] == env.obs_lo_size + 4


def test_insert_ll_trains_and_only_an_insert_ll_drives_the_insert_hl(tmp_path):
  from hdt.transfer import checkpoint as ckpt
  from hdt.transfer import configs
  from hdt.transfer.pipeline import high_env, train_low
  from hdt.transfer.runner import RunOptions
  small = dict(total_env_steps=256, num_envs=4, steps_per_chunk=64, batch_size=16, buffer_size=512,
               hidden_sizes=(16, 16), num_eval_episodes=2)
  ins = train_low("arm_point", configs.low_config("arm_point", **small), terrain="insert",
                  options=RunOptions(out=tmp_path / "ins", quiet=True))
  assert ins.history["eval/success_max"].shape[1] >= 2  # a few chunks, each evaluated
  hl = high_env("insert", ins.run_dir)
  assert hl.env.agent.xml == "arm_point_insert.xml" and hl.eps == 0.015
  s = jax.jit(hl.step)(hl.reset(jax.random.PRNGKey(0)), jnp.zeros(2))
  assert np.isfinite(float(s.reward))
  plain = train_low("arm_point", configs.low_config("arm_point", **dict(small, total_env_steps=64)),
                    options=RunOptions(out=tmp_path / "plain", quiet=True))
  with pytest.raises(ckpt.CheckpointError, match="--set terrain=insert") as e:
    high_env("insert", plain.run_dir)
  assert "\n" not in str(e.value)
  high_env("push1", plain.run_dir)  # the plain LL still drives the push tasks


@pytest.mark.parametrize("agent", ["arm2", "arm3", "arm4"])
def test_capsule_base_pole_is_as_near_as_the_authors_cylinder(agent):
  # reacher_push*.xml's base pole is a cylinder (r 0.01, 0.03 high); hdt's is a capsule on the same
  # segment (MJX has no cylinder-box collision). The fingertip moves in the plane z = 0.015 and the
  # block's sides span the pole's height, so their distances to the pole are the cylinder's (down to
  # contact; deeper overlaps, which contacts prevent, are not compared).
  m = E.make(agent, "push1").mj_model
  pole, tip, block = (mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, n)
                      for n in ("agent/base", "agent/fingertip", "block/block"))
  assert m.geom_type[pole] == mujoco.mjtGeom.mjGEOM_CAPSULE
  cyl = E.make(agent, "push1").mj_model
  cyl.geom_type[pole] = mujoco.mjtGeom.mjGEOM_CYLINDER  # same size (r, half-height) and centre
  dc, dy = mujoco.MjData(m), mujoco.MjData(cyl)
  rng, limit = np.random.default_rng(0), m.jnt_range[3:].max()
  near = {tip: 0, block: 0}
  for _ in range(400):
    r, th = rng.uniform(0.03, 0.08), rng.uniform(-np.pi, np.pi)  # block centre (world xy = its qpos)
    q = np.concatenate([[r * np.cos(th), r * np.sin(th)], [rng.uniform(-np.pi, np.pi)],
                        rng.uniform(-limit, limit, m.nq - 3)])
    for d, mm in ((dc, m), (dy, cyl)):
      d.qpos[:] = q
      mujoco.mj_forward(mm, d)
    for g in (tip, block):
      a = mujoco.mj_geomDistance(m, dc, pole, g, 0.05, None)
      b = mujoco.mj_geomDistance(cyl, dy, pole, g, 0.05, None)
      if -0.002 < min(a, b) < 0.05:
        near[g] += 1
        assert a == pytest.approx(b, abs=1e-6), (g, q)
  assert near[tip] > 10 and near[block] > 50, near  # the check saw both objects close to the pole
