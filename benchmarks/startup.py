"""Start-up: time to the first training step of an LL run, cold and warm.

    python benchmarks/startup.py [--agents point arm3 ant] [--cold 3] [--warm 2] [--out benchmarks/startup.json]

Each measurement is a fresh process that trains ``hdt.transfer.pipeline.low_stage(agent, cfg)`` with
the persistent compile cache on (as the CLI does, :func:`hdt.cache.enable_compile_cache`), cfg =
``configs.low_config(agent)`` (paper network, batch and buffer) with 8 envs, 8 updates per training
step and 50 training steps per chunk, 3 chunks, 1 seed.

* **cold**: a fresh cache directory (only the native physics library is copied in, so its C++ build
  is not counted): everything is traced, lowered and compiled;
* **warm**: the same cache directory again: the compiled programs are loaded (hdt.cache.compiled_all).

``startup_s`` = time from calling ``train_low`` (env built, programs obtained, params initialised,
the evaluation before training) to the end of the first chunk, minus one steady chunk (the median
chunk-to-chunk interval after it, each with its evaluation): the time before the first training
step. ``import_s`` (``import hdt...``, jax included) is reported beside it and not included.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))


def child(agent: str) -> dict:
  t0 = time.perf_counter()
  from hdt.agents.sharding import use_cpu_cores
  from hdt.cache import enable_compile_cache
  from hdt.transfer import configs, pipeline, runner
  t_import = time.perf_counter() - t0
  use_cpu_cores()  # as the CLI
  enable_compile_cache()
  stamps = []
  cfg = configs.low_config(agent, num_envs=8, updates_per_step=8, steps_per_chunk=50, total_env_steps=3 * 400)
  t_call = time.perf_counter()
  progress = lambda total, quiet, label: lambda step, m: stamps.append(time.perf_counter())
  runner.run_stage(pipeline.low_stage(agent, cfg), runner.RunOptions(seeds=1, quiet=True, progress=progress))
  steady = sorted(b - a for a, b in zip(stamps, stamps[1:]))[len(stamps[1:]) // 2]
  return dict(agent=agent, import_s=t_import, first_chunk_end_s=stamps[0] - t_call, steady_chunk_s=steady,
              startup_s=stamps[0] - t_call - steady)


def main() -> None:
  ap = argparse.ArgumentParser()
  ap.add_argument("--agents", nargs="+", default=["point", "arm3", "ant"])
  ap.add_argument("--cold", type=int, default=3, help="cold runs, each from an empty cache (median reported)")
  ap.add_argument("--warm", type=int, default=2, help="warm runs after the last cold one")
  ap.add_argument("--out", default=os.path.join(HERE, "startup.json"))
  ap.add_argument("--no-results", action="store_true", help="do not update benchmarks/results.json")
  ap.add_argument("--child")
  args = ap.parse_args()
  if args.child:
    print(json.dumps(child(args.child)))
    return
  from hdt.cache import cache_dir
  rows = []
  load_start = os.getloadavg()
  for agent in args.agents:
    for c in range(args.cold):  # each cold run in a fresh cache directory; the warm runs reuse the last
      with tempfile.TemporaryDirectory() as tmp:
        for lib in glob.glob(str(cache_dir() / "native_ffi-*.so")):
          shutil.copy(lib, tmp)
        env = dict(os.environ, HDT_CACHE_DIR=tmp, HDT_AOT_CACHE="1")  # the opt-in loaded programs (hdt.cache.compiled_all)
        env.pop("JAX_COMPILATION_CACHE_DIR", None)
        for i in range(1 + (args.warm if c == args.cold - 1 else 0)):
          out = subprocess.run([sys.executable, __file__, "--child", agent], env=env, capture_output=True,
                               text=True, check=True)
          row = json.loads(out.stdout.strip().splitlines()[-1]) | dict(kind="warm" if i else "cold",
                                                                       load=os.getloadavg()[0])
          rows.append(row)
          print(json.dumps(row), flush=True)
  med = lambda xs: sorted(xs)[len(xs) // 2]
  summary = {a: {k: med([r["startup_s"] for r in rows if r["agent"] == a and r["kind"] == k])
                 for k in ("cold", "warm") if any(r["agent"] == a and r["kind"] == k for r in rows)}
             for a in args.agents}
  result = dict(load_start=load_start, load_end=os.getloadavg(), summary=summary, rows=rows)
  with open(args.out, "w") as f:
    json.dump(result, f, indent=1)
  print(json.dumps(summary, indent=1))
  if "arm3" in summary and not args.no_results:
    sys.path.insert(0, HERE)
    from results import update
    measured = {f"{k}_startup_s_arm3_ll": v for k, v in summary["arm3"].items()}  # --warm 0 keeps the warm key
    update(measured,
           f"benchmarks/startup.py --agents {' '.join(args.agents)} --cold {args.cold} --warm {args.warm}: arm3 LL, 8 envs x 8 "
           f"updates x 50 steps per chunk, time before the first training step (median)")


if __name__ == "__main__":
  main()
