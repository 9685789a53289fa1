"""hdt's legged bodies against the authors' MJCF files, number by number and in a rollout.

    python benchmarks/authors_bodies.py MIRROR \
        [--agents ant ant3 ant2 quadruped] [--steps 200] [--seed 0] [--json out.json]

The first argument is the authors' repository: a checkout or a bare git mirror (read with
``git show HEAD:...``). Their bot_transfer/envs/assets/<file>.xml is compiled by plain MuJoCo
(``<include>`` elements, visual only in these files, are dropped); hdt's agent is composed with the
plane scene as hdt builds it (``hdt.envs.model.build_model(agent_spec(name), get_task("reach"))``).

Compared, on the robot's subtree (the authors' torso and its descendants against hdt's ``agent/root``
and its descendants, in body order; their target and highlevel bodies are static, massless to the
dynamics and collide with nothing): the options, every per-body, per-joint, per-dof, per-geom,
per-tendon, per-equality and per-actuator array that enters the dynamics, the set of colliding geom
pairs (MuJoCo's filters: same weld, parent-child, contype/conaffinity) and the parameters MuJoCo mixes
for each such contact (condim, friction, margin, gap, solref, solimp). Then a rollout of plain
``mujoco.mj_step`` on both models: the same start (qpos0 plus the authors' reset noise) and the same
uniform random controls held for the authors' frame skip, ``--steps`` env steps; qpos, qvel, act
and the robot's cfrc_ext rows are compared at every env step.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import re
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from hdt.envs.model import build_model  # noqa: E402
from hdt.envs.robot import agent_spec  # noqa: E402
from hdt.envs.tasks import get_task  # noqa: E402

ASSETS = "bot_transfer/envs/assets"
# hdt agent -> (authors' file, frame skip and reset noise of their env class)
AUTHORS = {
    "ant": ("ant_gather.xml", 5, 0.13, 0.13),  # ant.py Ant: frame skip 5, qpos U(+-.13), qvel .13 N(0,1)
    "ant3": ("ant_disabled_gather.xml", 5, 0.13, 0.13),  # ant.py AntDisabled(Ant)
    "ant2": ("ant_2leg_gather.xml", 5, 0.13, 0.13),  # ant.py Ant2Leg(Ant)
    "quadruped": ("quadruped_gather.xml", 3, 0.1, 0.1),  # quadruped.py Quadruped: skip 3, U(+-.1), .1 N(0,1)
}
HDT_ROOT, AUTHORS_ROOT = "agent/root", "torso"

OPTION_FIELDS = ("timestep", "integrator", "gravity", "wind", "magnetic", "density", "viscosity",
                 "impratio", "tolerance", "ls_tolerance", "iterations", "ls_iterations", "cone",
                 "jacobian", "solver", "noslip_iterations", "noslip_tolerance", "o_margin", "o_solref",
                 "o_solimp", "o_friction", "disableflags", "enableflags")
BODY_FIELDS = ("body_mass", "body_inertia", "body_pos", "body_quat", "body_ipos", "body_iquat",
               "body_gravcomp")
JOINT_FIELDS = ("jnt_type", "jnt_pos", "jnt_axis", "jnt_limited", "jnt_range", "jnt_margin",
                "jnt_solref", "jnt_solimp", "jnt_stiffness", "qpos0", "qpos_spring")
DOF_FIELDS = ("dof_damping", "dof_armature", "dof_frictionloss", "dof_solref", "dof_solimp")
GEOM_FIELDS = ("geom_type", "geom_size", "geom_pos", "geom_quat", "geom_contype", "geom_conaffinity",
               "geom_condim", "geom_priority", "geom_friction", "geom_margin", "geom_gap",
               "geom_solref", "geom_solimp", "geom_solmix")
ACT_FIELDS = ("actuator_trntype", "actuator_dyntype", "actuator_gaintype", "actuator_biastype",
              "actuator_dynprm", "actuator_gainprm", "actuator_biasprm", "actuator_gear",
              "actuator_ctrllimited", "actuator_ctrlrange", "actuator_forcelimited",
              "actuator_forcerange", "actuator_actlimited", "actuator_actrange", "actuator_actearly",
              "actuator_cranklength")
TENDON_FIELDS = ("tendon_num", "wrap_prm", "tendon_stiffness", "tendon_damping", "tendon_limited",
                 "tendon_range", "tendon_frictionloss", "tendon_lengthspring")
EQ_FIELDS = ("eq_type", "eq_solref", "eq_solimp", "eq_data", "eq_active0")


# -- loading -------------------------------------------------------------------------------------

def authors_text(repo: str, name: str) -> str:
  path = Path(repo) / ASSETS / name
  if path.is_file():
    return path.read_text()
  return subprocess.run(["git", "-C", repo, "show", f"HEAD:{ASSETS}/{name}"], check=True,
                        capture_output=True, text=True).stdout


def authors_model(repo: str, name: str) -> mujoco.MjModel:
  text = re.sub(r"<include[^>]*/>", "", authors_text(repo, name))  # common/*.xml: visual only
  with tempfile.TemporaryDirectory() as d:
    p = Path(d) / name
    p.write_text(text)
    return mujoco.MjModel.from_xml_path(str(p))


def hdt_model(agent: str) -> mujoco.MjModel:
  return build_model(agent_spec(agent), get_task("reach"))


# -- the robot inside each model ------------------------------------------------------------------

class Robot:
  """Index sets of the robot's subtree in a compiled model (bodies in order, and what hangs on them)."""

  def __init__(self, m: mujoco.MjModel, root: str):
    self.m = m
    r = m.body(root).id
    self.bodies = [b for b in range(m.nbody) if self._under(b, r)]
    bs = set(self.bodies)
    self.joints = [j for j in range(m.njnt) if m.jnt_bodyid[j] in bs]
    self.dofs = [d for d in range(m.nv) if m.dof_bodyid[d] in bs]
    self.geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] in bs]
    self.world_geoms = [g for g in range(m.ngeom) if g not in set(self.geoms)]
    self.qpos = [i for j in self.joints for i in range(m.jnt_qposadr[j], m.jnt_qposadr[j] + _nq(m, j))]

  def _under(self, b, r):
    while b != 0:
      if b == r:
        return True
      b = self.m.body_parentid[b]
    return False

  def select(self, field: str):
    a = np.asarray(getattr(self.m, field))
    for prefix, idx in (("body_", self.bodies), ("jnt_", self.joints), ("qpos", self.qpos),
                        ("dof_", self.dofs), ("geom_", self.geoms)):
      if field.startswith(prefix):
        return a[idx]
    return a


