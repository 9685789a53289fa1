"""hdt's legged bodies against the numbers of the authors' MJCF files (plain MuJoCo, no JAX compile).

Every expected number below was measured on the authors' file named in its comment
(bot_transfer/envs/assets/ of their repository, compiled by MuJoCo 4.0; the robot is their torso and
its descendants: the files' target and highlevel marker spheres are left out). The full comparison,
array by array and in a rollout, is benchmarks/authors_bodies.py (SPEC.md, "Legged bodies against
the authors' files").
"""

import mujoco
import numpy as np
import pytest

from hdt.envs.model import build_model
from hdt.envs.robot import agent_spec
from hdt.envs.spec import XML_DIR
from hdt.envs.tasks import get_task

HINGE, FREE = mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_FREE


def agent_model(name):
  return mujoco.MjModel.from_xml_path(str(XML_DIR / "agents" / f"{name}.xml"))


def robot_bodies(m, root="root"):
  r = m.body(root).id
  return [b for b in range(m.nbody) if m.body_rootid[b] == r]


def colliding_pairs(m):
  """(robot-world, robot-robot) counts of geom pairs MuJoCo's broad-phase filters let through."""
  world = robot = 0
  for g1 in range(m.ngeom):
    for g2 in range(g1 + 1, m.ngeom):
      w1, w2 = m.body_weldid[m.geom_bodyid[g1]], m.body_weldid[m.geom_bodyid[g2]]
      p1, p2 = m.body_weldid[m.body_parentid[w1]], m.body_weldid[m.body_parentid[w2]]
      if w1 == w2 or (w1 and w2 and (w1 == p2 or w2 == p1)):
        continue
      if not (m.geom_contype[g1] & m.geom_conaffinity[g2] or m.geom_contype[g2] & m.geom_conaffinity[g1]):
        continue
      if w1 and w2:
        robot += 1
      else:
        world += 1
  return world, robot


# -- quadruped: quadruped_gather.xml (DeepMind Control's quadruped) ----------------------------

def test_quadruped_mass_and_joints():
  m = agent_model("quadruped")
  bodies = robot_bodies(m)
  # quadruped_gather.xml: torso and descendants 107.11790584007245 kg (the file's 743.81 kg total
  # adds the target and highlevel spheres), torso ellipsoid 67.85840131753953 kg, 17 bodies
  assert m.body_mass[bodies].sum() == pytest.approx(107.11790584007245, rel=1e-12)
  assert m.body_mass[m.body("root").id] == pytest.approx(67.85840131753953, rel=1e-12)
  assert len(bodies) == 17
  # quadruped_gather.xml: 1 free joint + 16 hinges (yaw, pitch, knee, ankle per leg)
  assert list(m.jnt_type) == [FREE] + [HINGE] * 16
  hinge_dofs = m.jnt_dofadr[1:]
  np.testing.assert_array_equal(m.dof_damping[hinge_dofs], 30.0)  # class body: damping 30
  np.testing.assert_array_equal(m.dof_armature[hinge_dofs], 0.01)  # armature .01
  np.testing.assert_allclose(m.jnt_solimp[1:], [[0, 0.99, 0.01, 0.5, 2]] * 16)  # solimplimit 0 .99 .01
  # yaw +-50, pitch -20..60, knee -60..50, ankle -45..55 degrees
  np.testing.assert_allclose(np.degrees(m.jnt_range[1:5]), [[-50, 50], [-20, 60], [-60, 50], [-45, 55]])


def test_quadruped_position_servos_tendons_and_couplings():
  m = agent_model("quadruped")
  # quadruped_gather.xml: 12 general actuators, gain 1000, bias 0 -1000 (affine), filter tau .1
  assert m.nu == 12 and m.na == 12
  np.testing.assert_array_equal(m.actuator_gaintype, mujoco.mjtGain.mjGAIN_FIXED)
  np.testing.assert_array_equal(m.actuator_gainprm[:, 0], 1000.0)
  np.testing.assert_array_equal(m.actuator_biastype, mujoco.mjtBias.mjBIAS_AFFINE)
  np.testing.assert_array_equal(m.actuator_biasprm[:, :3], [[0, -1000, 0]] * 12)
  np.testing.assert_array_equal(m.actuator_dyntype, mujoco.mjtDyn.mjDYN_FILTER)
  np.testing.assert_array_equal(m.actuator_dynprm[:, 0], 0.1)
  # per leg: yaw on its joint (ctrl +-1), lift (-1..1.1) and extend (+-0.8) on tendons
  joint, tendon = mujoco.mjtTrn.mjTRN_JOINT, mujoco.mjtTrn.mjTRN_TENDON
  np.testing.assert_array_equal(m.actuator_trntype, [joint, tendon, tendon] * 4)
  np.testing.assert_allclose(m.actuator_ctrlrange, [[-1, 1], [-1, 1.1], [-0.8, 0.8]] * 4)
  # 12 fixed tendons (4 couplings of 3 joints, 4 extend of 3, 4 lift of 2), 4 tendon equalities
  np.testing.assert_array_equal(m.tendon_num, [3, 3, 3, 3] + [3, 2] * 4)
  assert m.neq == 4 and all(m.eq_type == mujoco.mjtEq.mjEQ_TENDON)
  np.testing.assert_allclose(m.eq_solref, [[0.005, 0.5]] * 4)
  np.testing.assert_allclose(m.eq_solimp, [[0.95, 0.99, 0.01, 0.5, 2]] * 4)


