"""Seeds sharded across devices (forced CPU host devices) give the same runs as on one device; the CLI
splits the CPU into devices."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hdt.agents.sharding import cpu_cores

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
r = run(env, cfg, {seeds!r})
print("RESULT", json.dumps(dict(devices=len(jax.devices()), shards=len(r.state.env_steps.sharding.device_set),
      ret=np.asarray(r.history["eval/return"]).tolist(), critic=np.asarray(r.history["critic_loss"]).tolist())))
"""


def _env(**extra):
  """This process's environment without a device choice (conftest pins 1), plus ``extra``."""
  return {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "JAX_NUM_CPU_DEVICES")} | extra


def _run(env, devices, seeds=(0, 1, 2, 3)):
  code = SCRIPT.format(tests=str(Path(__file__).parent), env=env, seeds=list(seeds))
  e = _env(XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}")
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


def test_seeds_use_the_most_devices_that_split_them_evenly():
  three = _run("toy", 3, seeds=(0, 1, 2))
  four = _run("toy", 3)
  assert (three["devices"], three["shards"]) == (3, 3)
  assert (four["devices"], four["shards"]) == (3, 2)  # 4 seeds over 2 of the 3 devices


def _devices_after(code, **env):
  out = subprocess.run([sys.executable, "-c", "import jax; from hdt.agents.sharding import use_cpu_cores\n" + code
                        + "\nprint('RESULT', len(jax.devices()))"], capture_output=True, text=True, env=_env(**env),
                       timeout=300)
  return out.returncode, out.stdout


def test_use_cpu_cores_splits_the_cpu_unless_too_late_or_chosen():
  n = cpu_cores()
  assert _devices_after("print(use_cpu_cores())")[1] == f"{n}\nRESULT {n}\n"
  assert _devices_after("jax.numpy.zeros(1); print(use_cpu_cores())")[1] == "None\nRESULT 1\n"
  assert _devices_after("print(use_cpu_cores())", JAX_NUM_CPU_DEVICES="2")[1] == "None\nRESULT 2\n"


def test_cli_trains_seeds_on_separate_cpu_devices(tmp_path):
  code = ("import sys, jax; from hdt.cli import main; r = main(sys.argv[1:]); "
          "print('RESULT', r, len(jax.devices()))")
  out = subprocess.run([sys.executable, "-c", code, "train", "low", "--agent", "point", "--preset", "smoke",
                        "--seeds", "2", "--out", str(tmp_path / "run"), "--quiet"],
                       capture_output=True, text=True, env=_env(), timeout=600)
  assert f"RESULT 0 {cpu_cores()}" in out.stdout, out.stderr[-2000:]


def test_a_run_that_cannot_use_every_device_says_how_to():
  code = "from hdt.transfer.runner import _device_hint as h; h(3, 'low arm3'); h(4, 'low arm3'); h(1, 'one')"
  rc, out = _devices_after(code, JAX_NUM_CPU_DEVICES="2")
  assert rc == 0 and out.splitlines() == [
      "low arm3: 3 runs split over 1 of the 2 devices; 2 or 4 runs would use all of them (or set "
      "JAX_NUM_CPU_DEVICES=3: faster for small-network LLs, slower for HLs; BENCHMARKS.md)", "RESULT 2"]
