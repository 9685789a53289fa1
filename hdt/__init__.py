"""hdt: hierarchically decoupled morphological transfer in pure JAX."""

__version__ = "0.1.0"


def _import_mjx_quietly() -> None:
  """mujoco.mjx prints "Failed to import warp ..." to stdout when the optional warp package is
  absent (hdt does not use it): import it once with stdout muted."""
  import contextlib
  import io
  with contextlib.redirect_stdout(io.StringIO()):
    try:
      import mujoco.mjx  # noqa: F401
    except ImportError:
      pass


_import_mjx_quietly()

from hdt import envs  # noqa: E402
from hdt.transfer.evaluate import compose, evaluate, random_actions, trajectory, zero_shot_matrix  # noqa: E402
from hdt.transfer.finetune import finetune_high  # noqa: E402
from hdt.transfer.pipeline import train_full, train_high, train_low  # noqa: E402

__all__ = ["envs", "train_low", "train_high", "train_full", "finetune_high", "compose", "evaluate", "random_actions", "zero_shot_matrix",
           "trajectory"]
