"""Bring your own robot (ROBOTS.md): an AgentSpec from one MJCF file, validated on load."""

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import pytest

import hdt.envs as E
from hdt.envs.robot import RobotError, check_recorded, load_robot, robot_record, short_name
from hdt.envs.spec import XML_DIR

REPO = Path(__file__).resolve().parents[1]
HEXAPOD = REPO / "examples" / "robots" / "hexapod.xml"
ARM5 = REPO / "examples" / "robots" / "arm5.xml"
FAMILY = '<custom><text name="hdt_family" data="{}"/></custom>'


def _with_family(src: Path, family: str, tmp_path: Path, extra: str = "") -> Path:
  """A copy of ``src`` with the hdt_family field (and ``extra`` custom fields) added."""
  text = src.read_text().replace("<worldbody>", FAMILY.format(family).replace(
      "</custom>", extra + "</custom>") + "\n  <worldbody>", 1)
  out = tmp_path / src.name
  out.write_text(text)
  return out


# The ant observes the authors' cfrc_ext on top of the legged family's defaults: one custom field.
CFRC = '<numeric name="hdt_contact_forces" data="1"/>'


@pytest.mark.parametrize("agent,family,extra", [("arm4", "manip", ""), ("ant", "legged", CFRC), ("point", "nav", "")])
def test_registry_robots_from_their_files_get_the_registry_spec(agent, family, extra, tmp_path):
  """Family defaults (and the arms' joint-limit start noise) reproduce the registry's entries, so a
  file-only robot is configured as hdt configures its own robots."""
  spec = load_robot(_with_family(XML_DIR / "agents" / f"{agent}.xml", family, tmp_path, extra))
  ref = E.AGENTS[agent]
  diff = {f.name for f in dataclasses.fields(ref) if getattr(spec, f.name) != getattr(ref, f.name)}
  assert diff == {"name", "xml"}, {f: (getattr(spec, f), getattr(ref, f)) for f in diff}
  assert spec.name == str((tmp_path / f"{agent}.xml").resolve())


def test_example_robots_load_from_a_path():
  hexa, arm = load_robot(HEXAPOD), load_robot(ARM5)
  assert hexa.family == "nav" and hexa.legged and hexa.frame_skip == 5 and hexa.k == 32
  assert hexa.fall_z == (0.2, 1.0) and hexa.qpos_skip == 2
  assert arm.family == "manip" and arm.trig_angles and arm.k == 35 and not arm.legged
  assert len(arm.ll_qpos_noise) == 5 and arm.ll_qpos_noise[1:] == (2.0,) * 4
  assert "hexapod" not in E.AGENTS and "arm5" not in E.AGENTS
  assert E.supported_tasks(str(HEXAPOD)) == ["reach", "waypoint", "maze", "steps"]
  assert E.supported_tasks(ARM5) == ["reach", "push1", "push2", "insert"]
  assert short_name(HEXAPOD) == "hexapod" and short_name("ant") == "ant"


@pytest.mark.parametrize("robot,task,obs_lo,actions", [
    (HEXAPOD, "waypoint", 17 + 18 + 6, 12),  # qpos[2:] + qvel + 6 foot contacts
    (HEXAPOD, "steps", 17 + 18 + 6 + 16, 12),  # + the 16 rangefinders hdt adds
    (ARM5, "push1", 15, 5),  # cos, sin, vel of 5 hinges
])
def test_make_accepts_a_path(robot, task, obs_lo, actions):
  env = E.make(str(robot.relative_to(REPO)) if task == "steps" else robot, task)  # str or Path
  assert env.obs_lo_size == obs_lo and env.action_size == actions
  s = jax.jit(env.reset)(jax.random.PRNGKey(0))
  s = jax.jit(env.step)(s, jnp.zeros(env.action_size))
  assert bool(jnp.all(jnp.isfinite(s.obs)))


