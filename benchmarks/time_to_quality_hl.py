"""Time to quality on a high level: hdt vs SBX on a PM HL over the same frozen LL.

    python benchmarks/time_to_quality_hl.py [--task waypoint|push1] [--seeds 2] [--first-seed 0] [--quick] [--check] [--low-run DIR]
        [--hdt-configs NAME,...] [--vmapped-seeds] [--skip-sbx] [--skip-hdt] [--sbx-max-minutes 3]
        [--hdt-max-minutes 1.5] [--out FILE] [--compile-cache DIR] [--recompute]

The high-level tasks of the time-to-quality benchmark (BENCHMARKS.md, "Time to quality"), next to the LL reach tasks of
``benchmarks/time_to_quality.py``, whose helpers (training loops, first crossings, summaries, table,
results.json update) it imports; the fairness rules are the same.

Two tasks (``--task``, ``TASKS`` below):
- ``waypoint`` (default): the PM Waypoint HL. Frozen LL: a point-mass LL trained once by
  ``hdt.train_low("point", ...)`` with the ``cpu`` preset's budget (20k env steps, 8 envs, one update
  per env step) into ``--low-run DIR`` and reused from there on later invocations (its training is in
  neither clock).
- ``push1``: the paper's quality, the arm_point HL solving BlockPush 1 in >= 90% of episodes, over
  the fixed zoo LL ``zoo:arm_point/low``. The metric is the success rate of the evaluation episodes (an
  episode succeeds if the block reaches its goal at any HL step; the task ends the episode there). Its
  HL env is built the same way; everything below that says "Waypoint" holds for it with "success rate"
  for "return".
Both learners train an HL over the LL's seed-0 policy.

Seeds: each seed trains on its own, and each side's median over seeds is compared. With
``--vmapped-seeds`` each hdt config also trains all the seeds together as one vmapped program (split
over the cores, as the CLI runs seeds) until every seed has reached quality; that wall-clock is
compared with SBX's seeds run one after another (``..._all_seeds`` in results.json).

Task: ``hdt.transfer.pipeline.high_env("waypoint", DIR)``, hdt's HL env: one HL action is a relative
sub-goal in [-1, 1]^2 (times delta_max = 4 m), one HL step is k = 32 LL steps of the frozen
deterministic LL in a ``lax.scan`` and carries the summed Waypoint reward (-0.1 dist per LL step,
+100 per waypoint reached); an episode is 50 HL steps. The HL observes the task's HL features
(``hl_features``: the waypoint relative to the agent). hdt trains on it with its own jitted, vmapped
loop (``make_train``, as ``hdt.train_high`` does). SBX trains on ``make_gym_env(env)``: a one-env
gymnasium wrapper of the SAME env object, ``jax.jit`` of its single-env ``reset`` / ``step``, numpy in
and out, obs = the HL features hdt's SAC sees, reward = the summed task reward, terminated = hdt's
``done`` with discount 0, truncated = ``done`` with discount 1 (the time limit, 50 or 60 HL steps; SB3
bootstraps through it, as hdt does with ``bootstrap_time_limits``; ``--sbx-time-limits terminal``
reports it as terminated instead, the authors' SB2 rule and hdt's default), and after an episode
``reset()`` continues from hdt's auto-reset state, as hdt's training envs do. There is no numpy port of an HL env a reference user
would write instead (the frozen LL is a JAX policy), so SBX pays hdt's own jitted env cost per step
(one dispatch and device-to-host copy per HL step; its LL loop ends at the env's own stopping step,
as the authors' does) plus its own learning. ``--check`` steps hdt's
vmapped env (the one its training loop uses) and the wrapper with the same actions over two episode
boundaries and prints the largest differences of obs, reward and done flags.

Quality (the same code for both): Waypoint defines no success, so the metric is the mean return of
the deterministic policy ``tanh(mean)`` over ``--eval-episodes`` full HL episodes (50 HL steps,
counted up to the first ``done``) from fresh resets with the SAME key for every evaluation of every
run, in hdt's HL env. A run reaches quality at the first evaluation whose mean return is at or above
the threshold. Thresholds: see ``TASK`` (how they were chosen is written there).

Clock, caches, SBX and hdt settings: as in ``benchmarks/time_to_quality.py``. hdt's clock starts
before the HL env is built (which loads the LL checkpoint) and includes init and the chunk compile;
SBX's starts before the gym wrapper and ``SAC(...)`` are built and includes compiling the wrapper's
jitted env reset / step (timed alone too: ``env_compile_s``, printed under the table; cold for the
first seed, from the persistent cache for later ones, like hdt's chunk); the HL env object it wraps
is built before SBX's clock starts (it is also the evaluator's env). SBX: the paper's HL
hyper-parameters ([64,64], lr 3e-4, batch 64, buffer 50k), one env, one gradient update per env
step, ``learning_starts=100``. hdt: ``HDT_CONFIGS`` below (for push1, ``e8_u32_b64_norm``: UTD 4 with
observation normalisation, chosen on seeds 0-2 and measured on held-out seeds 3-5, BENCHMARKS.md "Time to quality").
Writes ``benchmarks/time_to_quality_hl.json`` and the results.json key
``sbx_speedup_pm_waypoint_hl`` (skipped with ``--quick`` or ``--no-results``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time

import jax
import jax.numpy as jnp
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from hdt.agents.sharding import use_cpu_cores  # noqa: E402
from hdt.cache import enable_compile_cache  # noqa: E402
from hdt.transfer import checkpoint as ckpt  # noqa: E402
from hdt.transfer import configs  # noqa: E402
from hdt.transfer import pipeline  # noqa: E402
from hdt.transfer.runner import RunOptions  # noqa: E402

import time_to_quality as ttq  # noqa: E402

# The frozen LL: the cpu preset's point-mass LL (the one `hdt reproduce table1 --preset cpu` trains).
LOW_CONFIG = dict(total_env_steps=configs.CPU_LOW_STEPS["point"], num_envs=8, updates_per_step=8,
                  steps_per_chunk=250, num_eval_episodes=16)
# Thresholds on the mean evaluation return (higher is better), chosen from a pilot run (2026-11-22,
# load ~3, seed 0, 32 eval episodes every 256 HL steps, over the 20k-step LL below): hdt e8_u8_b64
# went -7184 (256 HL steps), -341, 305, 1072 (1,024), then stayed in 1,090-1,518 up to 8,192 (cf.
# the cpu preset's Table 1 HL: 1294 at 6,000); e16_u4_b128 crossed 500 at 2,816 and 1,000 at 3,328 and then stayed
# in 1,098-1,375; SBX seeds 0 / 1 crossed 1,000 at 1,280 / 1,024. 1,000 (about 20 waypoints per
# episode, ~80% of the plateau) is reached by every pilot run and held once reached; 1,200 or more
# lies within the plateau's evaluation-to-evaluation swing, so a run can hover below it by chance.
# The looser 500 marks learning well under way (the untrained HL scores about -7,000: it walks
# away from the waypoints).
# The paper's HL hyper-parameters (configs.high_config, the same for both tasks).
SBX_HL = dict(net_arch=[64, 64], learning_rate=3e-4, batch_size=64, buffer_size=50_000)
TASKS = {
    "waypoint": dict(name="pm_waypoint_hl", low=None, metric="return", threshold=1000.0,
                     extra_thresholds=(500.0,), eval_every=128, max_steps=12_288, sbx=SBX_HL,
                     results_key="sbx_speedup_pm_waypoint_hl", primary_only=False,
                     quick=dict(threshold=-1000.0, extra_thresholds=(), eval_every=128, max_steps=1024)),
    # the paper's quality: >= 90% of episodes solved; 0.5 marks learning well under way. The budget
    # cap is the paper's HL budget. results.json gets a number only if hdt reached 0.9 in every seed.
    "push1": dict(name="pm_push1_hl", low="zoo:arm_point/low", metric="success", threshold=0.9,
                  extra_thresholds=(0.5,), eval_every=2000, max_steps=500_000, sbx=SBX_HL,
                  results_key="sbx_speedup_pm_push1_hl_paper_quality", primary_only=True,
                  quick=dict(threshold=0.5, extra_thresholds=(), eval_every=512, max_steps=2048)),
}
# hdt settings: SACConfig overrides on top of configs.high_config (paper network, lr, batch 64).
HDT_CONFIGS = {
    "e1_u1_b64": dict(num_envs=1, updates_per_step=1, batch_size=64),  # the paper's: SB2's one env, UTD 1
    "e1_u1_b64_btl": dict(num_envs=1, updates_per_step=1, batch_size=64, bootstrap_time_limits=True),
    "e8_u8_b64": dict(num_envs=8, updates_per_step=8, batch_size=64),  # UTD 1, the cpu preset
    "e16_u4_b128": dict(num_envs=16, updates_per_step=4, batch_size=128),  # UTD 1/4
    "e8_u16_b64": dict(num_envs=8, updates_per_step=16, batch_size=64),  # UTD 2
    "e8_u8_b64_norm": dict(num_envs=8, updates_per_step=8, batch_size=64, normalize_observations=True),
    "e8_u16_b64_norm": dict(num_envs=8, updates_per_step=16, batch_size=64, normalize_observations=True),
    # UTD 4: chosen on seeds 0-2 (BENCHMARKS.md, "Time to quality"); UTD 8 and batch 128 cost more than they saved.
    "e8_u32_b64_norm": dict(num_envs=8, updates_per_step=32, batch_size=64, normalize_observations=True),
    # the same bootstrapping through the time limit (hdt's default before it took the authors' terminal ends)
    "e8_u32_b64_norm_btl": dict(num_envs=8, updates_per_step=32, batch_size=64, normalize_observations=True,
                                bootstrap_time_limits=True),
    "e8_u64_b64_norm": dict(num_envs=8, updates_per_step=64, batch_size=64, normalize_observations=True),
    "e8_u32_b128_norm": dict(num_envs=8, updates_per_step=32, batch_size=128, normalize_observations=True),
    "e16_u64_b64_norm": dict(num_envs=16, updates_per_step=64, batch_size=64, normalize_observations=True),
}


# ------------------------------------------------------------------------------------------------
# The frozen LL and the HL env


def ensure_low(low_dir: str, log) -> dict:
  """Trains the point-mass LL into ``low_dir`` unless a finished run (or a zoo entry) is there; returns
  its summary."""
  low_dir = ckpt.zoo_path(low_dir)
  if not os.path.exists(os.path.join(low_dir, "meta.json")):
    log(f"== training the frozen point-mass LL into {low_dir} ({LOW_CONFIG['total_env_steps']} env steps)")
    t = time.perf_counter()
    pipeline.train_low("point", configs.low_config("point", **LOW_CONFIG),
                       options=RunOptions(seeds=[0], out=low_dir, quiet=True))
    log(f"   LL trained in {time.perf_counter() - t:.0f}s (in neither clock)")
  with open(os.path.join(low_dir, "config.json")) as f:
    cfg = json.load(f)
  return dict(dir=ttq.shown_path(low_dir), total_env_steps=cfg["total_env_steps"],
              num_envs=cfg["num_envs"], updates_per_step=cfg["updates_per_step"])


def make_hl_evaluator(env, policy_fn, episodes: int, metric: str = "return"):
  """jitted ``(params) -> metric`` of ``policy_fn(params, obs) -> action`` over ``episodes`` HL
  episodes from the fixed key ``ttq.EVAL_KEY``, each counted to its first done: the mean episode
  return, or (``metric="success"``) the fraction of episodes with a successful HL step."""
  v_reset, v_step = jax.vmap(env.reset), jax.vmap(env.step)
  keys = jax.random.split(jax.random.PRNGKey(ttq.EVAL_KEY), episodes)

  def evaluate(params):
    def step(c, _):
      s, alive, ret, won = c
      s = v_step(s, policy_fn(params, s.obs))
      won = jnp.maximum(won, alive * s.metrics["success"]) if metric == "success" else won
      return (s, alive * (1.0 - s.done), ret + alive * s.reward, won), None

    zeros = jnp.zeros((episodes,))
    c0 = (v_reset(keys), jnp.ones((episodes,)), zeros, zeros)
    (_, _, ret, won), _ = jax.lax.scan(step, c0, None, length=env.horizon)
    return jnp.mean(won if metric == "success" else ret)

  return jax.jit(evaluate)


def make_gym_env(env, seed: int | None = None, terminal_time_limits: bool = False):
  """hdt's HL env ``env`` as a one-env gymnasium env ("HLGymEnv": jitted single-env reset / step,
  numpy in and out; obs / reward / termination rules in the module docstring). With
  ``terminal_time_limits`` a time-limit end is reported as terminated, so SB3 stores it as SB2 did."""
  import gymnasium as gym

  class _HLGymEnv(gym.Env):
    metadata = {"render_modes": []}

    def __init__(self):
      self.hdt_env = env
      self.observation_space = gym.spaces.Box(-np.inf, np.inf, (int(env.observation_size),), np.float32)
      self.action_space = gym.spaces.Box(-1.0, 1.0, (int(env.action_size),), np.float32)

      def step(s, a):
        s = env.step(s, a)
        return s, (s.next_obs, s.reward, s.done, s.discount, s.obs)

      # Compiled ahead of time so that the compile (part of SBX's clock) is also reported alone.
      t = time.perf_counter()
      key = jax.random.PRNGKey(0)
      self._reset = jax.jit(env.reset).lower(key).compile()
      act = jax.ShapeDtypeStruct((int(env.action_size),), jnp.float32)
      self._step = jax.jit(step).lower(jax.eval_shape(env.reset, key), act).compile()
      self.compile_s = time.perf_counter() - t
      self._state, self._after_done = None, None
      if seed is not None:
        self.reset(seed=seed)

    def reset(self, *, seed=None, options=None):
      super().reset(seed=seed)
      if seed is not None or self._state is None:
        key = jax.random.PRNGKey(int(self.np_random.integers(2**31)) if seed is None else seed)
        self._state = self._reset(key)
        self._after_done = None
        return np.asarray(self._state.obs, np.float32), {}
      obs = self._after_done  # hdt's auto-reset state after the finished episode
      self._after_done = None
      return obs, {}

    def step(self, action):
      self._state, out = self._step(self._state, jnp.asarray(action, jnp.float32))
      next_obs, reward, done, discount, obs = jax.device_get(out)
      done = bool(done > 0)
      terminated = done and (terminal_time_limits or bool(discount == 0))
      if done:
        self._after_done = np.asarray(obs, np.float32)
      return np.asarray(next_obs, np.float32), float(reward), terminated, done and not terminated, {}

  return _HLGymEnv()


# ------------------------------------------------------------------------------------------------
# The two learners (training loops shared with the LL benchmark)


def run_hdt(task, low_dir, overrides, seeds, thresholds, eval_every, max_steps, max_seconds, episodes, log):
  """One result per seed of ``seeds``: trained together in one vmapped program if several."""
  t0 = time.perf_counter()
  env = pipeline.high_env(task, low_dir)
  cfg = configs.high_config(task, total_env_steps=max_steps,
                            steps_per_chunk=eval_every // overrides["num_envs"], **overrides)
  metric = TASKS[task]["metric"]
  make_eval = lambda trainer: make_hl_evaluator(env, ttq.hdt_policy_fn(trainer.networks), episodes, metric)
  return ttq.hdt_loop_seeds("hdt HL", env, cfg, seeds, make_eval, thresholds, max_seconds, log, t0,
                            higher=True, metric_name=metric)


def run_sbx(task, low_dir, hp, seed, thresholds, eval_every, max_steps, max_seconds, episodes, log,
            terminal_time_limits=False):
  env = pipeline.high_env(task, low_dir)  # evaluator's env; the gym wrapper (built inside the clock) wraps it too
  t0 = time.perf_counter()
  metric = TASKS[task]["metric"]
  make_eval = lambda act: make_hl_evaluator(env, act, episodes, metric)
  genv = []
  make = lambda: genv.append(make_gym_env(env, seed, terminal_time_limits)) or genv[0]
  res = ttq.sbx_loop("sbx HL", make, hp, seed,
                     make_eval, thresholds, eval_every, max_steps, max_seconds, log, t0, higher=True,
                     metric_name=metric)
  res["terminal_time_limits"] = terminal_time_limits
  res["env_compile_s"] = genv[0].compile_s  # inside SBX's clock: hdt's HL env step, jitted for 1 env
  log(f"    sbx HL seed {seed}: of which compiling the wrapped env's reset/step {genv[0].compile_s:.1f}s")
  return res


def check(task, low_dir, steps=120):
  """hdt's vmapped HL env (as in training) vs the gym wrapper, same start and actions."""
  env = pipeline.high_env(task, low_dir)
  key = 3
  v_reset, v_step = jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))
  s = v_reset(jax.random.PRNGKey(key)[None])
  g = make_gym_env(env)
  o, _ = g.reset(seed=key)
  od = float(np.abs(o - np.asarray(s.obs)[0]).max())
  rd, flags, dones, rng = 0.0, 0, 0, np.random.default_rng(0)
  for _ in range(steps):
    a = rng.uniform(-1, 1, env.action_size).astype(np.float32)
    s = v_step(s, jnp.asarray(a)[None])
    o, r, term, trunc, _ = g.step(a)
    od = max(od, float(np.abs(o - np.asarray(s.next_obs)[0]).max()))
    rd = max(rd, abs(r - float(s.reward[0])))
    done = bool(s.done[0] > 0)
    flags += (term or trunc) != done or term != (done and float(s.discount[0]) == 0)
    if term or trunc:
      dones += 1
      o, _ = g.reset()
      od = max(od, float(np.abs(o - np.asarray(s.obs)[0]).max()))
  print(f"{TASKS[task]['name']}: hdt (vmapped) vs gym wrapper over {steps} random HL steps ({dones} episode ends): "
        f"max |obs diff| {od:.2e}, max |reward diff| {rd:.2e}, done-flag mismatches {flags}")


