"""Bring your own robot: an AgentSpec from one MJCF file, validated on load (ROBOTS.md).

Wherever hdt takes an agent name it also takes a path to an MJCF file that follows the robot
convention: a body ``root``, a site ``goal_point`` and a ``framepos`` sensor ``goal_point`` on it, at
least one actuator with a ``ctrlrange``, and a ``<custom><text name="hdt_family" data="..."/>`` field
("nav", "legged" or "manip"). Every other AgentSpec field is an optional ``<custom>`` numeric
``hdt_<field>``; what is not given comes from the family (``hdt.envs.families``). Such a robot's name
is its resolved path, so a run's metadata finds it again; ``robot_record`` adds the file's hash.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import os
from pathlib import Path

import mujoco

from hdt.envs.agents import AGENTS
from hdt.envs.families import FAMILIES, arm_start_noise
from hdt.envs.spec import AgentSpec

DOC = "ROBOTS.md"
PREFIX = "hdt_"
# AgentSpec fields a robot file may set as <numeric name="hdt_<field>">, with their number of entries
# (None: any) and kind. name, family and xml are not numbers: the name is the path, the family a text.
_INT = ("frame_skip", "k", "ll_horizon", "qpos_skip", "max_ll_episodes", "ll_budget")
_SIZE = {"fall_z": 2, "open_noise": 2, "ll_qpos_noise": None, "ll_qpos_offset": None, "contact_rows": 2}
_BOOL = ("trig_angles", "free_joint_noise", "contact_forces")
NUMERIC_FIELDS = tuple(f.name for f in dataclasses.fields(AgentSpec)
                       if f.name not in ("name", "family", "xml"))
TEXT_FIELDS = ("family",)


class RobotError(ValueError):
  """A robot file that does not follow the convention (one line: what is missing, what is expected)."""


def is_robot_path(agent) -> bool:
  """Whether ``agent`` names a robot file rather than a registry agent."""
  if isinstance(agent, Path):
    return True
  agent = str(agent)
  return agent not in AGENTS and (agent.lower().endswith(".xml") or os.sep in agent or "/" in agent)


def file_sha256(path) -> str:
  return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def agent_spec(agent) -> AgentSpec:
  """The AgentSpec of a registry name (``"ant"``) or of a robot file (``"path/to/robot.xml"``)."""
  if not is_robot_path(agent):
    if agent not in AGENTS:
      raise ValueError(f"unknown agent {agent!r}; valid agents: {', '.join(AGENTS)}, or a path to a "
                       f"robot MJCF file ({DOC})")
    return AGENTS[agent]
  return load_robot(agent)


def load_robot(path) -> AgentSpec:
  """AgentSpec of the robot file ``path``, validated (RobotError names what the convention misses)."""
  p = Path(path).expanduser()
  if not p.is_file():
    raise RobotError(f"robot file {path} does not exist (an agent is a registry name, "
                     f"{', '.join(AGENTS)}, or the path of an MJCF file that follows {DOC})")
  p = p.resolve()
  return _load(str(p), file_sha256(p))


def robot_record(spec: AgentSpec) -> dict:
  """What a run records about its robot: nothing for a registry agent, else the file and its hash."""
  if spec.name in AGENTS:
    return {}
  return {"robot_xml": str(spec.xml_path), "robot_sha256": file_sha256(spec.xml_path)}


def check_recorded(meta: dict) -> None:
  """Refuses a run whose robot file is gone or changed since the run was trained (same hash)."""
  sha = meta.get("robot_sha256")
  if not sha:
    return
  path = Path(meta.get("robot_xml") or meta["agent"])
  if not path.is_file():
    raise RobotError(f"the run's robot file {path} (sha256 {sha[:12]}) is gone: put it back at that "
                     f"path")
  now = file_sha256(path)
  if now != sha:
    raise RobotError(f"the run's robot file {path} changed since the run was trained (sha256 "
                     f"{sha[:12]} then, {now[:12]} now): restore it or train again")


def short_name(agent) -> str:
  """A label for run directories: the registry name, or the robot file's stem."""
  return Path(str(agent)).stem if is_robot_path(agent) else str(agent)


# -- loading -------------------------------------------------------------------------------------

@functools.lru_cache(maxsize=64)
def _load(path: str, sha: str) -> AgentSpec:
  del sha  # part of the cache key only: an edited file is loaded again
  where = f"robot {path}"
  spec = _try(where, mujoco.MjSpec.from_file, path)
  _check_names_exist(where, spec)  # before compiling: a missing site otherwise fails its sensor
  model = _try(where, spec.compile)

  texts = {t.name: t.data for t in spec.texts}
  numerics = {n.name: [float(x) for x in n.data] for n in spec.numerics}
  _check_names(where, texts, numerics)
  family = texts.get(PREFIX + "family", "").strip()
  if family not in FAMILIES:
    got = f"got {family!r}" if family else "it is missing"
    raise RobotError(f"{where}: <custom><text name=\"hdt_family\" data=\"...\"/> must be one of "
                     f"{', '.join(FAMILIES)} ({got}; {DOC})")
  _check_structure(where, model, family)

  joints = [model.joint(j) for j in range(model.njnt)]
  movable = [j for j in joints if int(j.type[0]) in (2, 3)]  # slide, hinge
  fields = dict(FAMILIES[family])
  if family == "manip" and joints and all(int(j.type[0]) == 3 for j in joints):
    # a planar arm: angles as (cos, sin), LL starts at uniform angles in the joint limits
    lims = [max(abs(float(j.range[0])), abs(float(j.range[1]))) if j.limited[0] else None for j in joints]
    fields |= dict(trig_angles=True, ll_qpos_noise=arm_start_noise(lims))
  fields["family"] = "nav" if family == "legged" else family
  for name, values in numerics.items():
    if name.startswith(PREFIX):  # other custom fields are the robot's own
      fields[name[len(PREFIX):]] = _value(where, name[len(PREFIX):], values)
  n = len(fields.get("ll_qpos_noise") or ())
  if n and n != len(movable):
    raise RobotError(f"{where}: hdt_ll_qpos_noise has {n} entries but the robot has {len(movable)} "
                       f"hinge/slide joints (one half-width per joint, in joint order)")
  out = AgentSpec(name=path, xml=path, **fields)
  for f in _INT:
    if getattr(out, f) < (0 if f == "qpos_skip" else 1):
      raise RobotError(f"{where}: hdt_{f} must be {'>= 0' if f == 'qpos_skip' else 'positive'}, "
                       f"got {getattr(out, f)}")
  return out