def _nq(m, j):
  return {0: 7, 1: 4, 2: 1, 3: 1}[int(m.jnt_type[j])]


def target_names(m: mujoco.MjModel, prefix: str):
  """Each actuator's transmission target (joint or tendon) by name without the prefix."""
  out = []
  for i in range(m.nu):
    t, obj = int(m.actuator_trntype[i]), int(m.actuator_trnid[i, 0])
    kind = {0: mujoco.mjtObj.mjOBJ_JOINT, 3: mujoco.mjtObj.mjOBJ_TENDON}[t]
    out.append(mujoco.mj_id2name(m, kind, obj).removeprefix(prefix))
  return out


def tendon_joints(m: mujoco.MjModel, prefix: str):
  """Each fixed tendon's (joint name, coefficient) list."""
  out = []
  for t in range(m.ntendon):
    adr, num = m.tendon_adr[t], m.tendon_num[t]
    out.append([(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, int(m.wrap_objid[w])).removeprefix(prefix),
                 float(m.wrap_prm[w])) for w in range(adr, adr + num)])
  return out


# -- contacts ------------------------------------------------------------------------------------

def can_collide(m: mujoco.MjModel, g1: int, g2: int) -> bool:
  """MuJoCo's broad-phase filters for a geom pair (no explicit pairs or excludes in these models)."""
  b1, b2 = m.geom_bodyid[g1], m.geom_bodyid[g2]
  w1, w2 = m.body_weldid[b1], m.body_weldid[b2]
  if w1 == w2:
    return False
  p1, p2 = m.body_weldid[m.body_parentid[w1]], m.body_weldid[m.body_parentid[w2]]
  filterparent = not (m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT)
  if filterparent and w1 != 0 and w2 != 0 and (w1 == p2 or w2 == p1):
    return False
  return bool((m.geom_contype[g1] & m.geom_conaffinity[g2]) or (m.geom_contype[g2] & m.geom_conaffinity[g1]))


