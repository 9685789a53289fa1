"""Time to quality: hdt vs SBX (stable-baselines-jax SAC) on the same LL reach task and threshold.

    python benchmarks/time_to_quality.py [--agents point,arm3] [--seeds 3] [--quick]
        [--hdt-configs NAME,...] [--skip-sbx] [--skip-hdt] [--sbx-max-minutes 25] [--out FILE]
        [--compile-cache DIR]

Task: ``hdt.envs.make(agent, "reach")`` (LL goal reaching). SBX trains on ``gym_reach.ReachGymEnv``,
a one-env gymnasium port of the same task (same compiled MjModel, obs, reward, goal sampling and
reset rules; checked step by step against hdt with ``--check``), stepping ``mujoco.MjData`` in
numpy, as a reference user would. hdt trains with its own jitted, vmapped loop.

Quality (the same code for both): the policy's deterministic action ``tanh(mean)`` is rolled out in
hdt's env for ``--eval-episodes`` episodes of the LL horizon from fresh resets, with the SAME key
every time (same start states and goals for every evaluation of every run), and the metric is the
mean goal distance at the episode's last step (``--metric success``: the share of episodes within the
agent's reach radius at some step, the authors' LL success; a run then passes at or above the threshold;
the ant's default, ``TASKS``). A run reaches quality at the first evaluation whose
metric is below the agent's threshold; evaluations happen every ``eval_every`` env steps (per
seed) for both, and their time is excluded from both clocks.

Clock: starts before the agent is built (SBX: ``SAC(...)``; hdt: ``make_train`` + ``init``) and
includes JIT compilation for both; hdt's compile time is also reported separately. Both sides cache
compiled programs as their users would: SBX in-process (its jitted functions are module-level), hdt in
JAX's persistent compilation cache, in a fresh directory per invocation unless ``--compile-cache DIR``
is given. So for both the first seed compiles cold and later seeds reuse; each run records which.

SBX: the paper's hyper-parameters, one env, one gradient update per env step (SB3 defaults
``train_freq=1, gradient_steps=1``, ``learning_starts=100``, ``ent_coef="auto"``).
hdt: several parallel-env / updates-per-step / batch settings (``HDT_CONFIGS``); every seed runs
on its own (seeds=[s]); the best setting is the one with the lowest median time.

SIGTERM ends the run in progress after its next evaluation and writes the results so far, that run
marked ``stopped`` (for curves longer than a session; later seeds are not started). With
``--sbx-keep DIR`` a stopped SBX run also saves its model and replay buffer there, and ``--resume``
continues it (its clock the sum of its parts).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import signal
import sys
import tempfile
import time

import jax
import jax.numpy as jnp
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from hdt import atomic  # noqa: E402
from hdt.agents import networks as nets  # noqa: E402
from hdt.cache import enable_compile_cache  # noqa: E402
from hdt.agents.sharding import use_cpu_cores  # noqa: E402
from hdt.agents.train import make_train, seed_indices, seed_keys, vmapped  # noqa: E402
from hdt.envs import make  # noqa: E402
from hdt.transfer import configs  # noqa: E402

import results as results_lib  # noqa: E402

# Per agent: threshold on the mean final goal distance (m), evaluation period (env steps per
# seed), step cap, the paper's SBX hyper-parameters.
TASKS = {
    "point": dict(threshold=0.5, extra_thresholds=(0.2, 0.1), eval_every=256, max_steps=100_352,
                  sbx=dict(net_arch=[64, 64], learning_rate=3e-4, batch_size=64, buffer_size=200_000)),
    "arm3": dict(threshold=0.05, extra_thresholds=(0.1,), eval_every=2048, max_steps=401_408,
                 sbx=dict(net_arch=[128, 96], learning_rate=3e-4, batch_size=100, buffer_size=250_000)),
    # The paper's LL quality: the share of episodes whose torso gets within epsilon_low = 0.27 m
    # (bot_transfer/envs/ant.py, Ant.__init__; the agent's reach radius) at some step, at least 0.95.
    # Not a final distance: the authors' LL episodes do not stop at the goal.
    "ant": dict(metric="success", threshold=0.95, extra_thresholds=(0.9, 0.5), eval_every=8192,
                max_steps=2_506_752,  # 306 x 8192
                sbx=dict(net_arch=[400, 300], learning_rate=8e-4, batch_size=100, buffer_size=1_000_000)),
}
QUICK = {"point": dict(threshold=1.5, extra_thresholds=(), eval_every=1024, max_steps=8192),
         "arm3": dict(threshold=0.1, extra_thresholds=(), eval_every=4096, max_steps=16384),
         "ant": dict(metric="dist", threshold=3.0, extra_thresholds=(), eval_every=4096, max_steps=16384)}

# hdt settings to try: name -> SACConfig overrides on top of configs.low_config(agent). The paper's
# network and learning rate stay; what changes is parallel envs, updates per step and batch.
HDT_CONFIGS = {
    "e8_u8_b64": dict(num_envs=8, updates_per_step=8, batch_size=64),  # UTD 1, the cpu preset
    "e16_u4_b128": dict(num_envs=16, updates_per_step=4, batch_size=128),  # UTD 1/4
    "e16_u4_b256": dict(num_envs=16, updates_per_step=4, batch_size=256),  # UTD 1/4
    "e16_u2_b256": dict(num_envs=16, updates_per_step=2, batch_size=256),  # UTD 1/8
    "e8_u8_b64_norm": dict(num_envs=8, updates_per_step=8, batch_size=64, normalize_observations=True),
    # --preset paper: SB2's SAC (state-value net), the paper's batch, one update per env step
    "paper": dict(num_envs=8, updates_per_step=8, value_net=True),
    # sample-efficient options: LayerNorm critics at a higher learning rate, twin-min Q, time limits
    # bootstrapped, a smaller network and a larger batch
    "ln256_u1": dict(num_envs=8, updates_per_step=8, batch_size=128, hidden_sizes=(256, 256),
                     critic_layer_norm=True, bootstrap_time_limits=True, actor_lr=1e-3, critic_lr=1e-3,
                     alpha_lr=1e-3),
}
EVAL_KEY = 20260  # same evaluation episodes for every run
VMAPPED = "_vmapped"  # suffix of a config's name when its seeds train as one vmapped program
_cache_hits = []
# SIGTERM ends a long measurement after its next evaluation, with the curve so far written out.
_stopped = []
jax.monitoring.register_event_listener(
    lambda event, **kw: _cache_hits.append(event) if event == "/jax/compilation_cache/cache_hits" else None)


def load():
  return round(os.getloadavg()[0], 2)


# ------------------------------------------------------------------------------------------------
# The one evaluator both frameworks go through.


def make_evaluator(env, policy_fn, episodes: int, metric: str = "dist"):
  """jitted ``(params) -> mean final goal distance`` of ``policy_fn(params, obs) -> action``; with
  ``metric="success"``, the share of episodes within the agent's reach radius at some step (what
  ``hdt eval`` reports as an LL's success)."""
  v_reset, v_step = jax.vmap(env.reset), jax.vmap(env.step)
  keys = jax.random.split(jax.random.PRNGKey(EVAL_KEY), episodes)

  def evaluate(params):
    s0 = v_reset(keys)

    def step(s, _):
      s = v_step(s, policy_fn(params, s.obs))
      return s, s.metrics["goal_dist"]

    _, dist = jax.lax.scan(step, s0, None, length=env.horizon)
    if metric == "success":
      return jnp.mean(jnp.any(dist < env.agent.reach_eps, axis=0))
    return jnp.mean(dist[-1])  # reach never ends early: the last step is the episode's last

  return jax.jit(evaluate)