BROKEN = [  # ((old, new, ...) edits of arm5.xml, fragment of the one-line error)
    (('<site name="goal_point" pos="0 0 0" size="0.005"/>', ""), "no site named 'goal_point'"),
    (('<framepos name="goal_point" objtype="site" objname="goal_point"/>', ""),
     "no sensor named 'goal_point'"),
    (('<framepos name="goal_point" objtype="site" objname="goal_point"/>',
      '<framepos name="goal_point" objtype="body" objname="root"/>'), "must be <framepos objtype=\"site\""),
    (('<body name="root" pos', '<body name="base_link" pos'), "no body named 'root'"),
    (('data="manip"', 'data="flying"'), "must be one of nav, legged, manip (got 'flying'"),
    (('<text name="hdt_family" data="manip"/>', ""), "hdt_family"),
    (('<text name="hdt_family" data="manip"/>', '<text name="hdt_family" data="legged"/>'),
     "a legged robot needs a <freejoint/> in body 'root'"),
    (('<text name="hdt_family" data="manip"/>',
      '<text name="hdt_family" data="manip"/><numeric name="hdt_framskip" data="3"/>'),
     "unknown numeric field 'hdt_framskip'"),
    (('<text name="hdt_family" data="manip"/>',
      '<text name="hdt_family" data="manip"/><numeric name="hdt_k" data="3.5"/>'),
     "hdt_k must be an integer"),
    (('<text name="hdt_family" data="manip"/>',
      '<text name="hdt_family" data="manip"/><numeric name="hdt_ll_qpos_noise" data="1 1"/>'),
     "has 2 entries but the robot has 5 hinge/slide joints"),
    (('ctrlrange="-0.5 0.5" forcelimited="true" forcerange="-0.1 0.1"/>\n  </actuator>',
      'forcelimited="true" forcerange="-0.1 0.1"/>\n  </actuator>'), "has no ctrlrange"),
    (("<actuator>", "<!--", "</actuator>", "-->"), "no actuator"),  # actuators commented out
    (('<body name="root"', '<body name="root" bogus="1"'), "the MJCF does not load"),
]


def test_validation_errors_are_one_line_and_name_the_convention(tmp_path):
  src = ARM5.read_text()
  for i, (edits, fragment) in enumerate(BROKEN):
    text = src
    for old, new in zip(edits[::2], edits[1::2]):
      assert old in text, old
      text = text.replace(old, new, 1)
    bad = tmp_path / f"bad{i}.xml"
    bad.write_text(text)
    with pytest.raises(RobotError) as e:
      E.make(bad, "reach")
    msg = str(e.value)
    assert fragment in msg and len(msg.splitlines()) == 1 and str(bad.resolve()) in msg, msg
  with pytest.raises(RobotError, match="does not exist"):
    E.make(tmp_path / "nope.xml", "reach")
  with pytest.raises(ValueError, match="valid agents: point, ant.*or a path to a robot MJCF"):
    E.make("spider", "reach")


def test_the_record_finds_the_robot_again_and_refuses_an_edited_one(tmp_path):
  robot = tmp_path / "arm5.xml"
  robot.write_text(ARM5.read_text())
  spec = load_robot(robot)
  rec = robot_record(spec)
  assert rec["robot_xml"] == str(robot.resolve()) and len(rec["robot_sha256"]) == 64
  assert robot_record(E.AGENTS["arm4"]) == {}
  meta = dict(agent=spec.name, **rec)
  check_recorded(meta)
  assert E.make(meta["agent"], "reach").agent == spec
  robot.write_text(ARM5.read_text().replace('gear="100"', 'gear="90"'))
  with pytest.raises(RobotError, match="changed since the run was trained"):
    check_recorded(meta)
  assert load_robot(robot) == spec  # same fields; the model itself is read again (cache key: the hash)
  robot.unlink()
  with pytest.raises(RobotError, match="is gone"):
    check_recorded(meta)


def test_envs_layering():
  """hdt.envs (robot loading included) imports neither the agents, transfer nor the CLI."""
  import ast
  for f in (REPO / "hdt" / "envs").glob("*.py"):
    for node in ast.walk(ast.parse(f.read_text())):
      names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
          [node.module or ""] if isinstance(node, ast.ImportFrom) else []
      assert not [n for n in names if n.startswith(("hdt.agents", "hdt.transfer", "hdt.cli"))], f
