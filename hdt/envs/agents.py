"""The nine morphologies of SPEC 2, as data (family defaults in ``hdt.envs.families``)."""

from hdt.envs.families import LEGGED, MANIP, NAV, arm
from hdt.envs.spec import AgentSpec

AGENTS: dict[str, AgentSpec] = {
    "point": AgentSpec("point", xml="point.xml", **NAV),
    # The authors' legged robots observe their clipped cfrc_ext (ant.py Ant.state, quadruped.py);
    # a robot file of the legged family observes its touch sensors unless it sets hdt_contact_forces.
    "ant": AgentSpec("ant", xml="ant.xml", contact_forces=True, **LEGGED),
    "ant3": AgentSpec("ant3", xml="ant3.xml", contact_forces=True, **LEGGED),
    "ant2": AgentSpec("ant2", xml="ant2.xml", contact_forces=True, **LEGGED),
    # quadruped.py Quadruped.reset_func starts as the maze classes (+-0.1, 0.1 N(0, 1)), not as Ant
    "quadruped": AgentSpec("quadruped", xml="quadruped.xml",
                           **dict(LEGGED, frame_skip=3, k=64, ll_horizon=150, fall_z=(0.15, 0.9),
                                  open_noise=(), contact_forces=True)),
    # ReacherPM.reset: every LL episode restarts at (0, 0) +- 0.05, every HL episode at (0.2, 0) +- 0.05.
    "arm_point": AgentSpec("arm_point", xml="arm_point.xml", qpos_skip=2,
                           **dict(MANIP, init_noise=0.05, reset_prob=1.0, ll_qpos_offset=(-0.2, 0.0))),
    # joint0 is unlimited, the others limited as in the MJCF (Reacher.reset_func's RAND_LIMITS)
    "arm2": AgentSpec("arm2", xml="arm2.xml", **arm([None] + [3.0])),
    "arm3": AgentSpec("arm3", xml="arm3.xml", **arm([None] + [2.7] * 2)),
    "arm4": AgentSpec("arm4", xml="arm4.xml", **arm([None] + [2.0] * 3)),
}

# Scene variants: a morphology the authors build differently for one scene. insert.py InsertPM uses
# reacher_insert_pm.xml (gear 125, ctrl +-1, armature 1) and starts HL and LL episodes with +-0.1
# noise (InsertPM.reset); the arms' insert files only add the peg (and the slot wall).
VARIANTS: dict[tuple[str, str], dict] = {
    ("arm_point", "insert"): dict(xml="arm_point_insert.xml", init_noise=0.1),
    # maze.py PointMaze: agent_size 0.5 (the open arena's point mass is 0.4)
    ("point", "maze"): dict(xml="point_maze.xml"),
}


def variant(agent: AgentSpec, name: str) -> AgentSpec:
  """``agent`` as built for the scene variant ``name`` ("" or no entry: unchanged)."""
  return agent.replace(**VARIANTS.get((agent.name, name), {})) if name else agent
