"""Seeds sharded across devices (forced CPU host devices) give the same runs as on one device."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

SCRIPT = """
import json, sys, numpy as np, jax
sys.path.insert(0, {tests!r})
from hdt.agents.sac import SACConfig
from hdt.agents.train import run
if {env!r} == "toy":
    from toy_env import PointGoal; env = PointGoal()
else:
    from hdt.envs import make; env = make("point", "reach")
cfg = SACConfig(hidden_sizes=(16, 16), num_envs=4, steps_per_chunk=50, total_env_steps=400, learning_starts=100,
                num_eval_episodes=2, batch_size=16)
r = run(env, cfg, [0, 1, 2, 3])
print("RESULT", json.dumps(dict(devices=len(jax.devices()), shards=len(r.state.env_steps.sharding.device_set),
      ret=np.asarray(r.history["eval/return"]).tolist(), critic=np.asarray(r.history["critic_loss"]).tolist())))
"""


def _run(env, devices):
  code = SCRIPT.format(tests=str(Path(__file__).parent), env=env)
  e = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}")
  out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=e, timeout=600)
  line = [l for l in out.stdout.splitlines() if l.startswith("RESULT")]
  assert line, out.stderr[-2000:]
  return json.loads(line[0][7:])


@pytest.mark.parametrize("env", ["native"])  # the physics callback runs per shard
def test_seed_axis_sharded_over_two_devices_matches_one(env):
  one, two = _run(env, 1), _run(env, 2)
  assert (one["devices"], one["shards"]) == (1, 1)
  assert (two["devices"], two["shards"]) == (2, 2)
  # Same programs per seed; XLA may fuse differently on the split batch (ulp-level differences).
  np.testing.assert_allclose(two["ret"], one["ret"], rtol=1e-4, atol=1e-3)
  np.testing.assert_allclose(two["critic"], one["critic"], rtol=1e-4, atol=1e-4)
  assert len({round(r[-1], 3) for r in one["ret"]}) == 4  # four different seeds