def test_quadruped_contacts_and_options():
  m = agent_model("quadruped")
  assert m.opt.timestep == 0.005 and m.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER
  np.testing.assert_allclose(m.geom_solref, [[0.01, 1]] * m.ngeom)  # top default solref .01 1
  np.testing.assert_allclose(m.geom_solimp, [[0.9, 0.99, 0.003, 0.5, 2]] * m.ngeom)
  np.testing.assert_array_equal(m.geom_condim, 1)  # class body: condim 1
  toes = [m.geom(f"toe_{leg}").id for leg in ("front_left", "front_right", "back_right", "back_left")]
  np.testing.assert_array_equal(m.geom_friction[toes, 0], 1.5)
  # quadruped_gather.xml with its floor: 19 robot-floor and 140 robot-robot geom pairs can collide
  assert colliding_pairs(build_model(agent_spec("quadruped"), get_task("reach"))) == (19, 140)


# -- ants: ant_gather.xml, ant_disabled_gather.xml, ant_2leg_gather.xml ---------------------------

# (mass of torso and descendants, hinge count, actuated joints in order, gear) per file
ANTS = {
    "ant": (0.9108800827073915, 8,  # ant_gather.xml
            ["hip_4", "ankle_4", "hip_1", "ankle_1", "hip_2", "ankle_2", "hip_3", "ankle_3"], 150.0),
    "ant3": (0.9100205536275376, 6,  # ant_disabled_gather.xml: leg 4 rigid, pointing down
             ["hip_1", "ankle_1", "hip_2", "ankle_2", "hip_3", "ankle_3"], 125.0),
    "ant2": (0.9091610245476837, 4,  # ant_2leg_gather.xml: legs 2 and 4 rigid, pointing down
             ["hip_1", "ankle_1", "hip_3", "ankle_3"], 125.0),
}


@pytest.mark.parametrize("agent", list(ANTS))
def test_ant_bodies(agent):
  mass, hinges, actuated, gear = ANTS[agent]
  m = agent_model(agent)
  bodies = robot_bodies(m)
  assert m.body_mass[bodies].sum() == pytest.approx(mass, rel=1e-12)
  # all three files: the same 13 bodies in the same tree (the cfrc_ext rows are read in body order)
  assert [int(m.body_parentid[b]) for b in bodies] == [0, 1, 2, 3, 1, 5, 6, 1, 8, 9, 1, 11, 12]
  assert list(m.jnt_type) == [FREE] + [HINGE] * hinges
  assert [m.joint(m.actuator_trnid[i, 0]).name for i in range(m.nu)] == actuated
  np.testing.assert_array_equal(m.actuator_gear[:, 0], gear)
  np.testing.assert_allclose(m.actuator_ctrlrange, [[-1, 1]] * m.nu)
  assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4 and m.opt.timestep == 0.01
  np.testing.assert_array_equal(m.geom_margin, 0.01)  # default geom margin 0.01
  assert m.jnt_margin[0] == 0.01  # the root joint's margin
  hinge_dofs = m.jnt_dofadr[1:]
  np.testing.assert_array_equal(m.dof_armature[hinge_dofs], 1.0)
  np.testing.assert_array_equal(m.dof_damping[hinge_dofs], 1.0)
  np.testing.assert_array_equal(m.dof_armature[:6], 0.0)
  np.testing.assert_allclose(np.degrees(m.jnt_range[1:3]), [[-30, 30], [30, 70]])
  assert not any(m.sensor(i).name.startswith("touch") for i in range(m.nsensor))


def test_ant_contacts_on_the_plane():
  m = build_model(agent_spec("ant"), get_task("reach"))
  # the composed model runs the agent file's RK4 at 0.01 s (ant_gather.xml), not the scene's defaults
  assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4 and m.opt.timestep == 0.01
  # ant_gather.xml with its floor: the 13 robot geoms against the floor only (robot bits 1/0)
  assert colliding_pairs(m) == (13, 0)
  # the contact margin the authors' MuJoCo 1.50 gave (the larger of robot 0.01 and floor 0.01):
  # 0.01, which MuJoCo 4 (margins add up) gives robot 0.01 + hdt's floor 0
  d = mujoco.MjData(m)
  d.qpos[2] = 0.25 + 0.005  # the torso sphere (r 0.25) 5 mm above the floor
  mujoco.mj_forward(m, d)
  assert d.ncon > 0 and all(c.includemargin == pytest.approx(0.01) for c in d.contact)


def test_ant_gear_switch_is_one_number():
  # ant_gather.xml's gear 150; the paper's text says 125: AgentSpec.gear_scale switches it
  m = build_model(agent_spec("ant").replace(gear_scale=125 / 150), get_task("reach"))
  np.testing.assert_allclose(m.actuator_gear[:, 0], 125.0)