def env_cost(task, low_dir, num_envs=8, steps=200):
  """Seconds per HL decision of the env alone: hdt's vmapped step over ``num_envs`` envs (one call per
  training step) and the gym wrapper's single-env step that SBX calls per decision (random actions,
  after a warm-up call). A lower bound on either learner's time per decision."""
  env = pipeline.high_env(task, low_dir)
  v_step = jax.jit(jax.vmap(env.step))
  s = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), num_envs))
  rng = np.random.default_rng(0)
  acts = [jnp.asarray(rng.uniform(-1, 1, (num_envs, env.action_size)), jnp.float32) for _ in range(steps)]
  s = jax.block_until_ready(v_step(s, acts[0]))
  t = time.perf_counter()
  for a in acts:
    s = v_step(s, a)
  jax.block_until_ready(s)
  vm = (time.perf_counter() - t) / (steps * num_envs)
  ll = np.array([np.asarray(v_step(s, a).metrics["ll_steps"]) for a in acts[:50]])  # untimed
  g = make_gym_env(env, seed=0)
  g.step(np.zeros(env.action_size, np.float32))
  t = time.perf_counter()
  for _ in range(steps):
    _, _, term, trunc, _ = g.step(rng.uniform(-1, 1, env.action_size).astype(np.float32))
    if term or trunc:
      g.reset()
  one = (time.perf_counter() - t) / steps
  print(f"{TASKS[task]['name']} over {low_dir}: env alone per HL decision: hdt vmapped x{num_envs} "
        f"{1e3 * vm:.2f} ms, gym wrapper (SBX) {1e3 * one:.2f} ms, ratio {one / vm:.1f}x; LL steps per "
        f"decision mean {ll.mean():.1f}, max of {num_envs} envs {ll.max(1).mean():.1f} of {env.k} (load {ttq.load()})")
  return dict(hdt_vmapped_s=vm, gym_single_s=one, num_envs=num_envs)


