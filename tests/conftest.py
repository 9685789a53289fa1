import os

# Compiled XLA programs are cached across test runs (and CI steps) to keep the suite fast.
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", os.path.expanduser("~/.cache/hdt/jax"))
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "1")
# One CPU device per test process, whichever test runs JAX first (the CLI would make one per core, so
# a worker's device count would depend on test order); tests/test_sharding.py runs several in subprocesses.
os.environ.setdefault("JAX_NUM_CPU_DEVICES", "1")

import pytest  # noqa: E402

# Small point-mass runs trained once per test session and shared by the test files that need "a
# trained point LL / HL" (test_transfer, test_align, test_finetune): one training and one set of
# compiled programs instead of one per file. Treat their run directories as read-only; a test that
# needs a run of its own config trains it itself.
POINT_LOW_STEPS = POINT_HIGH_STEPS = 4000


@pytest.fixture(scope="session")
def point_low(tmp_path_factory):
  """A point-mass LL that reaches its goals (4k env steps: goal distance 4.1 -> 0.4)."""
  from hdt.transfer import configs
  from hdt.transfer.pipeline import train_low
  from hdt.transfer.runner import RunOptions
  cfg = configs.low_config("point", total_env_steps=POINT_LOW_STEPS, num_envs=8, updates_per_step=8,
                           steps_per_chunk=125, num_eval_episodes=16)
  out = tmp_path_factory.mktemp("shared") / "point_low"
  return train_low("point", cfg, options=RunOptions(seeds=1, out=out, quiet=True))


@pytest.fixture(scope="session")
def point_high(point_low, tmp_path_factory):
  """A waypoint HL over :func:`point_low` (4k HL decisions)."""
  from hdt.transfer import configs
  from hdt.transfer.pipeline import train_high
  from hdt.transfer.runner import RunOptions
  cfg = configs.high_config("waypoint", total_env_steps=POINT_HIGH_STEPS, num_envs=8, updates_per_step=8,
                            steps_per_chunk=POINT_HIGH_STEPS // 8, num_eval_episodes=8)
  out = tmp_path_factory.mktemp("shared") / "point_high"
  return train_high("waypoint", point_low.run_dir, cfg, options=RunOptions(seeds=1, out=out, quiet=True))
