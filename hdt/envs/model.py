"""Compose an agent MJCF with a task scene (and its objects) into one MuJoCo model with MjSpec."""

from __future__ import annotations

import numpy as np
import mujoco

from hdt.envs.spec import XML_DIR, AgentSpec
from hdt.envs.tasks import Task

AGENT_PREFIX = "agent/"


def _add_rangefinders(spec: mujoco.MjSpec, n: int, tilt=0.5, cutoff=4.0, height=0.26):
  """n rays around the torso, tilted down, so a legged agent can see barriers (Steps). They start
  above the torso so they clear the leg roots (a ray begins inside any geom its origin is in)."""
  root = spec.body(AGENT_PREFIX + "root")
  for i in range(n):
    a = 2 * np.pi * i / n
    zaxis = [np.cos(a) * np.cos(tilt), np.sin(a) * np.cos(tilt), -np.sin(tilt)]
    root.add_site(name=f"{AGENT_PREFIX}ray_{i}", pos=[0, 0, height], zaxis=zaxis, size=[0.01] * 3)
    s = spec.add_sensor(name=f"{AGENT_PREFIX}ray_{i}", type=mujoco.mjtSensor.mjSENS_RANGEFINDER,
                        objtype=mujoco.mjtObj.mjOBJ_SITE, objname=f"{AGENT_PREFIX}ray_{i}", cutoff=cutoff)
    s.intprm[0] = 1  # output the distance only


def build_model(agent: AgentSpec, task: Task) -> mujoco.MjModel:
  scene = mujoco.MjSpec.from_file(str(XML_DIR / "scenes" / task.scene(agent)))
  agent_spec = mujoco.MjSpec.from_file(str(agent.xml_path))
  # The agent owns its integration: step and integrator (the authors' files differ per robot).
  scene.option.timestep = agent_spec.option.timestep
  scene.option.integrator = agent_spec.option.integrator
  if agent.gear_scale != 1.0:
    for act in agent_spec.actuators:
      act.gear = [g * agent.gear_scale for g in act.gear]
  for xml, prefix in task.objects:
    scene.attach(mujoco.MjSpec.from_file(str(XML_DIR / "scenes" / xml)), prefix=prefix,
                 frame=scene.worldbody.add_frame())
  scene.attach(agent_spec, prefix=AGENT_PREFIX, frame=scene.worldbody.add_frame())
  # Tools (the peg) mount at the agent's optional ``tool_mount`` site, else at its goal point.
  mount = next((s for s in scene.sites if s.name == AGENT_PREFIX + "tool_mount"), None)
  for xml, prefix in task.tools:
    scene.attach(mujoco.MjSpec.from_file(str(XML_DIR / "scenes" / xml)), prefix=prefix,
                 site=mount or scene.site(AGENT_PREFIX + "goal_point"))
  if task.rangefinders and agent.legged:
    _add_rangefinders(scene, task.rangefinders)
  task.customize(scene)
  return scene.compile()