# ------------------------------------------------------------------------------------------------


def merge_seeds(old: list[dict], new: list[dict]) -> list[dict]:
  """The runs of an earlier invocation (``--first-seed``) with this one's, a seed run now replacing
  the same seed run before."""
  seeds = {r["seed"] for r in new}
  return sorted([r for r in old if r["seed"] not in seeds] + new, key=lambda r: r["seed"])


def join_earlier(res: dict, old: dict, skip_sbx: bool, skip_hdt: bool) -> None:
  """Completes ``res`` (in place) from ``old``, the same task's row of an earlier invocation: a
  skipped half is taken from it, and the half run now joins its runs there (:func:`merge_seeds`)."""
  if skip_sbx:
    res["sbx"] = old.get("sbx") or res["sbx"]
    for name, h in res["hdt"].items():
      h["runs"] = merge_seeds(old.get("hdt", {}).get(name, {}).get("runs", []), h["runs"])
    res["hdt"] = {**old.get("hdt", {}), **res["hdt"]}  # configs not run now stay
  if skip_hdt:
    res["hdt"] = old.get("hdt", {})
    if res["sbx"]:
      res["sbx"]["runs"] = merge_seeds((old.get("sbx") or {}).get("runs", []), res["sbx"]["runs"])


def main():
  use_cpu_cores()  # as the CLI: one JAX device per core, so vmapped seeds split over the cores
  ap = argparse.ArgumentParser()
  ttq.add_run_args(ap, hdt_configs=HDT_CONFIGS, seeds=2, sbx_minutes=3.0, hdt_minutes=1.5, episodes=32)
  ap.add_argument("--task", choices=sorted(TASKS), default="waypoint", help="the HL task (module docstring)")
  ap.add_argument("--first-seed", type=int, default=0,
                  help="run seeds first..first+seeds-1; with --skip-hdt (--skip-sbx) they join the SBX (hdt) "
                       "runs already in --out, replacing any run of the same seed")
  ap.add_argument("--sbx-time-limits", choices=("truncated", "terminal"), default="truncated",
                  help="how SBX stores a time-limit end: truncated (SB3 bootstraps through it) or terminal "
                       "(no bootstrap, as SB2 and hdt's default)")
  ap.add_argument("--threshold", type=float, help="override the threshold (mean return or success rate)")
  ap.add_argument("--extra-thresholds", help="override the extra thresholds (comma-separated)")
  ap.add_argument("--eval-every", type=int, help="override the evaluation period (HL env steps)")
  ap.add_argument("--max-steps", type=int, help="override the HL env-step cap per seed")
  ap.add_argument("--low-run", help="the frozen LL: a run dir or zoo name (default: waypoint's point LL, "
                  "trained into a temp dir if missing; push1's zoo:arm_point/low)")
  ap.add_argument("--recompute", action="store_true",
                  help="recompute the comparison and table from --out (no training)")
  ap.add_argument("--check", action="store_true", help="only compare hdt's HL env and the gym wrapper")
  ap.add_argument("--env-cost", action="store_true", help="only time the env alone per HL decision, "
                  "hdt's vmapped step and the gym wrapper's")
  ap.add_argument("--out", help="JSON to write (default benchmarks/time_to_quality_hl.json, "
                  "..._hl_push1.json for push1; with --quick a temp file)")
  ap.add_argument("--no-results", action="store_true", help="do not update benchmarks/results.json")
  ap.add_argument("--compile-cache", help="JAX compilation cache dir (default: a fresh temp dir)")
  args = ap.parse_args()

  def log(msg):
    print(msg, flush=True)

  source = "benchmarks/time_to_quality_hl.py"
  spec = TASKS[args.task]
  suffix = "" if args.task == "waypoint" else f"_{args.task}"
  if args.out is None:
    args.out = (os.path.join(tempfile.gettempdir(), f"time_to_quality_hl{suffix}_quick.json") if args.quick
                else os.path.join(HERE, f"time_to_quality_hl{suffix}.json"))
  if args.low_run is None:
    args.low_run = spec["low"] or os.path.join(tempfile.gettempdir(), "hdt-ttq-hl", "low_point")
  if args.recompute:
    with open(args.out) as f:
      out = json.load(f)
    for r in out["agents"].values():
      r["by_threshold"] = ttq.compare(r, r["thresholds"])
    with open(args.out, "w") as f:
      json.dump(out, f, indent=1)
    ttq.print_table(out)
    if not args.no_results:
      ttq.update_results(out, source)
    return
  args.compile_cache = str(enable_compile_cache(args.compile_cache or tempfile.mkdtemp(prefix="hdt-ttq-hl-")))
  low = ensure_low(args.low_run, log)
  if args.check:
    check(args.task, args.low_run)
    return
  if args.env_cost:
    env_cost(args.task, args.low_run)
    return

  task = dict(spec, **(spec["quick"] if args.quick else {}))
  for k in ("threshold", "eval_every", "max_steps"):
    if getattr(args, k) is not None:
      task[k] = getattr(args, k)
  if args.extra_thresholds is not None:
    task["extra_thresholds"] = tuple(float(t) for t in args.extra_thresholds.split(",") if t)
  elif args.threshold is not None:
    task["extra_thresholds"] = ()
  thr, every, cap = task["threshold"], task["eval_every"], task["max_steps"]
  thrs = [thr, *task["extra_thresholds"]]
  seeds = list(range(args.first_seed, args.first_seed + (1 if args.quick else args.seeds)))
  hdt_names = args.hdt_configs.split(",")[:1] if args.quick else args.hdt_configs.split(",")

  out = dict(machine=dict(platform=platform.platform(), cpus=os.cpu_count(), jax=jax.__version__,
                          load_start=ttq.load()), args=ttq.shown_args(args), low=low, agents={})
  res = dict(threshold=thr, thresholds=thrs, eval_every=every, max_steps=cap,
             eval_episodes=args.eval_episodes, sbx_hyper=task["sbx"], hdt={}, sbx=None,
             higher=True, unit="", metric=f"eval {task['metric']} ", results_key=task["results_key"],
             primary_only=task["primary_only"])
  log(f"== PM {args.task} HL over {low['dir']}: quality = eval {task['metric']} >= {thrs} (load {ttq.load()})")
  if not args.skip_hdt:
    res["hdt"] = ttq.hdt_rows(HDT_CONFIGS, hdt_names, lambda ov, ss: run_hdt(
        args.task, args.low_run, ov, ss, thrs, every, cap, 60 * args.hdt_max_minutes, args.eval_episodes, log),
        seeds, args.vmapped_seeds)
  if not args.skip_sbx:
    runs = [run_sbx(args.task, args.low_run, task["sbx"], s, thrs, every, cap, 60 * args.sbx_max_minutes,
                    args.eval_episodes, log, args.sbx_time_limits == "terminal") for s in seeds]
    res["sbx"] = dict(runs=runs)
  if os.path.exists(args.out) and (args.skip_sbx or args.skip_hdt):  # merge with the other half
    with open(args.out) as f:
      old = json.load(f).get("agents", {}).get(task["name"], {})
    join_earlier(res, old, args.skip_sbx, args.skip_hdt)
  res["by_threshold"] = ttq.compare(res, thrs)
  out["agents"][task["name"]] = res
  out["machine"]["load_end"] = ttq.load()
  with open(args.out, "w") as f:
    json.dump(out, f, indent=1)
  ttq.print_table(out)
  if res["sbx"] and "env_compile_s" in res["sbx"]["runs"][0]:
    env_c = ", ".join(f"{r['env_compile_s']:.1f}" for r in res["sbx"]["runs"])
    print(f"  (SBX's times include compiling the wrapped hdt HL env's single-env reset/step: "
          f"{env_c} s per seed)")
  if not args.quick and not args.no_results:
    ttq.update_results(out, source)


if __name__ == "__main__":
  main()
