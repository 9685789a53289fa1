"""Several processes through jax.distributed (HDT_DISTRIBUTED=1): each trains its share of the seeds,
process 0 alone writes the run directory, the results equal one process's, and --resume after both
were killed continues exactly. The two-process run is `slow` (3-6 minutes on the 2-core CPU):
``python -m pytest -q -m slow tests/test_distributed.py``."""

import csv
import json
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import jax
import numpy as np
import pytest

from hdt.agents import sharding

TRAIN = ["-m", "hdt.cli", "train", "low", "--agent", "point", "--preset", "smoke", "--seeds", "4"]
TOTAL = 2000  # the smoke preset's LL budget


def _initialize(**env) -> str:
  """What initialize_distributed says in a fresh process (JAX allows it before any JAX operation only)."""
  code = ("from hdt.agents import sharding\ntry:\n  print('RESULT', sharding.initialize_distributed())\n"
          "except ValueError as e:\n  print('ERROR', e)")
  out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=_env(**env))
  return out.stdout.strip() or out.stderr[-2000:]


def test_outside_a_cluster_the_missing_variables_are_named():
  text = _initialize(HDT_DISTRIBUTED="1", JAX_COORDINATOR_ADDRESS="localhost:1")
  assert text.startswith("ERROR HDT_DISTRIBUTED=1 but number of processes must be defined"), text
  assert "set JAX_NUM_PROCESSES, JAX_PROCESS_ID on every process" in text and "\n" not in text
  text = _initialize(HDT_DISTRIBUTED="1", JAX_NUM_PROCESSES="two")
  assert text == "ERROR JAX_NUM_PROCESSES='two': give a whole number (e.g. JAX_NUM_PROCESSES=0)", text
  assert _initialize() == "RESULT False"  # not asked


def test_the_seed_mesh_takes_the_same_devices_from_every_process():
  devices = [SimpleNamespace(process_index=p, id=10 * p + i) for p in range(2) for i in range(2)]
  ids = lambda seeds: [d.id for d in sharding.mesh_devices(devices, seeds, processes=2)]
  assert ids(4) == [0, 1, 10, 11]  # process 0 trains seeds 0, 1; process 1 seeds 2, 3
  assert ids(8) == [0, 1, 10, 11]
  assert ids(2) == [0, 10]  # one device of each
  assert ids(6) == [0, 10]  # 3 seeds per process do not split over its 2 devices
  assert ids(3) == []  # not over 2 processes: every process trains all of them
  assert [d.id for d in sharding.mesh_devices(devices, 3)] == [0, 1, 10]  # one process: as before


def _free_port() -> int:
  with socket.socket() as s:
    s.bind(("localhost", 0))
    return s.getsockname()[1]


def _env(**extra) -> dict:
  """This environment without a device choice (conftest pins 1 device), plus ``extra``."""
  drop = ("XLA_FLAGS", "JAX_NUM_CPU_DEVICES", "HDT_DISTRIBUTED", "JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES",
          "JAX_PROCESS_ID")
  return {k: v for k, v in os.environ.items() if k not in drop} | extra


def _launch(cwds, *args) -> list[subprocess.Popen]:
  """Two processes of one run (2 CPU devices each, so the 4 seeds split over 4 devices), in ``cwds``;
  their output goes to files beside them (a pipe nobody reads could fill and stall them)."""
  port = _free_port()
  procs = []
  for i, cwd in enumerate(cwds):
    out, err = (open(Path(cwd).parent / f"process{i}.{time.time_ns()}.{k}", "w+") for k in ("out", "err"))
    procs.append(subprocess.Popen([sys.executable, *TRAIN, "--out", "run", *args], cwd=cwd, text=True,
                                  stdout=out, stderr=err,
                                  env=_env(JAX_NUM_CPU_DEVICES="2", HDT_DISTRIBUTED="1", JAX_NUM_PROCESSES="2",
                                           JAX_PROCESS_ID=str(i), JAX_COORDINATOR_ADDRESS=f"localhost:{port}")))
    procs[-1].files = (out, err)
  return procs


def _output(p) -> tuple[str, str]:
  p.wait()
  texts = []
  for f in p.files:
    f.seek(0)
    texts.append(f.read())
    f.close()
  return tuple(texts)


