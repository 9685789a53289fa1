"""hdt: hierarchically decoupled morphological transfer in pure JAX."""

__version__ = "0.1.0"

from hdt import envs
from hdt.agents.sharding import use_cpu_cores
from hdt.transfer.evaluate import compose, evaluate, random_actions, trajectory, zero_shot_matrix
from hdt.transfer.finetune import finetune_high
from hdt.transfer.pipeline import train_full, train_high, train_low

__all__ = ["envs", "use_cpu_cores", "train_low", "train_high", "train_full", "finetune_high", "compose", "evaluate", "random_actions", "zero_shot_matrix",
           "trajectory"]
