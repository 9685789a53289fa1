"""Morphologies and tasks of the hdt suite: ``make(agent, task, **overrides)``."""

from hdt.envs.agents import AGENTS
from hdt.envs.core import Env, State
from hdt.envs.registry import make, supported_tasks
from hdt.envs.robot import RobotError, agent_spec, load_robot
from hdt.envs.tasks import TASKS

__all__ = ["AGENTS", "TASKS", "Env", "RobotError", "State", "agent_spec", "load_robot", "make",
           "supported_tasks"]