def contact_params(m: mujoco.MjModel, g1: int, g2: int, margin_rule=np.add) -> np.ndarray:
  """The parameters MuJoCo gives a contact of g1 and g2 (mj_collideGeoms and mj_contactParam, equal
  priorities, the lower geom id first as the collision driver orders them): condim, friction (5),
  margin, gap, solref (2), solimp (5) as one vector. ``margin_rule``: np.add is this MuJoCo's (the
  geoms' margins and gaps add up), np.maximum the rule of MuJoCo 1.50, which the authors ran."""
  g1, g2 = min(g1, g2), max(g1, g2)
  assert m.geom_priority[g1] == m.geom_priority[g2]
  condim = max(m.geom_condim[g1], m.geom_condim[g2])
  fr = np.maximum(m.geom_friction[g1], m.geom_friction[g2])
  friction = [fr[0], fr[0], fr[1], fr[2], fr[2]]
  margin = margin_rule(m.geom_margin[g1], m.geom_margin[g2])
  gap = margin_rule(m.geom_gap[g1], m.geom_gap[g2])
  w1, w2, eps = m.geom_solmix[g1], m.geom_solmix[g2], mujoco.mjMINVAL
  if w1 >= eps and w2 >= eps:
    mix = w1 / (w1 + w2)
  elif w1 < eps and w2 < eps:
    mix = 0.5
  else:
    mix = 0.0 if w1 < eps else 1.0
  r1, r2 = m.geom_solref[g1], m.geom_solref[g2]
  solref = mix * r1 + (1 - mix) * r2 if (r1[0] > 0 and r2[0] > 0) else np.minimum(r1, r2)
  solimp = mix * m.geom_solimp[g1] + (1 - mix) * m.geom_solimp[g2]
  return np.concatenate([[condim], friction, [margin, gap], solref, solimp])


def contacts(rob: Robot, floor: int, margin_rule=np.add):
  """{(i, j): params} over colliding pairs of the robot's geoms (their index in the robot, 'floor')."""
  m, out = rob.m, {}
  named = [(g, i) for i, g in enumerate(rob.geoms)] + [(floor, "floor")]
  for a in range(len(named)):
    for b in range(a + 1, len(named)):
      (g1, k1), (g2, k2) = named[a], named[b]
      if can_collide(m, g1, g2):
        out[(k1, k2)] = contact_params(m, g1, g2, margin_rule)
  others = [g for g in rob.world_geoms if g != floor]  # must collide with nothing on the robot
  stray = [(g, h) for g in others for h in rob.geoms + [floor] if can_collide(m, g, h)]
  return out, stray


# -- comparison ----------------------------------------------------------------------------------

def diff(a, b) -> float:
  a, b = np.asarray(a, float), np.asarray(b, float)
  if a.shape != b.shape:
    return float("inf")
  return float(np.max(np.abs(a - b))) if a.size else 0.0


