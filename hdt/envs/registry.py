"""``make(agent, task, **overrides)``: the one way to build an environment."""

from __future__ import annotations

import dataclasses

from hdt.envs.agents import variant
from hdt.envs.env import AgentTaskEnv
from hdt.envs.robot import agent_spec
from hdt.envs.tasks import TASKS

# Pairs the suite does not define (SPEC 3: the 2-link arm cannot reach the PegInsert slot).
UNSUPPORTED = {("arm2", "insert"): "the 2-link arm cannot reach the PegInsert slot"}


def supported_tasks(agent: str) -> list[str]:
  """Tasks of ``agent`` (a registry name or a robot file, see ``hdt.envs.robot``)."""
  fam = agent_spec(agent).family
  out = []
  for name, cls in TASKS.items():
    t = cls()
    if (not t.family or t.family == fam) and (agent, name) not in UNSUPPORTED:
      out.append(name)
  return out


def make(agent: str, task: str, backend: str = "auto", **overrides) -> AgentTaskEnv:
  """Build ``agent`` on ``task``. ``agent`` is a registry name ("ant") or the path of a robot MJCF
  file (ROBOTS.md), validated on load. ``overrides`` set AgentSpec fields (k, delta_max, frame_skip,
  reset_prob, ...) or Task fields (goal="end", hl_horizon, ...)."""
  spec = agent_spec(agent)
  agent = spec.name
  if task not in TASKS:
    raise ValueError(f"unknown task {task!r}; valid tasks: {', '.join(TASKS)}")
  if task not in supported_tasks(agent):
    why = UNSUPPORTED.get((agent, task), f"{task} is a {TASKS[task]().family} task, {agent} a "
                          f"{spec.family} agent")
    raise ValueError(f"agent {agent!r} cannot run task {task!r} ({why}); tasks for {agent}: "
                     f"{', '.join(supported_tasks(agent))}")
  if "ll_budget" in overrides:  # a training default stored on the agent, not a physics option
    raise ValueError("ll_budget is the LL's training budget, not an env option: set total_env_steps "
                     "(--total-env-steps) instead")
  agent_fields = {f.name for f in dataclasses.fields(spec)}
  task_obj = TASKS[task]()
  task_fields = {f.name for f in dataclasses.fields(task_obj)}
  bad = set(overrides) - agent_fields - task_fields
  if bad:
    raise ValueError(f"unknown override(s) {sorted(bad)} for {agent}/{task}; agent fields: "
                     f"{sorted(agent_fields)}; task fields: {sorted(task_fields)}")
  task_obj = TASKS[task](**{k: v for k, v in overrides.items() if k in task_fields and k not in agent_fields})
  spec = variant(spec, task_obj.agent_variant)  # e.g. the insert PM (agents.VARIANTS), then the overrides
  spec = spec.replace(**{k: v for k, v in overrides.items() if k in agent_fields})
  return AgentTaskEnv(spec, task_obj, backend=backend)
