"""hdt's trained navigation policies, unchanged, in an independent rebuild of the authors' envs.

    python benchmarks/authors_envs.py MIRROR [--agent point|ant|quadruped] \
        [--low runs/pm_low] [--high runs/pm_waypoint] [--episodes 100] [--json benchmarks/authors_envs.json]

The first argument is the authors' repository (a checkout or a bare git mirror, read with ``git show
HEAD:...``). Their bot_transfer/envs/assets/point_gather.xml is rewritten as ``PointMassMJ.__init__``
does for ``PointMassLargeMJ`` (agent_size 0.4: the first torso geom's size and pos; gear 75 on every
motor) and run with plain ``mujoco`` and numpy. The rebuild uses no hdt environment code: hdt only loads
the parameters (``hdt.transfer.evaluate.load_policy`` / ``compose``) and applies the policy networks
(``PolicyCard.policy_fn``: tanh of the mean, as hdt's evaluation acts).

``--agent ant`` / ``quadruped`` rebuild ant.py ``Ant`` (ant_gather.xml as it is: gear 150, RK4, frame
skip 5) and quadruped.py ``Quadruped`` (quadruped_gather.xml, frame skip 3) the same way, with what
their classes add: the survive bonus 0.7, the fall test on the torso height (``low_level_is_done``:
an LL episode ends there, an HL step's LL loop stops), their reset noise, and ``clip(cfrc_ext, -1,
1)`` in the state. Two things of MuJoCo 1.50 (the authors' ``mujoco-py<2.0``) are reproduced: a
contact's margin is the larger of the two geoms' (the floor's margin set to 0, as
``authors_bodies.with_max_margin_rule``), and ``cfrc_ext`` is what its ``mj_forward`` left, i.e. of
the state at the start of the last substep (and of the state set, after a reset). The --low LL is of
that agent; --high is any agent's Waypoint HL composed over it (the PM's, by default of hdt).

The rebuild (point_mass.py PointMassMJ / PointMassLargeMJ, hierarchical.py Hierarchical, LowLevelEnv,
HighLevelEnv) keeps their order of operations:
  * positions are ``data.xpos`` after ``mj_step`` (mujoco-py's ``get_body_xpos``), no extra forward;
    the target body is moved in ``model.body_pos``, so its xpos follows at the next step;
  * ``low_level_step``: prev_state before the action, the LL marker moved to the goal, ctrl set, 3
    steps, the progress reward after (weighted cosine over dt) minus 0.5 * sum(a^2), then
    ``post_action`` (waypoint reached at a 3-D torso-target distance < 0.5 -> flag, new waypoint
    uniform in the disc of radius 8 by rejection from the square);
  * ``high_level_step``: goal = position + skill, up to k LL steps, stop once the 2-D distance to the
    goal is < epsilon_low 0.27; reward -0.25 * |skill| plus 100 if a waypoint was reached during the
    step, else -0.1 * the 3-D distance at its end;
  * resets (``reset_func``): qpos0 + U(+-0.05 * 8), qvel U(+-0.1), a new waypoint; the LL env's
    ``reset(low=True)`` keeps the state unless a reset_prob coin or max_sequential_low says otherwise,
    and always draws a new goal = position + U(+-delta_max 4).

Values set by the authors' experiment configs rather than their classes are taken as hdt trains with
them (and checked against the policies' cards): k 32 (the quadruped 64), LL episodes of 100 steps (the
quadruped 150), reset_prob 0.1, max_sequential_low 10 (the class default), 50 HL steps per Waypoint
episode.
SB2's SAC rescales a [-1, 1] action to the action space [low, high]: the ctrlrange for the LL (the
identity on the point mass and the ant, not on the quadruped), the skill space [-4, 4] for the HL
(skill = 4 * a).

Adapter (a deliberate departure of hdt, SPEC.md section 8, "Waypoint HL input"): the authors' HL
observes obs_func = (torso xy, target xy); hdt's HL observes ``Task.hl_features`` of that, which for a
Waypoint HL trained with hdt's defaults (hl_relative=(2,), hl_absolute=False) is target xy - torso xy.
``hl_input`` rebuilds that map from the HL card's recorded layout, so an HL trained with absolute
inputs (``--preset paper``) gets the raw observation.

Evaluations (100 episodes per seed, deterministic policies):
  (a) LL episodes on the rebuilt LowLevelEnv, ``--low`` run, seeds 0..2, --params best and final.
      success = the fraction of episodes within epsilon_low 0.27 of the goal at some step (hdt's
      ``success`` of reach, reduced by ``max`` over the episode: eval/success_max); goal_dist_final =
      the 2-D goal distance after the last step, goal_dist = its mean over the episode's steps.
      "fresh": every episode starts with reset_func (as each of hdt's parallel evaluation episodes
      does); "sequential": the LowLevelEnv's own reset rules, episode after episode (the state is kept
      with probability 0.9).
  (b) an HL over an LL (``--high`` over ``--low``, paired as ``hdt.compose`` pairs them) on Waypoint:
      mean episode return, waypoints reached per episode.
  (c) lockstep: one LL episode per seed in both envs from the same start and goal, hdt's env given the
      rebuild's actions: the largest per-step differences of the LL observation and reward.
The same numbers from hdt's own env come from ``hdt.evaluate``'s computation (same keys as
``hdt eval --policy RUN --task reach --episodes 100`` and ``hdt eval --high RUN --low RUN --task
waypoint --episodes 100``), read in full (also goal_dist_final and waypoints per episode).
Acceptance: LL success equal within 0.05, HL return within 10%.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

ASSETS = "bot_transfer/envs/assets/"
OUT = Path(__file__).with_suffix(".json")

# PointMassLargeMJ.__init__ (point_mass.py)
AGENT_SIZE, GEAR = 0.4, 75
EPSILON_LOW, EPSILON_HIGH = 0.27, 0.5
ACTION_PENALTY, SKILL_PENALTY = 0.5, 0.25
SPARSE_REWARD, ARENA_WIDTH = 100.0, 8.0
DELTA_MAX = 4.0
# as hdt trains (hdt's NAV family, Waypoint task); checked against the cards in main()
HL_HORIZON, RESET_PROB, MAX_SEQUENTIAL_LOW = 50, 0.1, 10


def read_authors(repo: str, path: str) -> str:
  p = Path(repo) / path
  if p.is_file():
    return p.read_text()
  return subprocess.run(["git", "-C", repo, "show", f"HEAD:{path}"], capture_output=True, text=True,
                        check=True).stdout


def authors_xml(repo: str, agent: str = "point") -> str:
  """The agent's file as the authors' class loads it: point_gather.xml rewritten as
  PointMassMJ.__init__ does (agent_size, gear); ant_gather.xml (gear=None keeps its 150) and
  quadruped_gather.xml as they are."""
  text = read_authors(repo, ASSETS + AUTHORS[agent].FILE)
  if agent != "point":
    return text
  tree = ET.ElementTree(ET.fromstring(text))
  geom = tree.find(".//worldbody/body/geom")
  geom.set("size", str(AGENT_SIZE))
  geom.set("pos", "0 0 " + str(AGENT_SIZE))
  for motor in tree.find(".//actuator").findall("motor"):
    motor.set("gear", str(GEAR))
  return ET.tostring(tree.getroot(), encoding="unicode")


class PointMassLarge:
  """One PointMassLargeMJ: Hierarchical's LL and HL steps on its own MjModel (body_pos is mutated).
  The ant and quadruped below differ by the class attributes and the methods they override."""

  FILE, FRAME_SKIP, K, LL_HORIZON = "point_gather.xml", 3, 32, 100  # PointMassMJ -> HierarchicalMJ(path, 3)
  SURVIVE, Z_RANGE, CONTACTS = 0.0, None, False

  def __init__(self, xml: str, seed, k=None, reset_prob=RESET_PROB, max_sequential_low=MAX_SEQUENTIAL_LOW):
    self.model = mujoco.MjModel.from_xml_string(xml)
    if self.CONTACTS:  # the robot stands on the floor: contacts as MuJoCo 1.50 mixed their margins
      from authors_bodies import with_max_margin_rule
      self.model = with_max_margin_rule(self.model, self.model.geom("floor").id)
    self.data = mujoco.MjData(self.model)
    body = lambda n: mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, n)
    self.torso, self.target, self.highlevel = body("torso"), body("target"), body("highlevel")
    self.rng = np.random.default_rng(seed)
    self.k, self.reset_prob, self.max_sequential_low = k or self.K, reset_prob, max_sequential_low
    self.dt = self.model.opt.timestep * self.FRAME_SKIP
    self.reached_goal = False
    self.num_sequential_low = 0
    self.waypoints = 0  # every post_action hit (hdt's "waypoints" metric sums them too)
    self.cfrc = np.zeros_like(self.data.cfrc_ext)
    self.init_qpos, self.init_qvel = self.data.qpos.copy(), self.data.qvel.copy()
    # HierarchicalMJ.__init__ ends with a random skill and one random LL step
    self.set_skill(self.sample_skill())
    lo, hi = self.model.actuator_ctrlrange.T
    self.low_level_step(self.rng.uniform(lo, hi))  # action_space().sample()

  def unscale(self, action):
    """SB2's SAC acts in [-1, 1] and rescales onto the action space, the actuators' ctrlrange."""
    lo, hi = self.model.actuator_ctrlrange.T
    return lo + (np.clip(action, -1.0, 1.0) + 1.0) * 0.5 * (hi - lo)

  # -- PointMassMJ / Ant / Quadruped -------------------------------------------------------------
  def state(self):
    d = self.data
    forces = [np.clip(self.cfrc, -1.0, 1.0).reshape(-1)] if self.CONTACTS else []
    return np.concatenate([d.qpos[2:], d.qvel, *forces, d.xpos[self.torso][:2], d.xpos[self.target][:2]])

  def agent_state_func(self, state):
    return np.concatenate([state[:-4], self.low_level_goal - state[-4:-2]])

  @staticmethod
  def obs_func(state):
    return state[-4:]

  @staticmethod
  def skill_func(obs):
    return obs[:2]

  def _contact_forces(self):
    """cfrc_ext as mujoco-py < 2.0 (MuJoCo 1.5, the authors' requirements.txt) leaves it: mj_forward
    ran mj_rnePostConstraint on every call, so after sim.step() it describes the state at the start of
    the last substep (RK4's later stages skip it), and after sim.forward() the state set."""
    mujoco.mj_forward(self.model, self.data)
    mujoco.mj_rnePostConstraint(self.model, self.data)
    self.cfrc = self.data.cfrc_ext.copy()

  def apply_action(self, action):
    self.model.body_pos[self.highlevel][:2] = self.low_level_goal
    self.data.ctrl[:] = action
    for i in range(self.FRAME_SKIP):
      if self.CONTACTS and i == self.FRAME_SKIP - 1:
        self._contact_forces()
      mujoco.mj_step(self.model, self.data)

  def sample_waypoint(self):
    while True:
      goal = self.rng.uniform(-ARENA_WIDTH, ARENA_WIDTH, 2)
      if np.linalg.norm(goal) < ARENA_WIDTH:
        return goal

  def target_dist(self):
    return np.linalg.norm(self.data.xpos[self.torso] - self.data.xpos[self.target])

  def post_action(self):
    if self.target_dist() < EPSILON_HIGH:
      self.reached_goal = True
      self.waypoints += 1
      self.model.body_pos[self.target][:2] = self.sample_waypoint()

  def low_level_reward(self, prev_state):
    prev_delta = prev_state[-2:]
    curr_delta = self.agent_state_func(self.state())[-2:]
    forward = np.dot(prev_delta - curr_delta, prev_delta) / (np.linalg.norm(prev_delta) + 1e-6)
    return forward / self.dt + self.SURVIVE

  def low_level_is_done(self):
    if self.Z_RANGE is None:
      return False
    z = self.data.qpos[2]
    finite = np.isfinite(self.data.qpos).all() and np.isfinite(self.data.qvel).all()
    return not (finite and self.Z_RANGE[0] <= z <= self.Z_RANGE[1])

  def high_level_reward(self):
    if self.reached_goal:
      self.reached_goal = False
      return SPARSE_REWARD
    return -0.1 * self.target_dist()

  def set_mj_state(self, qpos, qvel):
    self.data.qpos[:], self.data.qvel[:] = qpos, qvel
    mujoco.mj_forward(self.model, self.data)  # sim.forward()
    if self.CONTACTS:
      self._contact_forces()

  def reset_func(self):
    mujoco.mj_resetData(self.model, self.data)
    qpos = self.rng.uniform(-0.05 * ARENA_WIDTH, 0.05 * ARENA_WIDTH, self.model.nq) + self.init_qpos
    self.model.body_pos[self.target][:2] = self.sample_waypoint()
    qvel = self.init_qvel + self.rng.uniform(-0.1, 0.1, self.model.nv)
    self.set_mj_state(qpos, qvel)

  # -- Hierarchical ------------------------------------------------------------------------------
  def sample_skill(self):
    return self.rng.uniform(-DELTA_MAX, DELTA_MAX, 2)

  def set_skill(self, skill):
    self.low_level_goal = self.skill_func(self.obs_func(self.state())) + skill

  def goal_dist(self):
    return np.linalg.norm(self.skill_func(self.obs_func(self.state())) - self.low_level_goal)

  def low_level_step(self, action):
    prev_state = self.agent_state_func(self.state())
    self.apply_action(action)
    reward = self.low_level_reward(prev_state) - ACTION_PENALTY * np.sum(np.square(action))
    done = self.low_level_is_done()  # early_low_termination is off
    self.post_action()
    return self.agent_state_func(self.state()), reward, done

  def reset(self, low=False):
    reset = (not low or (low and self.low_level_is_done()) or self.rng.random() < self.reset_prob
             or self.num_sequential_low == self.max_sequential_low)
    if reset:
      self.reset_func()
      self.num_sequential_low = 0
    else:
      self.num_sequential_low += 1
    self.set_skill(self.sample_skill())

  def high_level_start(self, skill):
    """First half of high_level_step: the sub-goal."""
    self.set_skill(skill)

  def high_level_end(self, skill):
    """Last half of high_level_step (after the LL loop): reward and observation."""
    reward = -SKILL_PENALTY * np.linalg.norm(skill) + self.high_level_reward()
    return self.obs_func(self.state()), reward


class Ant(PointMassLarge):
  """ant.py Ant (gear=None: the file's 150; include_contacts=True), at hdt's k."""

  FILE, FRAME_SKIP, K, LL_HORIZON = "ant_gather.xml", 5, 32, 100
  SURVIVE, Z_RANGE, CONTACTS = 0.7, (0.2, 1.0), True

  def reset_func(self):
    mujoco.mj_resetData(self.model, self.data)
    qpos = self.rng.uniform(-0.13, 0.13, self.model.nq) + self.init_qpos
    qvel = self.init_qvel + self.rng.standard_normal(self.model.nv) * 0.13
    self.set_mj_state(qpos, qvel)
    self.model.body_pos[self.target][:2] = self.sample_waypoint()


class Quadruped(PointMassLarge):
  """quadruped.py Quadruped (include_contacts=True), at hdt's k and LL horizon."""

  FILE, FRAME_SKIP, K, LL_HORIZON = "quadruped_gather.xml", 3, 64, 150
  SURVIVE, Z_RANGE, CONTACTS = 0.7, (0.15, 0.9), True

  def reset_func(self):
    mujoco.mj_resetData(self.model, self.data)
    qpos = self.rng.uniform(-0.1, 0.1, self.model.nq) + self.init_qpos
    self.model.body_pos[self.target][:2] = self.sample_waypoint()
    qvel = self.init_qvel + self.rng.standard_normal(self.model.nv) * 0.1
    self.set_mj_state(qpos, qvel)


AUTHORS = {"point": PointMassLarge, "ant": Ant, "quadruped": Quadruped}


# -- policies --------------------------------------------------------------------------------------
def jitted_policy(card):
  """apply(params, obs_norm, obs) -> deterministic action, jitted once per card."""
  import jax
  return jax.jit(lambda params, norm, obs: card.policy_fn(norm)(params, obs))


def hl_input(obs, layout):
  """What hdt's HL observes of the authors' obs_func (torso xy, target xy): Task.hl_features, here in
  numpy from the HL card's layout: pairs at the ``hl_relative`` offsets made relative to the goal-space
  point obs[:2], which is kept only if ``hl_absolute``."""
  point = obs[..., :2]
  parts, i = ([point] if layout.hl_absolute else []), 2
  while i < obs.shape[-1]:
    if i in layout.hl_relative:
      parts.append(obs[..., i:i + 2] - point)
      i += 2
    else:
      parts.append(obs[..., i:i + 1])
      i += 1
  return np.concatenate(parts, axis=-1)


def check_adapter():
  """hl_input against hdt's own Task.hl_features, both layouts (comparison side only)."""
  from hdt.envs.tasks import get_task
  from hdt.transfer.card import ObsLayout
  obs = np.random.default_rng(0).normal(size=(5, 4)).astype(np.float32)
  for layout in (ObsLayout((2,), False), ObsLayout((), True)):
    want = np.asarray(get_task("waypoint", **layout.task_options()).hl_features(obs))
    np.testing.assert_allclose(hl_input(obs, layout), want, rtol=0, atol=1e-6)


def at(tree, i):
  import jax
  return None if tree is None else jax.tree.map(lambda x: x[i], tree)


def act(apply, params, norm, obs):
  return np.asarray(apply(params, norm, np.asarray(obs, np.float32)), np.float64)


# -- evaluations in the rebuilt envs ---------------------------------------------------------------
def low_episodes(cls, xml, apply, params, norm, episodes, seed, protocol):
  """LL episodes of cls.LL_HORIZON steps (or to a fall), batched over envs (fixed batch: one policy
  shape)."""
  if protocol == "fresh":
    envs = [cls(xml, [seed, e]) for e in range(episodes)]
    per_env = 1
  else:  # sequential: 10 envs, each through its own reset rules
    n_env = 10
    envs = [cls(xml, [seed, e]) for e in range(n_env)]
    per_env = -(-episodes // n_env)
  success, final, mean_dist, ret, falls = [], [], [], [], []
  for _ in range(per_env):
    for env in envs:
      if protocol == "fresh":
        env.reset_func()
        env.set_skill(env.sample_skill())
      else:
        env.reset(low=True)  # LowLevelEnv.reset
    obs = np.stack([env.agent_state_func(env.state()) for env in envs])
    hit, alive = np.zeros(len(envs), bool), np.ones(len(envs), bool)
    dsum, r, steps = np.zeros(len(envs)), np.zeros(len(envs)), np.zeros(len(envs))
    for _ in range(cls.LL_HORIZON):
      actions = act(apply, params, norm, obs)
      for j in np.flatnonzero(alive):
        env = envs[j]
        obs[j], rew, done = env.low_level_step(env.unscale(actions[j]))
        r[j] += rew
        d = env.goal_dist()
        hit[j] |= d < EPSILON_LOW
        dsum[j] += d
        steps[j] += 1
        alive[j] = not done
    success += hit.tolist()
    final += [env.goal_dist() for env in envs]
    mean_dist += (dsum / steps).tolist()
    falls += (~alive).tolist()
    ret += r.tolist()
  n = episodes
  return dict(success=float(np.mean(success[:n])), goal_dist_final=float(np.mean(final[:n])),
              goal_dist=float(np.mean(mean_dist[:n])), return_=float(np.mean(ret[:n])),
              falls=float(np.mean(falls[:n])))


def high_episodes(cls, xml, hl_apply, hl_params, hl_norm, layout, ll_apply, ll_params, ll_norm, episodes, seed):
  """Waypoint episodes (HighLevelEnv over the LL), all episodes stepped together: per HL step every
  env runs its own LL loop (the early stop per env), the LL policy evaluated on the whole batch."""
  envs = [cls(xml, [seed, e]) for e in range(episodes)]
  for env in envs:
    env.reset(low=False)  # HighLevelEnv.reset
    env.waypoints = 0
  obs = np.stack([env.obs_func(env.state()) for env in envs])
  ret = np.zeros(episodes)
  bonus_steps = np.zeros(episodes)
  stale = np.zeros(episodes)  # HL observations showing a reached waypoint (moved on the last LL step)
  ll_steps = 0
  for _ in range(HL_HORIZON):
    skills = DELTA_MAX * np.clip(act(hl_apply, hl_params, hl_norm, hl_input(obs, layout)), -1.0, 1.0)
    for env, z in zip(envs, skills):
      env.high_level_start(z)
    running = np.ones(episodes, bool)
    low = np.stack([env.agent_state_func(env.state()) for env in envs])
    for _ in range(cls.K):
      if not running.any():
        break
      actions = act(ll_apply, ll_params, ll_norm, low)
      for j in np.flatnonzero(running):
        env = envs[j]
        low[j], _, done = env.low_level_step(env.unscale(actions[j]))
        ll_steps += 1
        if done or env.goal_dist() < EPSILON_LOW:
          running[j] = False
    for j, (env, z) in enumerate(zip(envs, skills)):
      bonus_steps[j] += env.reached_goal
      stale[j] += np.any(env.model.body_pos[env.target][:2] != env.data.xpos[env.target][:2])
      obs[j], r = env.high_level_end(z)
      ret[j] += r
  return dict(return_=float(np.mean(ret)), return_std=float(np.std(ret)),
              waypoints=float(np.mean([env.waypoints for env in envs])),
              bonus_steps=float(np.mean(bonus_steps)), stale_waypoint_obs=float(np.mean(stale)),
              ll_steps_per_hl_step=ll_steps / (episodes * HL_HORIZON))


def lockstep_low(cls, agent, xml, apply, params, norm, seed):
  """One LL episode in both envs from the same start (the rebuild's reset draw copied into hdt's reach
  env), hdt's env driven by the rebuild's actions: largest differences of the LL observation (its
  contact-force part apart) and reward per step (hdt keeps float32 states, so ~1e-5 is agreement).
  Legged robots drift apart over an episode (contacts amplify float32 against float64)."""
  import jax
  import jax.numpy as jnp
  from hdt.envs.registry import make

  env = cls(xml, [seed, 0])
  env.reset_func()
  env.set_skill(env.sample_skill())
  h = make(agent, "reach")
  assert (h.mj_model.nq, h.mj_model.nv) == (env.model.nq, env.model.nv)
  s = h.reset(jax.random.PRNGKey(0))
  ps = h.physics.forward(jnp.float32(0.0), jnp.asarray(env.data.qpos, jnp.float32),
                         jnp.asarray(env.data.qvel, jnp.float32))
  q = h.quantities(ps)
  goal = jnp.asarray(env.low_level_goal, jnp.float32)
  t = {"goal": goal, "z": goal - q["point"]}
  lo, hi, obs = h.observe(ps, q, t)
  s = s.replace(physics=ps, obs=obs, obs_lo=lo, obs_hi=hi, task=dict(s.task, t=t))
  step = jax.jit(h.step)
  ours = env.agent_state_func(env.state())
  nq, nv = env.model.nq - 2, env.model.nv
  forces = np.zeros(ours.shape, bool)
  forces[nq + nv:-2] = True  # clip(cfrc_ext) of the legged robots
  diff = lambda o: np.abs(np.asarray(o) - ours)
  d_obs, d_frc, d_rew = [float(np.max(diff(s.obs)[~forces]))], [float(np.max(diff(s.obs)[forces], initial=0))], []
  for _ in range(cls.LL_HORIZON):
    a = act(apply, params, norm, ours[None])[0]
    ours, r, done = env.low_level_step(env.unscale(a))
    s = step(s, jnp.asarray(a, jnp.float32))
    d_obs.append(float(np.max(diff(s.next_obs)[~forces])))
    d_frc.append(float(np.max(diff(s.next_obs)[forces], initial=0)))
    d_rew.append(abs(float(s.reward) - r))
    if done:
      break
  return dict(max_obs_diff=max(d_obs), max_force_obs_diff=max(d_frc), max_reward_diff=max(d_rew),
              obs_diff_first_10=max(d_obs[:11]), final_goal_dist=float(env.goal_dist()), steps=len(d_rew))


# -- the same numbers from hdt's own env -----------------------------------------------------------
def hdt_numbers(policy, task, episodes, key=1234):
  """hdt.evaluate's computation (same envs, keys and vmap over seeds), every acting.evaluate output
  kept: what ``hdt eval`` prints plus the _final and per-step means it leaves out."""
  import jax
  import jax.numpy as jnp
  from hdt.agents import acting

  n = policy.num_seeds

  def one(params, norm, low_params, low_norm, k):
    if policy.low_card is None:
      env = policy.card.make_env(task)
    else:
      env = policy.low_card.high_env(low_params, task, delta_max=policy.delta_max, low_obs_norm=low_norm,
                                     **policy.card.obs_layout.task_options())
    return acting.evaluate(env, policy.card.policy_fn(norm), params, k, episodes)

  keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.PRNGKey(key), i))(jnp.arange(n))
  out = jax.device_get(jax.jit(jax.vmap(one))(policy.params, policy.obs_norm, policy.low_params,
                                              policy.low_obs_norm, keys))
  out = {k: np.asarray(v) for k, v in out.items()}
  if policy.low_card is None:
    return [dict(success=float(out["success_max"][i]), goal_dist_final=float(out["goal_dist_final"][i]),
                 goal_dist=float(out["goal_dist"][i]), return_=float(out["return"][i])) for i in range(n)]
  # per-HL-step metrics are means over the episode's HL steps: times its length for per-episode sums
  return [dict(return_=float(out["return"][i]), return_std=float(out["return_std"][i]),
               waypoints=float(out["waypoints"][i] * out["length"][i]),
               ll_steps_per_hl_step=float(out["ll_steps"][i])) for i in range(n)]


# -- main ------------------------------------------------------------------------------------------
def check_card(card, **want):
  got = {k: getattr(card, k) for k in want}
  if got != want:
    raise SystemExit(f"{card.source}: this rebuild expects a policy with {want}, the policy has {got}")


def summarize(rows, keys):
  return {k: dict(mean=float(np.mean([r[k] for r in rows])), std=float(np.std([r[k] for r in rows])),
                  per_seed=[r[k] for r in rows]) for k in keys}


def main(argv=None) -> int:
  p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  p.add_argument("repo", help="the authors' repository (checkout or bare mirror)")
  p.add_argument("--agent", default="point", choices=sorted(AUTHORS), help="whose env is rebuilt (the LL's agent)")
  p.add_argument("--low", default="runs/pm_low", help="LL run (reach)")
  p.add_argument("--high", default="runs/pm_waypoint", help="HL run (waypoint) over --low; '' to skip")
  p.add_argument("--params", nargs="+", default=["best", "final"], choices=["best", "final"],
                 help="the LL's parameters evaluated on LL episodes")
  p.add_argument("--episodes", type=int, default=100, help="episodes per seed")
  p.add_argument("--protocols", nargs="+", default=["fresh", "sequential"], choices=["fresh", "sequential"])
  p.add_argument("--json", help=f"output (default {OUT.name}, or authors_envs_AGENT.json beside it)")
  args = p.parse_args(argv)
  cls = AUTHORS[args.agent]
  args.json = args.json or str(OUT if args.agent == "point" else OUT.with_name(f"{OUT.stem}_{args.agent}.json"))

  from hdt.envs.agents import AGENTS
  from hdt.transfer.evaluate import compose, load_policy

  if AGENTS[args.agent].ll_horizon != cls.LL_HORIZON:
    raise SystemExit(f"hdt's {args.agent} has LL episodes of {AGENTS[args.agent].ll_horizon} steps, the rebuild "
                     f"{cls.LL_HORIZON}")

  xml = authors_xml(args.repo, args.agent)
  m = mujoco.MjModel.from_xml_string(xml)
  torso = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "torso")
  result = dict(authors_repo="jhejna/hierarchical_morphology_transfer", agent=args.agent, episodes=args.episodes,
                body=dict(mass=float(m.body_subtreemass[torso]), integrator=mujoco.mjtIntegrator(m.opt.integrator).name,
                          timestep=float(m.opt.timestep), frame_skip=cls.FRAME_SKIP, ll_horizon=cls.LL_HORIZON, k=cls.K,
                          gear=m.actuator_gear[:, 0].tolist()),
                low={}, high=None)
  table = []

  for which in args.params:
    t0 = time.time()
    pol = load_policy(args.low, which)
    check_card(pol.card, agent=args.agent, k=cls.K, delta_max=DELTA_MAX)
    apply = jitted_policy(pol.card)
    ours = {proto: [low_episodes(cls, xml, apply, at(pol.params, i), at(pol.obs_norm, i), args.episodes, 1000 + i, proto)
                    for i in range(pol.num_seeds)] for proto in args.protocols}
    theirs = hdt_numbers(pol, "reach", args.episodes)
    keys = ("success", "goal_dist_final", "goal_dist", "return_")
    lock = [lockstep_low(cls, args.agent, xml, apply, at(pol.params, i), at(pol.obs_norm, i), 3000 + i) for i in range(pol.num_seeds)]
    entry = dict(run=args.low, params=which, hdt=summarize(theirs, keys),
                 authors={proto: summarize(rows, keys + ("falls",)) for proto, rows in ours.items()}, lockstep=lock)
    result["low"][which] = entry
    for k in keys:
      table.append([f"LL {which}: {k.rstrip('_')}", entry["hdt"][k]["mean"]] +
                   [entry["authors"][proto][k]["mean"] for proto in args.protocols])
    print(f"LL {which} done in {time.time() - t0:.0f} s; lockstep episode, largest |obs| / |reward| "
          f"differences per seed: " + ", ".join(f"{x['max_obs_diff']:.1e} / {x['max_reward_diff']:.1e}" for x in lock),
          flush=True)

  if args.high:
    t0 = time.time()
    pol = compose(args.high, args.low)
    check_card(pol.low_card, agent=args.agent, k=cls.K, delta_max=DELTA_MAX)
    if (pol.card.hl_horizon or HL_HORIZON) != HL_HORIZON or pol.delta_max != DELTA_MAX:
      raise SystemExit(f"{args.high}: expected hl_horizon {HL_HORIZON} and a goal box of {DELTA_MAX}")
    check_adapter()
    hl_apply, ll_apply = jitted_policy(pol.card), jitted_policy(pol.low_card)
    layout = pol.card.obs_layout
    ours = [high_episodes(cls, xml, hl_apply, at(pol.params, i), at(pol.obs_norm, i), layout, ll_apply,
                          at(pol.low_params, i), at(pol.low_obs_norm, i), args.episodes, 2000 + i)
            for i in range(pol.num_seeds)]
    theirs = hdt_numbers(pol, "waypoint", args.episodes)
    keys = ("return_", "waypoints", "ll_steps_per_hl_step")
    result["high"] = dict(run=args.high, low_run=args.low, params=pol.card.loaded,
                          low_params=pol.low_card.loaded, hl_layout=layout.to_json(),
                          hdt=summarize(theirs, keys), authors=summarize(ours, keys + ("bonus_steps", "stale_waypoint_obs")))
    for k in keys:
      table.append([f"HL: {k.rstrip('_')}", result["high"]["hdt"][k]["mean"],
                    result["high"]["authors"][k]["mean"]] + [float("nan")] * (len(args.protocols) - 1))
    print(f"HL done in {time.time() - t0:.0f} s", flush=True)

  # acceptance: LL success within 0.05 (fresh starts, hdt's protocol), HL return within 10%
  checks = {}
  for which, e in result["low"].items():
    proto = "fresh" if "fresh" in e["authors"] else args.protocols[0]
    diff = e["authors"][proto]["success"]["mean"] - e["hdt"]["success"]["mean"]
    checks[f"LL {which} success ({proto}) within 0.05"] = dict(diff=diff, ok=abs(diff) <= 0.05)
  if result["high"]:
    h, a = result["high"]["hdt"]["return_"]["mean"], result["high"]["authors"]["return_"]["mean"]
    rel = (a - h) / abs(h)
    checks["HL return within 10%"] = dict(rel_diff=rel, ok=abs(rel) <= 0.10)
  result["checks"] = checks

  head = ["metric (mean over seeds)", "hdt env"] + [f"authors' env ({p})" for p in args.protocols]
  print("| " + " | ".join(head) + " |\n|" + "---|" * len(head))
  for row in table:
    print("| " + " | ".join([row[0]] + ["" if x != x else f"{x:.4g}" for x in row[1:]]) + " |")
  for name, c in checks.items():
    print(f"{'PASS' if c['ok'] else 'FAIL'}: {name} ({', '.join(f'{k} {v:+.4f}' for k, v in c.items() if k != 'ok')})")
  Path(args.json).write_text(json.dumps(result, indent=1) + "\n")
  print(f"written: {args.json}")
  return 0 if all(c["ok"] for c in checks.values()) else 1


if __name__ == "__main__":
  sys.exit(main())