def compare_static(agent: str, ma: mujoco.MjModel, mh: mujoco.MjModel):
  ra, rh = Robot(ma, AUTHORS_ROOT), Robot(mh, HDT_ROOT)
  rows = []  # (quantity, authors, hdt, max |difference|)

  def row(name, a, h, d=None):
    rows.append((name, a, h, diff(a, h) if d is None else d))

  row("robot mass (kg)", ra.select("body_mass").sum(), rh.select("body_mass").sum())
  row("bodies", len(ra.bodies), len(rh.bodies))
  row("joints (free, hinge)", _count_types(ra), _count_types(rh))
  row("nq, nv, na", (ma.nq, ma.nv, ma.na), (mh.nq, mh.nv, mh.na))
  row("actuators", ma.nu, mh.nu)
  row("tendons, equalities", (ma.ntendon, ma.neq), (mh.ntendon, mh.neq))
  row("geoms on the robot", len(ra.geoms), len(rh.geoms))
  for f in OPTION_FIELDS:
    row(f"opt.{f}", _short(getattr(ma.opt, f)), _short(getattr(mh.opt, f)))
  for f in BODY_FIELDS + JOINT_FIELDS + DOF_FIELDS + GEOM_FIELDS:
    row(f, "", "", diff(ra.select(f), rh.select(f)))
  for f in ACT_FIELDS + TENDON_FIELDS + EQ_FIELDS:
    row(f, "", "", diff(getattr(ma, f), getattr(mh, f)))
  row("actuator targets", "", "", 0.0 if target_names(ma, "") == target_names(mh, "agent/") else float("inf"))
  row("tendon joints and coefs", "", "",
      0.0 if _tj(tendon_joints(ma, "")) == _tj(tendon_joints(mh, "agent/")) else float("inf"))
  ca, stray_a = contacts(ra, ma.geom("floor").id)
  ch, stray_h = contacts(rh, mh.geom("floor").id)
  self_a = sum(1 for k in ca if "floor" not in k)
  self_h = sum(1 for k in ch if "floor" not in k)
  row("colliding pairs (robot-floor, self)", (len(ca) - self_a, self_a), (len(ch) - self_h, self_h),
      0.0 if set(ca) == set(ch) and not stray_a and not stray_h else float("inf"))
  both = sorted(set(ca) & set(ch), key=str)
  row("contact params of those pairs", "", "", max((diff(ca[k], ch[k]) for k in both), default=0.0))
  fa = [k for k in both if "floor" in k]
  margin = lambda c: sorted({float(c[k][6]) for k in fa})
  row("  robot-floor margin (MuJoCo 4: sum)", margin(ca), margin(ch), diff(margin(ca), margin(ch)))
  ca1, _ = contacts(ra, ma.geom("floor").id, np.maximum)
  ch1, _ = contacts(rh, mh.geom("floor").id, np.maximum)
  row("contact params, MuJoCo 1.50 margin rule", "", "", max((diff(ca1[k], ch1[k]) for k in both), default=0.0))
  row("  robot-floor margin (1.50: larger)", margin(ca1), margin(ch1), diff(margin(ca1), margin(ch1)))
  return rows


def with_max_margin_rule(m: mujoco.MjModel, floor: int) -> mujoco.MjModel:
  """A copy of ``m`` whose contacts get, under this MuJoCo's rule (margins add up), the margins MuJoCo
  1.50 gave them (the larger of the two): the floor's margin set to 0. Exact for these files, where
  every robot geom's margin is at least the floor's and robot-robot pairs have none (checked)."""
  out = copy.copy(m)
  rob = Robot(m, AUTHORS_ROOT)
  before, _ = contacts(rob, floor, np.maximum)
  out.geom_margin[floor] = 0.0
  after, _ = contacts(Robot(out, AUTHORS_ROOT), floor, np.add)
  assert all(diff(before[k], after[k]) == 0 for k in before), "no floor margin gives the 1.50 rule"
  return out


def _count_types(rob):
  t = rob.select("jnt_type")
  return (int(np.sum(t == 0)), int(np.sum(t == 3)))


def _short(v):
  a = np.asarray(v)
  return a.item() if a.size == 1 else tuple(float(x) for x in a)


def _tj(tj):
  return [[(n, round(c, 12)) for n, c in t] for t in tj]


def rollout(m: mujoco.MjModel, rob: Robot, qpos, qvel, ctrls, frame_skip):
  d = mujoco.MjData(m)
  d.qpos[:], d.qvel[:] = qpos, qvel
  mujoco.mj_forward(m, d)
  out = {"qpos": [], "qvel": [], "act": [], "cfrc_ext": [], "ncon": []}
  for u in ctrls:
    d.ctrl[:] = u
    for _ in range(frame_skip):
      mujoco.mj_step(m, d)
    mujoco.mj_rnePostConstraint(m, d)  # cfrc_ext: older MuJoCo filled it in every step, 4.0 on demand
    out["qpos"].append(d.qpos.copy())
    out["qvel"].append(d.qvel.copy())
    out["act"].append(d.act.copy())
    out["cfrc_ext"].append(d.cfrc_ext[rob.bodies].copy())
    out["ncon"].append(d.ncon)
  return {k: np.asarray(v) for k, v in out.items()}