def _try(where, fn, *args):
  try:
    return fn(*args)
  except Exception as e:  # mujoco raises ValueError with the parser's or compiler's message
    first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
    raise RobotError(f"{where}: the MJCF does not load: {first}") from None


def _check_names_exist(where, spec: mujoco.MjSpec):
  if "root" not in {b.name for b in spec.bodies}:
    raise RobotError(f"{where}: no body named 'root' (the convention: the robot's base body is named "
                     f"root; a nav robot's torso, an arm's first link; {DOC})")
  if "goal_point" not in {s.name for s in spec.sites}:
    raise RobotError(f"{where}: no site named 'goal_point' (the convention: a site at the goal-space "
                     f"point, the torso centre of a nav robot or the fingertip of an arm; {DOC})")
  if "goal_point" not in {s.name for s in spec.sensors}:
    raise RobotError(f"{where}: no sensor named 'goal_point' (the convention: <framepos "
                     f"name=\"goal_point\" objtype=\"site\" objname=\"goal_point\"/>; {DOC})")


def _check_names(where, texts, numerics):
  for name in texts:
    if name.startswith(PREFIX) and name[len(PREFIX):] not in TEXT_FIELDS:
      hint = " (a number: use <numeric>)" if name[len(PREFIX):] in NUMERIC_FIELDS else ""
      raise RobotError(f"{where}: unknown text field {name!r}{hint}; text fields: "
                       f"{', '.join(PREFIX + f for f in TEXT_FIELDS)}")
  for name in numerics:
    if name.startswith(PREFIX) and name[len(PREFIX):] not in NUMERIC_FIELDS:
      hint = " (a word: use <text>)" if name[len(PREFIX):] in TEXT_FIELDS else ""
      raise RobotError(f"{where}: unknown numeric field {name!r}{hint}; numeric fields: "
                       f"{', '.join(PREFIX + f for f in NUMERIC_FIELDS)}")


def _value(where, field, values):
  size = _SIZE.get(field, 1)
  if size is not None and len(values) != size:
    raise RobotError(f"{where}: hdt_{field} takes {size} number(s), got {len(values)}")
  if field in _INT:
    if values[0] != int(values[0]):
      raise RobotError(f"{where}: hdt_{field} must be an integer, got {values[0]:g}")
    return int(values[0])
  if field in _BOOL:
    return bool(values[0])
  if size == 1:
    return float(values[0])
  if field == "contact_rows":
    return tuple(int(v) for v in values)
  return tuple(values)


def _check_structure(where, m: mujoco.MjModel, family: str):
  s = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, "goal_point")
  site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "goal_point")
  if (m.sensor_type[s] != mujoco.mjtSensor.mjSENS_FRAMEPOS or m.sensor_objtype[s] != mujoco.mjtObj.mjOBJ_SITE
      or m.sensor_objid[s] != site or m.sensor_reftype[s] != mujoco.mjtObj.mjOBJ_UNKNOWN):
    raise RobotError(f"{where}: sensor 'goal_point' must be <framepos objtype=\"site\" "
                     f"objname=\"goal_point\"/> in world coordinates (no reftype; {DOC})")
  if m.nu == 0:
    raise RobotError(f"{where}: no actuator (the convention: one actuator per controlled joint, each "
                     f"with a ctrlrange; policies output [-1, 1], mapped onto it; {DOC})")
  for i in range(m.nu):
    lo, hi = m.actuator_ctrlrange[i]
    if not m.actuator_ctrllimited[i] or not lo < hi:
      name = m.actuator(i).name or f"#{i}"
      raise RobotError(f"{where}: actuator {name} has no ctrlrange (the convention: every actuator is "
                       f"ctrllimited, e.g. ctrlrange=\"-1 1\"; {DOC})")
  for i in range(m.nsensor):
    name = m.sensor(i).name
    if name.startswith("touch") and m.sensor_type[i] != mujoco.mjtSensor.mjSENS_TOUCH:
      raise RobotError(f"{where}: sensor {name} is not a <touch> sensor (names starting with 'touch' "
                       f"are read as foot contacts; {DOC})")
    if name.startswith("ray"):
      raise RobotError(f"{where}: sensor {name}: names starting with 'ray' are reserved for the "
                       f"rangefinders hdt adds on Steps ({DOC})")
  root = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "root")
  free = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
  if family == "legged" and not any(m.jnt_bodyid[j] == root for j in free):
    raise RobotError(f"{where}: a legged robot needs a <freejoint/> in body 'root' (its height decides "
                     f"a fall; {DOC})")
  if family != "legged" and free:
    raise RobotError(f"{where}: a free joint makes a robot that can fall: use hdt_family \"legged\" "
                     f"({DOC})")