def hdt_policy_fn(networks):
  """``(params, obs) -> action``; params: (the policy's, its observation statistics or None)."""
  def act(params, obs):
    policy_params, obs_norm = params
    return nets.deterministic_action(networks.policy_apply(policy_params, obs, obs_norm)[0])
  return act


# ------------------------------------------------------------------------------------------------
# hdt


def passes(metric, thr, higher=False):
  """Quality reached: metric below thr (distances) or, with ``higher``, at or above it (returns)."""
  return metric >= thr if higher else metric < thr


def first_crossings(curve, thresholds, offset=0.0, higher=False):
  """{threshold: {env_steps, seconds}} of the first evaluation past each threshold."""
  out = {}
  for thr in thresholds:
    hit = next(((n, t) for n, t, m in curve if passes(m, thr, higher)), None)
    out[str(thr)] = None if hit is None else dict(env_steps=hit[0], seconds=hit[1],
                                                  seconds_excl_startup=hit[1] - offset)
  return out


def run_hdt(agent, overrides, seeds, thresholds, eval_every, max_steps, max_seconds, episodes, log, metric="dist"):
  """One result per seed of ``seeds``: trained together in one vmapped program if several."""
  t0 = time.perf_counter()
  env = make(agent, "reach")
  cfg = configs.low_config(agent, total_env_steps=max_steps,
                           steps_per_chunk=eval_every // overrides["num_envs"], **overrides)
  make_eval = lambda trainer: make_evaluator(env, hdt_policy_fn(trainer.networks), episodes, metric)
  return hdt_loop_seeds(f"hdt {agent}", env, cfg, seeds, make_eval, thresholds, max_seconds, log, t0,
                        higher=metric == "success", metric_name=metric)


def hdt_loop_seeds(label, env, cfg, seeds, make_eval, thresholds, max_seconds, log, t0, higher=False,
                   metric_name="dist"):
  """Trains hdt SAC on ``env`` with ``cfg`` chunk by chunk, evaluating after each chunk with
  ``make_eval(trainer)((policy_params, obs_norm)) -> metric`` until the tightest threshold is passed, the
  step cap or ``max_seconds`` (training clock, started at ``t0``, evaluation excluded). Several ``seeds``
  train together as ONE vmapped program (split over the devices, as the CLI runs seeds), on one clock,
  until every seed has passed the tightest threshold at some evaluation (or the cap). One result per seed,
  its times on the shared clock; with several seeds each carries ``vmapped_seeds``, and the wall-clock for
  all of them is the last seed's first crossing. ``max_seconds`` is per seed: the seeds together get
  ``len(seeds)`` times it."""
  trainer = make_train(env, cfg)
  fns = vmapped(trainer, num_seeds=len(seeds))
  ts = jax.block_until_ready(fns.init(seed_keys(seeds), seed_indices(len(seeds))))
  t_init = time.perf_counter() - t0
  tc, hits0 = time.perf_counter(), len(_cache_hits)
  chunk = fns.run_chunk.lower(ts).compile()
  compile_s = time.perf_counter() - tc
  cache = "warm" if len(_cache_hits) > hits0 else "cold"  # the training chunk loaded, not compiled
  tag = f"seed {seeds[0]}" if len(seeds) == 1 else f"seeds {seeds[0]}-{seeds[-1]} vmapped"
  log(f"    {label} {tag}: init {t_init:.1f}s, chunk compile {compile_s:.1f}s ({cache} cache)")
  evaluate = jax.vmap(make_eval(trainer))
  train_s = t_init + compile_s
  curves, stop, done = [[] for _ in seeds], (max if higher else min)(thresholds), [False] * len(seeds)
  while True:
    tc = time.perf_counter()
    ts, m = chunk(ts)
    jax.block_until_ready(m)
    train_s += time.perf_counter() - tc
    steps = int(np.asarray(ts.env_steps)[0])
    metrics = np.asarray(evaluate((ts.agent.policy_params, ts.agent.obs_norm)), np.float64)
    for i, metric in enumerate(metrics):
      curves[i].append((steps, train_s, float(metric)))
      done[i] = done[i] or passes(float(metric), stop, higher)
    log(f"    {label} {tag}: {steps:7d} steps {train_s:7.1f}s  {metric_name} "
        + " ".join(f"{x:.3f}" for x in metrics))
    if all(done) or _stopped:
      break
    if steps + cfg.env_steps_per_chunk > cfg.total_env_steps or train_s > max_seconds * len(seeds):
      break
  shared = {} if len(seeds) == 1 else dict(vmapped_seeds=len(seeds))
  return [dict(seed=seed, reached=first_crossings(curve, thresholds, t_init + compile_s, higher),
               curve=curve, compile_s=compile_s, init_s=t_init, startup_s=t_init + compile_s,
               compile_cache=cache, final_steps=curve[-1][0], final_seconds=curve[-1][1],
               final_metric=curve[-1][2], load_end=load(), stopped=bool(_stopped), **shared)
          for seed, curve in zip(seeds, curves)]


def shown_path(path) -> str:
  """``path`` as a results file records it: relative to the working directory, or ``<tmp>/...`` under the
  temporary directory (nothing machine-specific in a committed JSON)."""
  if path is None:
    return None
  path = os.path.abspath(str(path))
  tmp = os.path.abspath(tempfile.gettempdir())
  if os.path.commonpath([path, tmp]) == tmp:
    return "<tmp>/" + os.path.relpath(path, tmp)
  return os.path.relpath(path)


def shown_args(args) -> dict:
  """The command-line arguments as recorded, path-valued ones through :func:`shown_path`."""
  paths = ("compile_cache", "out", "low_run")
  return {k: shown_path(v) if k in paths and isinstance(v, str) else v for k, v in vars(args).items()}


# ------------------------------------------------------------------------------------------------
# SBX


def save_sbx(path, model, curve):
  """Writes a stopped SBX run to ``path`` whole or not at all (hdt's atomic directory swap)."""
  def write(tmp):
    model.save(tmp / "model.zip")
    model.save_replay_buffer(tmp / "replay.pkl")
    (tmp / "curve.json").write_text(json.dumps(curve))
  atomic.replace_dir(path, write)


def run_sbx(agent, hp, seed, thresholds, eval_every, max_steps, max_seconds, episodes, log, metric="dist",
            algo="sac", keep=None, resume=False):
  from gym_reach import ReachGymEnv

  env = make(agent, "reach")  # hdt env: the model for the gym port, and the evaluator's env
  t0 = time.perf_counter()
  return sbx_loop(f"sbx {algo} {agent}", lambda: ReachGymEnv(env, seed=seed), hp, seed,
                  lambda act: make_evaluator(env, act, episodes, metric), thresholds,
                  eval_every, max_steps, max_seconds, log, t0, higher=metric == "success", metric_name=metric,
                  algo=algo, keep=None if keep is None else os.path.join(keep, f"{agent}_{algo}_seed{seed}"),
                  resume=resume)


def sbx_loop(label, make_genv, hp, seed, make_eval, thresholds, eval_every, max_steps, max_seconds,
             log, t0, higher=False, metric_name="dist", algo="sac", keep=None, resume=False):
  """Trains SBX on ``make_genv()`` (one env, one update per env step): ``algo="sac"`` at the paper's
  ``hp``; ``"crossq"`` at CrossQ's published defaults (sbx's: batch-renormalised 2048-wide critics
  without targets, lr 1e-3, batch 256, policy delay 3). Evaluates every ``eval_every`` env steps with
  ``make_eval(act)(params) -> metric``, ``act(params, obs) -> deterministic action``; the training clock
  starts at ``t0`` and excludes evaluation.

  ``keep``: a directory where a run stopped by SIGTERM saves its model (optimiser states included),
  replay buffer and curve; ``resume=True`` continues the run saved there (its clock adds this part's,
  start-up included, to the earlier parts') and removes the saved state once the run ends."""
  from stable_baselines3.common.callbacks import BaseCallback

  saved = keep is not None and os.path.exists(os.path.join(keep, "curve.json"))
  if saved and not resume:
    raise SystemExit(f"{keep} holds a stopped SBX run: add --resume to continue it, or pick another --sbx-keep")
  if resume and not saved:
    raise SystemExit(f"--resume: no stopped SBX run in {keep}; run without --resume to start one")
  genv = make_genv()
  if algo == "crossq":
    from sbx import CrossQ as Algo
    kwargs = {}
    # batch statistics frozen at evaluation (train=False), as sbx's own predict
    act = lambda p, obs: model.policy.actor_state.apply_fn(p, obs, train=False).mode()
    params = lambda m: {"params": m.policy.actor_state.params, "batch_stats": m.policy.actor_state.batch_stats}
  else:
    from sbx import SAC as Algo
    kwargs = dict(learning_rate=hp["learning_rate"], batch_size=hp["batch_size"], buffer_size=hp["buffer_size"],
                  learning_starts=100, train_freq=1, gradient_steps=1,
                  policy_kwargs=dict(net_arch=list(hp["net_arch"])))
    act = lambda p, obs: model.policy.actor_state.apply_fn(p, obs).mode()
    params = lambda m: m.policy.actor_state.params
  if saved:
    model = Algo.load(os.path.join(keep, "model.zip"), env=genv)
    model.load_replay_buffer(os.path.join(keep, "replay.pkl"))
    with open(os.path.join(keep, "curve.json")) as f:
      before = json.load(f)
    state = dict(eval_s=0.0, curve=[tuple(c) for c in before["curve"]], offset=before["seconds"])
    log(f"    {label} seed {seed}: continues from {model.num_timesteps} env steps, {before['seconds']:.1f}s ({keep})")
  else:
    model = Algo("MlpPolicy", genv, seed=seed, verbose=0, **kwargs)
    state = dict(eval_s=0.0, curve=[], offset=0.0)
  evaluate = make_eval(act)
  stop = (max if higher else min)(thresholds)

  class Eval(BaseCallback):
    def _on_step(self):
      n = self.num_timesteps
      if n % eval_every:
        return True
      te = time.perf_counter()
      metric = float(evaluate(params(self.model)))
      now = time.perf_counter()
      state["eval_s"] += now - te
      t = state["offset"] + now - t0 - state["eval_s"]
      state["curve"].append((n, t, metric))
      log(f"    {label} seed {seed}: {n:7d} steps {t:7.1f}s  {metric_name} {metric:.3f}")
      if passes(metric, stop, higher) or _stopped:
        return False
      return t < max_seconds

  model.learn(total_timesteps=max_steps - model.num_timesteps, callback=Eval(), reset_num_timesteps=not saved)
  c = state["curve"]
  if keep is not None and _stopped and model.num_timesteps < max_steps:
    save_sbx(keep, model, dict(curve=c, seconds=c[-1][1] if c else state["offset"]))
    log(f"    {label} seed {seed}: stopped at {model.num_timesteps} env steps; saved in {keep} (--resume continues)")
  elif saved:
    shutil.rmtree(keep)  # consumed: the run ended
  return dict(seed=seed, reached=first_crossings(c, thresholds, higher=higher), curve=c,
              final_steps=c[-1][0] if c else 0, final_seconds=c[-1][1] if c else 0.0,
              final_metric=c[-1][2] if c else None, load_end=load(), stopped=bool(_stopped))


# ------------------------------------------------------------------------------------------------


def summarize(runs, thr):
  """Median time / steps to ``thr`` over seeds; unreached seeds count with their final time and
  steps (so a median over them is a lower bound)."""
  thr = str(thr)
  hit = [r["reached"][thr] for r in runs]
  secs = [h["seconds"] if h else r["final_seconds"] for h, r in zip(hit, runs)]
  steps = [h["env_steps"] if h else r["final_steps"] for h, r in zip(hit, runs)]
  n_reached = sum(h is not None for h in hit)
  # the wall-clock for all seeds: one after another, or (vmapped) together until the last one crossed
  vmapped_seeds = bool(runs) and runs[0].get("vmapped_seeds", 1) > 1
  out = dict(median_seconds=float(np.median(secs)), median_env_steps=float(np.median(steps)),
             seeds_reached=n_reached, seeds=len(runs), all_reached=n_reached == len(runs),
             seconds=secs, env_steps=steps, vmapped_seeds=vmapped_seeds,
             all_seeds_seconds=float(max(secs) if vmapped_seeds else sum(secs)) if runs else 0.0)
  if runs and "startup_s" not in runs[0]:  # SBX: startup estimated from the curve (see below)
    st = [sbx_startup_estimate(r["curve"]) for r in runs]
    out["median_startup_est_s"] = float(np.median(st))
    out["median_seconds_excl_startup_est"] = float(np.median([s - t for s, t in zip(secs, st)]))
  if runs and "startup_s" in runs[0]:
    out["median_compile_s"] = float(np.median([r["compile_s"] for r in runs]))
    out["median_startup_s"] = float(np.median([r["startup_s"] for r in runs]))
    out["median_seconds_excl_startup"] = float(np.median(
        [s - r["startup_s"] for s, r in zip(secs, runs)]))
  return out


def sbx_startup_estimate(curve):
  """SBX's time before steady state (build + JIT compile), estimated from its curve: the time of
  the first evaluation minus its env steps at the steady-state rate between first and last."""
  if len(curve) < 2:
    return 0.0
  (n0, t0, _), (n1, t1, _) = curve[0], curve[-1]
  return max(0.0, t0 - n0 * (t1 - t0) / max(n1 - n0, 1))


def check(agents):
  """Step hdt's env and the gym port side by side with the same actions, the port put back on hdt's
  state before every step (float32 against float64 states diverge within tens of steps on contact-rich
  agents: the ant's after ≈ 28); print the max one-step differences."""
  from gym_reach import ReachGymEnv
  for agent in agents:
    e = make(agent, "reach")
    s = jax.jit(e.reset)(jax.random.PRNGKey(3))
    g = ReachGymEnv(e, seed=0)
    step, rng, od, rd = jax.jit(e.step, static_argnames="auto_reset"), np.random.default_rng(0), 0.0, 0.0
    for _ in range(40):
      act = s.physics.act
      g.set_state(np.asarray(s.physics.qpos, np.float64), np.asarray(s.physics.qvel, np.float64),
                  np.asarray(s.task["t"]["goal"]), None if act is None else np.asarray(act, np.float64))
      a = rng.uniform(-1, 1, e.action_size).astype(np.float32)
      s = step(s, a, auto_reset=False)
      o, r, *_ = g.step(a)
      od = max(od, float(np.abs(o - np.asarray(s.next_obs)).max()))
      rd = max(rd, abs(r - float(s.reward)))
    print(f"{agent}: hdt vs gym port over 40 random steps: max |obs diff| {od:.2e}, max |reward diff| {rd:.2e}")


def hdt_rows(hdt_configs, names, run, seeds, vmapped_seeds=False):
  """``{config name: dict(overrides, runs)}`` for the hdt ``names``: each seed on its own
  (``run(overrides, [seed])``), and with ``vmapped_seeds`` also all seeds as one vmapped program under
  the name + :data:`VMAPPED` (``run(overrides, seeds)``; each returns one result per seed)."""
  rows = {}
  for name in names:
    overrides = hdt_configs[name]
    rows[name] = dict(overrides=overrides, runs=[r for s in seeds for r in run(overrides, [s])])
    if vmapped_seeds and len(seeds) > 1:
      rows[name + VMAPPED] = dict(overrides=overrides, runs=run(overrides, seeds))
  return rows


def add_run_args(ap, *, hdt_configs, seeds, sbx_minutes, hdt_minutes, episodes):
  """The options every time-to-quality benchmark shares (this one and time_to_quality_hl.py)."""
  ap.add_argument("--seeds", type=int, default=seeds)
  ap.add_argument("--hdt-configs", default=",".join(hdt_configs))
  ap.add_argument("--skip-sbx", action="store_true")
  ap.add_argument("--skip-hdt", action="store_true")
  ap.add_argument("--sbx-max-minutes", type=float, default=sbx_minutes, help="per seed, net of evaluation")
  ap.add_argument("--hdt-max-minutes", type=float, default=hdt_minutes, help="per seed, net of evaluation")
  ap.add_argument("--eval-episodes", type=int, default=episodes)
  ap.add_argument("--vmapped-seeds", action="store_true",
                  help=f"also train each hdt config's seeds together as one vmapped program (config name + "
                       f"'{VMAPPED}'; the seeds split over the cores, as the CLI runs them) and compare the "
                       "wall-clock until all seeds reached quality with SBX's seeds run one after another")
  ap.add_argument("--quick", action="store_true", help="low thresholds and caps, 1 seed, 1 hdt config")


def main():
  ap = argparse.ArgumentParser()
  ap.add_argument("--agents", default="point,arm3")
  add_run_args(ap, hdt_configs=HDT_CONFIGS, seeds=3, sbx_minutes=25.0, hdt_minutes=10.0, episodes=50)
  ap.add_argument("--threshold", type=float, help="override the agent's threshold (m, or a rate with --metric success)")
  ap.add_argument("--first-seed", type=int, default=0, help="seeds first-seed, first-seed + 1, ...")
  ap.add_argument("--extra-thresholds", default="", help="comma-separated further thresholds with --threshold")
  ap.add_argument("--metric", choices=("dist", "success"),
                  help="quality: mean final goal distance below the threshold, or the share of episodes within "
                       "the agent's reach radius (1 cm for arms) at some step at or above it (needs "
                       "--threshold unless it is the agent's default; default: the agent's, see TASKS)")
  ap.add_argument("--eval-every", type=int, help="override the evaluation period (env steps)")
  ap.add_argument("--max-steps", type=int, help="override the env-step cap per seed")
  ap.add_argument("--recompute", action="store_true",
                  help="recompute the comparison and table from --out (no training)")
  ap.add_argument("--check", action="store_true", help="only compare hdt's env and the gym port")
  ap.add_argument("--out", default=os.path.join(HERE, "time_to_quality.json"))
  ap.add_argument("--no-results", action="store_true", help="do not update benchmarks/results.json")
  ap.add_argument("--compile-cache", help="JAX compilation cache dir for hdt (default: a fresh temp dir)")
  ap.add_argument("--sbx-algo", choices=("sac", "crossq"), default="sac",
                  help="SBX's SAC at the paper's hyper-parameters, or CrossQ at its published defaults "
                       "(results under 'crossq', compared in crossq_speedup_<agent>_ll_paper_quality)")
  ap.add_argument("--sbx-keep", metavar="DIR",
                  help="where an SBX run stopped by SIGTERM saves its model, replay buffer and curve")
  ap.add_argument("--resume", action="store_true", help="continue the SBX runs saved in --sbx-keep")
  args = ap.parse_args()
  if args.resume and not args.sbx_keep:
    raise SystemExit("--resume continues SBX runs saved in --sbx-keep DIR: give that DIR")
  agents = args.agents.split(",")
  if args.check:
    check(agents)
    return
  if args.recompute:
    with open(args.out) as f:
      out = json.load(f)
    for r in out["agents"].values():
      r["by_threshold"] = compare(r, r["thresholds"])
    with open(args.out, "w") as f:
      json.dump(out, f, indent=1)
    print_table(out)
    if not args.no_results:
      update_results(out)
    return
  signal.signal(signal.SIGTERM, lambda *_: _stopped.append(True))
  use_cpu_cores()  # as the CLI: one JAX device per core, so vmapped seeds split over the cores
  args.compile_cache = str(enable_compile_cache(args.compile_cache or tempfile.mkdtemp(prefix="hdt-ttq-")))
  seeds = list(range(args.first_seed, args.first_seed + (1 if args.quick else args.seeds)))
  hdt_names = args.hdt_configs.split(",")[:1] if args.quick else args.hdt_configs.split(",")

  def log(msg):
    print(msg, flush=True)

  out = dict(machine=dict(platform=platform.platform(), cpus=os.cpu_count(), jax=jax.__version__,
                          load_start=load()),
             args=shown_args(args), agents={})
  if os.path.exists(args.out) and not args.quick:  # keep other agents' rows from earlier runs
    with open(args.out) as f:
      prev = json.load(f)
    out["agents"] = {k: v for k, v in prev.get("agents", {}).items() if k not in agents}

  for agent in agents:
    task = dict(TASKS[agent], **(QUICK[agent] if args.quick else {}))
    default_metric = task.get("metric", "dist")
    metric = args.metric or default_metric
    success = metric == "success"
    if metric != default_metric and args.threshold is None:
      raise SystemExit(f"--metric {metric} for {agent} needs --threshold (its default quality is "
                       f"{default_metric} {task['threshold']}); e.g. --threshold 0.65")
    for k in ("threshold", "eval_every", "max_steps"):
      if getattr(args, k) is not None:
        task[k] = getattr(args, k)
    if args.threshold is not None:
      task["extra_thresholds"] = tuple(float(t) for t in args.extra_thresholds.split(",") if t)
    thr, every, cap = task["threshold"], task["eval_every"], task["max_steps"]
    thrs = [thr, *task["extra_thresholds"]]
    res = dict(threshold=thr, thresholds=thrs, eval_every=every, max_steps=cap,
               eval_episodes=args.eval_episodes, sbx_hyper=task["sbx"], hdt={}, sbx=None)
    if success:
      res.update(higher=True, unit="", metric="success within the reach radius ",
                 results_key=f"sbx_speedup_{agent}_reach_success")
    if success and default_metric == "success" and args.threshold is None:  # the agent's defined quality
      res.update(results_key=f"sbx_speedup_{agent}_ll_paper_quality", primary_only=True)
    log(f"== {agent} reach: quality = " + (f"success rate >= {thrs}" if success else f"mean final goal distance < {thrs} m")
        + f" (load {load()})")
    if not args.skip_hdt:
      res["hdt"] = hdt_rows(HDT_CONFIGS, hdt_names, lambda ov, ss: run_hdt(
          agent, ov, ss, thrs, every, cap, 60 * args.hdt_max_minutes, args.eval_episodes, log, metric),
          seeds, args.vmapped_seeds)
    sbx_key = "crossq" if args.sbx_algo == "crossq" else "sbx"
    if not args.skip_sbx:
      runs = [run_sbx(agent, task["sbx"], s, thrs, every, cap, 60 * args.sbx_max_minutes,
                      args.eval_episodes, log, metric, algo=args.sbx_algo, keep=args.sbx_keep, resume=args.resume)
              for s in seeds if not _stopped]
      res[sbx_key] = dict(runs=runs)
    if os.path.exists(args.out):  # merge with the halves this invocation did not run
      with open(args.out) as f:
        old = json.load(f).get("agents", {}).get(agent, {})
      for key in ("sbx", "crossq"):
        if old.get(key) and (key != sbx_key or args.skip_sbx):
          res[key] = old[key]
      if args.skip_hdt:
        res["hdt"] = old.get("hdt", {})
      else:  # other hdt configs measured before stay beside this invocation's
        res["hdt"] = {**old.get("hdt", {}), **res["hdt"]}
    res["by_threshold"] = compare(res, thrs)
    out["agents"][agent] = res
    out["machine"]["load_end"] = load()
    with open(args.out, "w") as f:
      json.dump(out, f, indent=1)

  print_table(out)
  if not args.quick and not args.no_results:
    update_results(out)


def update_results(out, source="benchmarks/time_to_quality.py"):
  """sbx_speedup_<agent>_reach (or the row's ``results_key``): the wall-clock ratio at the primary
  threshold; if hdt did not reach it in every seed, at the tightest threshold it did reach in every
  seed (the source says which), unless the row is ``primary_only`` (a fixed quality: no number then)."""
  for a, r in out["agents"].items():
    higher = r.get("higher", False)
    cands = [(float(t), c) for t, c in r["by_threshold"].items()
             if "speedup_seconds" in c and c["hdt_all_reached"]]
    prim = [tc for tc in cands if tc[0] == float(r["threshold"])]
    tightest = max if higher else min
    pick = prim[0] if prim else (tightest(cands, key=lambda tc: tc[0]) if cands and not r.get("primary_only")
                                 else None)
    if pick is None:
      continue
    thr, c = pick
    key = r.get("results_key", f"sbx_speedup_{a}_reach")
    lb = ", SBX did not reach it in every seed: lower bound" if c["speedup_is_lower_bound"] else ""
    if c.get("hdt_all_seeds_reached") and c["sbx"]["all_reached"]:
      n = c["hdt"][c["hdt_best_all_seeds"]]
      results_lib.update({key + "_all_seeds": c["speedup_all_seeds"]},
                         f"{source}: wall-clock until all {n['seeds']} seeds reached {thr:g}, SBX's seeds one "
                         f"after another, hdt {c['hdt_best_all_seeds']}"
                         + (" (seeds vmapped)" if n["vmapped_seeds"] else ""),
                         load=out["machine"].get("load_end"))
    results_lib.update({key: c["speedup_seconds"]},
                       f"{source}: median wall-clock incl. JIT compile, "
                       f"threshold {r['metric'] + ('>= ' if higher else '< ') if 'metric' in r else ''}"
                       f"{thr:g}{r.get('unit', ' m')}, hdt {c['hdt_best']}{lb}",
                       load=out["machine"].get("load_end"))


def compare(res, thrs):
  """Per threshold: each side's summary, the best hdt setting and the SBX / hdt ratios."""
  out = {}
  for thr in thrs:
    c = dict(hdt={n: summarize(v["runs"], thr) for n, v in res["hdt"].items()},
             sbx=summarize(res["sbx"]["runs"], thr) if res["sbx"] else None)
    if c["hdt"]:
      # per seed: configs trained seed by seed (a vmapped config's seeds share one clock)
      per_seed = [n for n, v in c["hdt"].items() if not v["vmapped_seeds"]] or list(c["hdt"])
      best = min(per_seed, key=lambda n: (not c["hdt"][n]["all_reached"], c["hdt"][n]["median_seconds"]))
      c["hdt_best"] = best
      every = min(c["hdt"], key=lambda n: (not c["hdt"][n]["all_reached"], c["hdt"][n]["all_seeds_seconds"]))
      c["hdt_best_all_seeds"] = every
      if c["sbx"] and c["sbx"]["seeds"] == c["hdt"][every]["seeds"]:
        c["speedup_all_seeds"] = c["sbx"]["all_seeds_seconds"] / c["hdt"][every]["all_seeds_seconds"]
        c["hdt_all_seeds_reached"] = c["hdt"][every]["all_reached"]
      if c["sbx"]:
        h, s = c["hdt"][best], c["sbx"]
        c["speedup_seconds"] = s["median_seconds"] / h["median_seconds"]
        c["speedup_seconds_excl_hdt_startup"] = s["median_seconds"] / h["median_seconds_excl_startup"]
        c["env_step_ratio"] = s["median_env_steps"] / h["median_env_steps"]
        c["speedup_excl_startup_both"] = (s["median_seconds_excl_startup_est"]
                                          / h["median_seconds_excl_startup"])
        c["speedup_is_lower_bound"] = not s["all_reached"]
        c["hdt_all_reached"] = h["all_reached"]
      if res.get("crossq"):
        q = c["crossq"] = summarize(res["crossq"]["runs"], thr)
        c["crossq_speedup_seconds"] = q["median_seconds"] / c["hdt"][best]["median_seconds"]
        c["crossq_speedup_is_lower_bound"] = not q["all_reached"]
    out[str(thr)] = c
  return out


def print_table(out):
  print()
  print(f"Time to quality, median over seeds (clock incl. JIT compile, excl. evaluation; ~ = estimated); "
        f"load avg {out['machine']['load_start']} -> {out['machine'].get('load_end')}")
  w = max([6, *map(len, out["agents"])])
  hdr = (f"{'agent':{w}s} {'threshold':>9s} {'who':24s} {'reached':>7s} {'env steps':>10s} {'seconds':>8s} "
         f"{'startup s':>11s}")
  print(hdr)
  print("-" * len(hdr))
  for agent, r in out["agents"].items():
    op, unit = (">=" if r.get("higher") else "<"), r.get("unit", " m")
    for thr, c in r["by_threshold"].items():
      rows = [(f"hdt {n}" + (" *" if n == c.get("hdt_best") else ""), v) for n, v in c["hdt"].items()]
      if c.get("sbx"):
        rows.append(("sbx (paper hp, 1 env)", c["sbx"]))
      for who, s in rows:
        comp = (f"{s['median_startup_s']:11.1f}" if "median_startup_s" in s
                else f"{s['median_startup_est_s']:10.1f}~")
        print(f"{agent:{w}s} {float(thr):9.4g} {who:24s} {s['seeds_reached']:>3d}/{s['seeds']:<3d} "
              f"{s['median_env_steps']:10.0f} {s['median_seconds']:8.1f} {comp}")
      if "speedup_all_seeds" in c:
        h = c["hdt"][c["hdt_best_all_seeds"]]
        print(f"  -> {agent} {op} {thr}{unit}, all {h['seeds']} seeds: hdt ({c['hdt_best_all_seeds']}, "
              f"{'vmapped' if h['vmapped_seeds'] else 'one after another'}) {h['all_seeds_seconds']:.1f} s, SBX "
              f"(one after another) {c['sbx']['all_seeds_seconds']:.1f} s: {c['speedup_all_seeds']:.2f}x"
              + ("" if c["hdt_all_seeds_reached"] else " (hdt did not reach it in every seed)"))
      if "speedup_seconds" in c:
        lb = " (lower bound: SBX did not reach it in every seed)" if c["speedup_is_lower_bound"] else ""
        bad = "" if c["hdt_all_reached"] else " (hdt did not reach it in every seed)"
        print(f"  -> {agent} {op} {thr}{unit}: hdt ({c['hdt_best']}) {c['speedup_seconds']:.2f}x faster "
              f"wall-clock ({c['speedup_seconds_excl_hdt_startup']:.1f}x without hdt's init+compile, "
              f"{c['speedup_excl_startup_both']:.1f}x without either's startup)"
              f"{lb}{bad}; SBX used {c['env_step_ratio']:.2f}x hdt's env steps")


if __name__ == "__main__":
  main()