def compare_rollout(agent, ma, mh, steps, seed):
  """hdt's model ``mh`` against the authors' ``ma``: the same start and controls, per env step."""
  _, skip, qnoise, vnoise = AUTHORS[agent]
  ra, rh = Robot(ma, AUTHORS_ROOT), Robot(mh, HDT_ROOT)
  assert ma.nq == mh.nq and ma.nv == mh.nv and ma.nu == mh.nu
  rng = np.random.default_rng(seed)
  qpos = ma.qpos0 + rng.uniform(-qnoise, qnoise, ma.nq)  # the authors' reset_func
  qvel = vnoise * rng.standard_normal(ma.nv)
  lo, hi = ma.actuator_ctrlrange.T
  ctrls = rng.uniform(lo, hi, (steps, ma.nu))
  a = rollout(ma, ra, qpos, qvel, ctrls, skip)
  h = rollout(mh, rh, qpos, qvel, ctrls, skip)
  res = {k: diff(a[k], h[k]) for k in ("qpos", "qvel", "act", "cfrc_ext")}
  res["contacts (authors, hdt)"] = (int(a["ncon"].sum()), int(h["ncon"].sum()))
  res["torso z range"] = (float(a["qpos"][:, 2].min()), float(a["qpos"][:, 2].max()))
  res["bitwise equal qpos"] = bool(np.array_equal(a["qpos"], h["qpos"]))
  return res


def main(argv=None):
  warnings.filterwarnings("ignore", message="Attach conflict")  # build_model sets the agent's options
  p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  p.add_argument("repo", help="the authors' repository (checkout or bare mirror)")
  p.add_argument("--agents", nargs="+", default=list(AUTHORS), choices=list(AUTHORS))
  p.add_argument("--steps", type=int, default=200, help="env steps of the rollout")
  p.add_argument("--seed", type=int, default=0)
  p.add_argument("--json", help="write the numbers here")
  args = p.parse_args(argv)
  report, worst = {}, 0.0
  for agent in args.agents:
    ma, mh = authors_model(args.repo, AUTHORS[agent][0]), hdt_model(agent)
    rows = compare_static(agent, ma, mh)
    rolls = {"authors' file as MuJoCo 4 reads it": compare_rollout(agent, ma, mh, args.steps, args.seed),
             "with MuJoCo 1.50's margin rule": compare_rollout(
                 agent, with_max_margin_rule(ma, ma.geom("floor").id), mh, args.steps, args.seed)}
    print(f"\n== {agent}: hdt xml/agents/{agent}.xml on plane.xml vs the authors' {AUTHORS[agent][0]}")
    print(f"{'quantity':40s} {'authors':>28s} {'hdt':>28s} {'max |diff|':>11s}")
    for name, a, h, d in rows:
      if a == "" and d == 0.0:
        continue  # equal arrays: summarised below
      print(f"{name:40s} {_fmt(a):>28s} {_fmt(h):>28s} {d:11.3g}")
    same = [name for name, a, h, d in rows if a == "" and d == 0.0]
    print(f"{len(same)} further arrays equal (max |diff| 0): {', '.join(same)}")
    print(f"rollout of {args.steps} env steps x frame skip {AUTHORS[agent][1]}, seed {args.seed}, max |diff| "
          "over the trajectory:")
    for name, roll in rolls.items():
      print(f"  {name:36s} " + ", ".join(f"{k} {_fmt(v)}" for k, v in roll.items()))
    report[agent] = {"static": [(n, _js(a), _js(h), d) for n, a, h, d in rows], "rollout": rolls}
    roll = rolls["with MuJoCo 1.50's margin rule"]
    worst = max(worst, roll["qpos"], roll["qvel"])
  if args.json:
    Path(args.json).write_text(json.dumps(report, indent=1, default=str))
  print(f"\nworst qpos/qvel difference over all agents (the authors' margin rule): {worst:.3g}")
  return 0 if worst < 1e-6 else 1


def _fmt(v):
  if isinstance(v, float):
    return f"{v:.10g}"
  if isinstance(v, tuple):
    return "(" + ", ".join(_fmt(x) for x in v) + ")"
  return str(v)


def _js(v):
  return list(v) if isinstance(v, tuple) else v


if __name__ == "__main__":
  sys.exit(main())
