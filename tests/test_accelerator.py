"""The defaults table's throughput for MJX on a GPU or TPU (configs.ACCELERATOR): applied to the paper
preset only when the backend runs MJX on an accelerator, below the options given, splitting every
paper budget into whole chunks; and benchmarks/gpu.py stops at once without a GPU."""

import os
import subprocess
import sys
from pathlib import Path

import jax
import pytest

from hdt.envs.agents import AGENTS
from hdt.envs.tasks import TASKS
from hdt.transfer import configs

ROOT = Path(__file__).resolve().parents[1]
HL_TASKS = [t for t in TASKS if TASKS[t]().hl_budget]


@pytest.fixture
def gpu(monkeypatch):
  """JAX reporting a GPU (the defaults table only asks jax.default_backend)."""
  monkeypatch.setattr(jax, "default_backend", lambda: "gpu")


def test_on_a_cpu_nothing_changes():
  assert not configs.on_accelerator("auto") and not configs.on_accelerator("mjx")
  assert configs.config("low", "paper", agent="ant", backend="mjx") == configs.config("low", "paper", agent="ant")


def test_mjx_on_a_gpu_gets_thousands_of_envs_a_large_batch_and_several_updates(gpu):
  assert configs.on_accelerator("auto") and configs.on_accelerator("mjx") and not configs.on_accelerator("native")
  ll = configs.config("low", "paper", agent="ant", backend="auto")
  assert (ll.num_envs, ll.batch_size, ll.updates_per_step, ll.learning_starts) == (2000, 1024, 64, 10_000)
  assert ll.total_env_steps == 2_500_000 and ll.num_chunks == configs.ACCELERATOR_EVALS and ll.value_net
  hl = configs.config("high", "paper", task="waypoint", backend="mjx")
  assert (hl.num_envs, hl.batch_size, hl.updates_per_step, hl.num_chunks) == (200, 256, 50, 10)
  assert configs.config("low", "paper", agent="ant", backend="native").num_envs == 1  # native physics: as on a CPU
  assert configs.config("low", "cpu", agent="ant", backend="auto").num_envs == 8  # the CPU presets keep theirs
  assert configs.config("low", "smoke", agent="ant", backend="auto").num_envs == 4


def test_options_given_win_and_short_runs_still_learn(gpu):
  c = configs.config("low", "paper", agent="ant", backend="auto", num_envs=4000, updates_per_step=8)
  assert (c.num_envs, c.updates_per_step, c.batch_size) == (4000, 8, 1024)
  short = configs.config("low", "paper", agent="ant", backend="auto", total_env_steps=40_000)
  assert short.learning_starts == 10_000 and short.num_chunks == 10
  tiny = configs.config("low", "paper", agent="point", backend="auto", total_env_steps=16_000, num_envs=8)
  assert tiny.learning_starts == 8_000  # within the first half


@pytest.mark.parametrize("level", ["low", "full"])
def test_every_paper_budget_splits_into_whole_chunks(gpu, level):
  for agent in AGENTS:
    for task in (HL_TASKS if level == "full" else [None]):
      c = configs.config(level, "paper", agent=agent, task=task, backend="auto")
      assert c.num_envs == 2000 and c.num_chunks == configs.ACCELERATOR_EVALS, (agent, task)
  for task in HL_TASKS:
    for level in ("high", "finetune"):
      c = configs.config(level, "paper", task=task, backend="auto")
      assert c.num_envs == 200 and c.num_chunks == configs.ACCELERATOR_EVALS, (level, task)


def test_stages_without_a_config_and_the_cli_use_them(gpu):
  from hdt import cli
  assert configs.stage_default("low", "auto", "ant") == configs.low_config("ant", **{
      k: v for k, v in configs.config("low", "paper", agent="ant", backend="auto").__dict__.items()
      if k in ("num_envs", "batch_size", "updates_per_step", "learning_starts", "steps_per_chunk")})
  assert configs.stage_default("finetune", "auto", task="push1", hidden_sizes=(64, 64)).num_envs == 200
  args = cli.build_parser().parse_args(["train", "low", "--agent", "ant", "--preset", "paper", "--batch-size", "512"])
  c = cli.sac_config(args, "low", "ant")
  assert (c.num_envs, c.batch_size) == (2000, 512)


def test_the_gpu_benchmark_says_why_it_measures_nothing_without_a_gpu():
  out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "gpu.py")], capture_output=True, text=True,
                       timeout=300, env=dict(os.environ, JAX_PLATFORMS="cpu"))
  assert out.returncode == 0, out.stderr[-2000:]
  assert out.stdout.strip().splitlines() == ["benchmarks/gpu.py: no GPU visible to JAX (backend cpu), nothing "
                                             "measured; run it on a machine with a CUDA GPU and jax[cuda]"]