def _stop(procs) -> None:
  for p in procs:
    if p.poll() is None:
      p.kill()


def _finish(procs, timeout=900) -> list[tuple[str, str]]:
  """The processes' (stdout, stderr) once all ended; if one fails (or time runs out) the others, which
  would wait for it, are killed."""
  deadline = time.time() + timeout
  while any(p.poll() is None for p in procs) and time.time() < deadline:
    if any(p.poll() not in (None, 0) for p in procs):
      break
    time.sleep(0.2)
  _stop(procs)
  outs = [_output(p) for p in procs]
  for p, (_, err) in zip(procs, outs):
    assert p.returncode == 0, err[-3000:]
  return outs


def _saved_steps(run: Path) -> int:
  try:
    return json.loads((run / "state" / "state.json").read_text())["env_steps"]
  except (OSError, ValueError, KeyError):
    return 0


def _snapshot(path: Path) -> dict:
  """Every entry under ``path`` with its size, mode and modification time (a write changes it)."""
  return {str(p.relative_to(path)): (p.stat().st_size, p.stat().st_mode, p.stat().st_mtime_ns)
          for p in sorted([path, *path.rglob("*")])}


def _metrics(run: Path) -> list[dict]:
  with open(run / "metrics.csv") as f:
    return [{k: v for k, v in row.items() if k != "walltime"} for row in csv.DictReader(f)]


def _params(run: Path, seed: int) -> list[np.ndarray]:
  from hdt.transfer import checkpoint as ckpt
  return [np.asarray(x) for x in jax.tree.leaves(ckpt.load(run, seed)[0])]


@pytest.mark.slow
def test_two_processes_split_the_seeds_write_once_and_resume_exactly(tmp_path):
  # One process over 4 devices: each seed on its own device, as in the two-process run.
  ref = tmp_path / "ref"
  single = subprocess.run([sys.executable, *TRAIN, "--out", str(ref), "--quiet"], text=True, capture_output=True,
                          env=_env(JAX_NUM_CPU_DEVICES="4"), timeout=900)
  assert single.returncode == 0, single.stderr[-3000:]

  # Both processes in one directory, killed once a state past the first saves is on disk.
  a, b = tmp_path / "a", tmp_path / "b"
  a.mkdir()
  procs = _launch([a, a])
  deadline = time.time() + 900
  while _saved_steps(a / "run") < 800 and time.time() < deadline:
    if any(p.poll() is not None for p in procs):  # one failed: stop the other, which waits for it
      _stop(procs)
      pytest.fail("\n".join(_output(p)[1][-3000:] for p in procs))
    time.sleep(0.05)
  _stop(procs)  # SIGKILL
  errs = [_output(p)[1] for p in procs]
  assert 800 <= _saved_steps(a / "run") < TOTAL, "the run ended before it could be killed"
  assert "process 0 of 2 trains seeds 0, 1" in errs[0], errs[0][-3000:]
  assert "process 1 of 2 trains seeds 2, 3" in errs[1], errs[1][-3000:]
  assert not any("in use by" in e for e in errs)  # the lock did not trip
  assert json.loads((a / "run" / ".hdt-run").read_text())["pid"] == procs[0].pid  # process 0 claimed it

  # Resumed with process 1 on a copy of the run (as on a host with its own disk): it only reads.
  shutil.copytree(a, b, symlinks=True)
  before = _snapshot(b / "run")
  (out0, err0), (out1, err1) = _finish(_launch([a, b], "--resume"))
  assert _snapshot(b / "run") == before, "process 1 wrote into its run directory"
  assert "final evaluation" in out0 and "final evaluation" not in out1  # process 0 reports
  assert "low point [####################] 2000/2000" in err0 and "2000/2000" not in err1

  run = a / "run"
  assert json.loads((run / "meta.json").read_text())["seeds"] == [0, 1, 2, 3]
  assert _metrics(run) == _metrics(ref)  # every seed's training and evaluation records, exactly
  for seed in range(4):
    for x, y in zip(_params(run, seed), _params(ref, seed)):
      np.testing.assert_array_equal(x, y)
