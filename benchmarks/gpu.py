"""The Ant LL on a GPU with MJX: env steps/s over the number of parallel envs, and time to quality
under the defaults table's accelerator throughput (``hdt.transfer.configs.ACCELERATOR``).

    python benchmarks/gpu.py [--num-envs 512,2000,4096,8192] [--steps 100] [--seeds 1]
        [--eval-every 100000] [--eval-episodes 100] [--max-minutes 60] [--skip-quality]
        [--out benchmarks/gpu.json]

Without a GPU it prints one line saying so and exits 0: nothing is measured (on a CPU, MJX runs
contact-rich scenes 100-200x slower than native MuJoCo; BENCHMARKS.md has the CPU numbers).

Env steps/s: full environment steps of ``hdt.envs.make("ant", "reach", backend="mjx")`` (frame_skip
physics steps each, with rewards, observations and auto-reset) under uniform-random actions, vmapped
over the envs inside one jitted ``lax.scan`` of ``--steps`` steps; the best of 3 timed calls after
the compiling one.

Time to quality: ``hdt.agents.train.run`` on the Ant LL with ``configs.config("low", "paper",
agent="ant", backend="mjx")`` (2000 envs, batch 1024, 64 updates per step, the paper's network and
2.5M-step budget), evaluated every ``--eval-every`` env steps on ``--eval-episodes`` episodes; quality
is the paper's LL success, the share of episodes whose torso comes within the reach radius at some
step (``eval/success_max``), at least 0.95 (as ``benchmarks/time_to_quality.py`` for the ant). The
clock starts before the trainer is built and includes compilation (reported apart as the time to
the first evaluation after training starts) and the evaluations.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

THRESHOLD = 0.95  # the paper's LL quality for the ant (benchmarks/time_to_quality.py, TASKS["ant"])
NO_GPU = ("benchmarks/gpu.py: no GPU visible to JAX (backend {}), nothing measured; run it on a machine with "
          "a CUDA GPU and jax[cuda]")


def env_throughput(num_envs: list[int], steps: int) -> list[dict]:
  import jax
  import jax.numpy as jnp
  from hdt.envs import make

  env = make("ant", "reach", backend="mjx")
  rows = []
  for n in num_envs:
    @jax.jit
    def rollout(key):
      k_reset, k_act = jax.random.split(key)
      state = jax.vmap(env.reset)(jax.random.split(k_reset, n))

      def body(s, k):
        a = jax.random.uniform(k, (n, int(env.action_size)), minval=-1.0, maxval=1.0)
        return jax.vmap(env.step)(s, a), None

      state, _ = jax.lax.scan(body, state, jax.random.split(k_act, steps))
      return jnp.sum(state.reward)

    t0 = time.perf_counter()
    rollout(jax.random.PRNGKey(0)).block_until_ready()
    compile_s = time.perf_counter() - t0
    best = float("inf")
    for i in range(3):
      t0 = time.perf_counter()
      rollout(jax.random.PRNGKey(i + 1)).block_until_ready()
      best = min(best, time.perf_counter() - t0)
    rows.append(dict(num_envs=n, steps=steps, env_steps_per_s=n * steps / best, compile_s=compile_s))
    print(f"ant reach, MJX, {n} envs: {n * steps / best:,.0f} env steps/s (compile {compile_s:.1f} s)", flush=True)
  return rows


class _Reached(Exception):
  pass


def time_to_quality(seeds: int, eval_every: int, eval_episodes: int, max_minutes: float) -> dict:
  import numpy as np
  from hdt.agents.train import make_train, run
  from hdt.envs import make
  from hdt.transfer import configs

  base = configs.config("low", "paper", agent="ant", backend="mjx")
  if eval_every % base.num_envs or base.total_env_steps % eval_every:
    raise SystemExit(f"--eval-every {eval_every}: give a multiple of num_envs={base.num_envs} that divides the "
                     f"budget {base.total_env_steps}, e.g. 100000")
  cfg = configs.config("low", "paper", agent="ant", backend="mjx", steps_per_chunk=eval_every // base.num_envs,
                       num_eval_episodes=eval_episodes)
  t0 = time.perf_counter()
  env = make("ant", "reach", backend="mjx")
  trainer = make_train(env, cfg)
  first, reached, curve = {}, [None] * seeds, []

  def progress(step, metrics):
    now = time.perf_counter() - t0
    first.setdefault("s", now)
    success = np.asarray(metrics.get("eval/success_max", np.full(seeds, np.nan)), float).reshape(-1)
    curve.append(dict(env_steps=step, seconds=now, success=success.tolist()))
    print(f"{step} env steps, {now / 60:.1f} min: success {np.round(success, 3).tolist()}", flush=True)
    for i, s in enumerate(success):
      if reached[i] is None and s >= THRESHOLD:
        reached[i] = dict(env_steps=step, seconds=now)
    if all(r is not None for r in reached) or now > 60 * max_minutes:
      raise _Reached

  try:
    run(env, cfg, seeds, progress_fn=progress, trainer=trainer, eval_at_start=False)
  except _Reached:
    pass
  return dict(config={k: getattr(cfg, k) for k in ("num_envs", "batch_size", "updates_per_step", "learning_starts",
                                                    "total_env_steps", "hidden_sizes", "actor_lr", "value_net")},
              threshold=THRESHOLD, metric="eval/success_max", eval_every=eval_every, eval_episodes=eval_episodes,
              first_evaluation_s=first.get("s"), reached=reached, curve=curve)


def main(argv=None) -> int:
  p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
  p.add_argument("--num-envs", default="512,2000,4096,8192", help="parallel envs to time (comma-separated)")
  p.add_argument("--steps", type=int, default=100, help="env steps per timed rollout")
  p.add_argument("--seeds", type=int, default=1, help="seeds of the time-to-quality run (vmapped)")
  p.add_argument("--eval-every", type=int, default=100_000, help="env steps between evaluations")
  p.add_argument("--eval-episodes", type=int, default=100)
  p.add_argument("--max-minutes", type=float, default=60.0, help="stop the time-to-quality run after this")
  p.add_argument("--skip-quality", action="store_true", help="measure env steps/s only")
  p.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "gpu.json"))
  args = p.parse_args(argv)

  import jax
  if jax.default_backend() != "gpu":
    print(NO_GPU.format(jax.default_backend()))
    return 0
  from hdt.cache import enable_compile_cache
  enable_compile_cache()
  result = dict(device=jax.devices()[0].device_kind, devices=jax.device_count(), jax=jax.__version__,
                host=platform.node(), throughput=env_throughput([int(n) for n in args.num_envs.split(",")], args.steps))
  if not args.skip_quality:
    result["time_to_quality"] = time_to_quality(args.seeds, args.eval_every, args.eval_episodes, args.max_minutes)
  with open(args.out, "w") as f:
    json.dump(result, f, indent=1)
  print(f"wrote {args.out}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
