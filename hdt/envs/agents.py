"""The nine morphologies of SPEC 2, as data."""

from hdt.envs.spec import AgentSpec

_NAV = dict(family="nav", delta_max=4.0, reset_prob=0.1, ctrl_cost=0.5, reach_eps=0.5)
_LEGGED = dict(_NAV, qpos_skip=2, fall_z=(0.2, 1.0), survive_bonus=0.7, k=32, ll_horizon=100)
_MANIP = dict(family="manip", frame_skip=3, k=35, delta_max=0.07, ll_horizon=45, reset_prob=0.25,
              ctrl_cost=0.05, reach_eps=0.01, success_bonus=4.0, init_noise=0.02)

AGENTS: dict[str, AgentSpec] = {
    "point": AgentSpec("point", xml="point.xml", frame_skip=3, k=32, ll_horizon=100, qpos_skip=2,
                       **_NAV),
    "ant": AgentSpec("ant", xml="ant.xml", frame_skip=5, **_LEGGED),
    "ant3": AgentSpec("ant3", xml="ant3.xml", frame_skip=5, **_LEGGED),
    "ant2": AgentSpec("ant2", xml="ant2.xml", frame_skip=5, **_LEGGED),
    "quadruped": AgentSpec("quadruped", xml="quadruped.xml",
                           **dict(_LEGGED, frame_skip=3, k=64, ll_horizon=150, fall_z=(0.15, 0.9))),
    "arm_point": AgentSpec("arm_point", xml="arm_point.xml", qpos_skip=2, **_MANIP),
    "arm2": AgentSpec("arm2", xml="arm2.xml", trig_angles=True, **_MANIP),
    "arm3": AgentSpec("arm3", xml="arm3.xml", trig_angles=True, **_MANIP),
    "arm4": AgentSpec("arm4", xml="arm4.xml", trig_angles=True, **_MANIP),
}
