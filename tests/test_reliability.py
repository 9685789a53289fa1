"""Reliability: exact resume, atomic versioned checkpoints, determinism, NaN guards and
argument validation that fails before anything is written.

Training runs use the toy point-goal env of toy_env.py through ``runner.run_stage``, the function every
``train_*`` / ``finetune_high`` / ``align_low`` call ends in (MuJoCo envs compile for over a minute on
a 2-core CPU); the wiring of the public ``resume=`` keyword is checked by the validation cases.
"""

import dataclasses
import errno
import hashlib
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hdt import report
from hdt.agents import discriminator as disc_lib
from hdt.agents import train as sac_train
from hdt.agents.discriminator import DiscConfig
from hdt.agents.sac import SACConfig
from hdt.transfer import checkpoint as ckpt
from hdt.transfer import pipeline, runner, sweep
from hdt.transfer.card import LowRef, PolicyCard
from hdt.transfer.runner import RunOptions
from toy_env import PointGoal

ENV = PointGoal()
# 8 chunks of 25 training steps x 4 envs; learning starts in the first chunk.
CFG = SACConfig(hidden_sizes=(16, 16), batch_size=16, buffer_size=500, num_envs=4, steps_per_chunk=25,
                total_env_steps=800, learning_starts=40, num_eval_episodes=4)
CARD = PolicyCard(level="low", agent="toy", task="reach", family="nav", goal_space=None, k=1, delta_max=1.0,
                  obs_size=ENV.observation_size, action_size=ENV.action_size, hidden_sizes=CFG.hidden_sizes)
HALF = CFG.total_env_steps // 2
# The resumed runs carry plug-in state too: a discriminator (hdt.transfer.align's) against random taus.
_ALIGN = disc_lib.make_alignment(
    DiscConfig(batch_size=8, hidden_sizes=(8,), buffer_size=256, include_z=False, data="fixed"),  # toy env: no z
    np.random.default_rng(0).normal(size=(256, disc_lib.TAU_SIZE)).astype(np.float32),
    CFG.total_env_steps, CFG.num_envs)
ALIGN = (_ALIGN.plugin,)


class Interrupted(Exception):
  pass


def train(out, config=CFG, seeds=(0, 3), env=ENV, plugins=ALIGN, **kw):
  return runner.run_stage(runner.Stage(env, config, CARD, "toy", plugins=plugins),
                          runner.RunOptions(list(seeds), out, quiet=True, **kw))


def without_walltime(history):
  return {k: v for k, v in history.items() if k != "walltime"}  # the only non-deterministic record


def assert_trees_equal(a, b):
  la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
  assert jax.tree.structure(a) == jax.tree.structure(b) and len(la) == len(lb)
  for x, y in zip(la, lb):
    assert np.asarray(x).dtype == np.asarray(y).dtype
    assert np.array_equal(np.asarray(x), np.asarray(y), equal_nan=True)


def saved_state(run_dir, config=CFG, seeds=(0, 3), env=ENV, plugins=ALIGN):
  trainer = sac_train.make_train(env, config, plugins=plugins)
  template = jax.eval_shape(sac_train.vmapped(trainer).init, sac_train.seed_keys(list(seeds)),
                            sac_train.seed_indices(len(list(seeds))))
  return ckpt.load_state(run_dir, template)[:3]


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
  return train(tmp_path_factory.mktemp("runs") / "full", save_every=HALF)


@pytest.fixture(scope="module")
def resumed(tmp_path_factory):
  """The same run killed (an exception) right after its state was saved at HALF, then resumed."""
  out = tmp_path_factory.mktemp("runs") / "resumed"

  def crash_at_half(total, quiet, label):
    def progress(step, metrics):
      if step == HALF:
        raise Interrupted(step)
    return progress

  with pytest.raises(Interrupted):
    train(out, save_every=HALF, progress=crash_at_half)
  info = ckpt.load_state_info(out)
  assert info["env_steps"] == HALF and not (out / "seed_0").exists()
  # its curves so far are readable (hdt.report, experiments/studies/curves.py) before it finishes
  steps, _ = report.read_eval_curves(out)["eval/return"]
  assert 0 < steps.max() <= HALF
  return train(out, resume=True, save_every=HALF)


def test_resume_equals_uninterrupted_run(uninterrupted, resumed):
  assert_trees_equal(resumed.params, uninterrupted.params)
  h_full, h_res = without_walltime(uninterrupted.history), without_walltime(resumed.history)
  assert sorted(h_full) == sorted(h_res)
  for k in h_full:
    assert np.array_equal(h_full[k], h_res[k], equal_nan=True), k
  assert h_full["env_steps"].shape == (2, CFG.num_chunks)
  # The whole final TrainState (replay, env states, optimiser states, keys, ...) matches too.
  (ts_a, hist_a, info_a), (ts_b, hist_b, info_b) = saved_state(uninterrupted.run_dir), saved_state(resumed.run_dir)
  assert_trees_equal(ts_a, ts_b)
  assert int(ts_b.aux["discriminator"].size[0]) > 0 and "disc/loss" in h_res  # the plug-in state was live
  assert info_a["env_steps"] == info_b["env_steps"] == CFG.total_env_steps
  # The saved final state holds the real params and the saved checkpoints hold them too.
  assert_trees_equal(ts_b.agent.policy_params, resumed.params["policy"])
  params, _ = ckpt.load(resumed.run_dir, 1)
  assert_trees_equal(params["policy"], jax.tree.map(lambda x: np.asarray(x[1]), resumed.params["policy"]))


def test_a_finished_run_is_returned_as_it_is_and_one_of_other_settings_refused(uninterrupted, tmp_path):
  """runner.finished_run: what hdt reproduce reuses. The finished run comes back as run_stage returned
  it without a byte written; an interrupted one, or a larger budget, is None (resume it); other seeds
  are refused naming the difference."""
  stage = runner.Stage(ENV, CFG, CARD, "toy", plugins=ALIGN)
  before = _snapshot(uninterrupted.run_dir)
  res = runner.finished_run(stage, RunOptions([0, 3], uninterrupted.run_dir))
  assert _snapshot(uninterrupted.run_dir) == before
  assert_trees_equal(res.params, uninterrupted.params)
  assert_trees_equal(res.best, uninterrupted.best)
  assert_trees_equal(without_walltime(res.history), without_walltime(uninterrupted.history))
  assert runner.finished_run(stage, RunOptions([0, 3], tmp_path / "nothing")) is None
  with pytest.raises(ckpt.CheckpointError, match=r"seeds: saved \[0, 3\], requested \[0, 1\]"):
    runner.finished_run(stage, RunOptions([0, 1], uninterrupted.run_dir))
  killed = tmp_path / "killed"
  shutil.copytree(uninterrupted.run_dir, killed)
  (killed / "meta.json").unlink()  # stopped after its last state save, before its outputs were complete
  assert runner.finished_run(stage, RunOptions([0, 3], killed)) is None


def test_best_evaluation_params_survive_resume(uninterrupted, resumed):
  """The best-of-evaluation record (policy, q, return, env step per seed) of a resumed run equals the
  uninterrupted run's: it is part of the saved state, and it is saved beside the final params."""
  assert_trees_equal(resumed.best, uninterrupted.best)
  ev, steps = uninterrupted.history["eval/return"][:, 1:], uninterrupted.history["eval/env_steps"][:, 1:]
  first_max = np.argmax(ev, axis=1)  # argmax takes the earliest of ties, as update_best
  np.testing.assert_array_equal(resumed.best["env_steps"], steps[np.arange(2), first_max])
  np.testing.assert_array_equal(resumed.best["score"], ev[np.arange(2), first_max])
  for i in range(2):
    params, meta = ckpt.load(resumed.run_dir, i, which="best")
    assert meta["params"] == "best" and meta["params_env_steps"] == meta["best"]["env_steps"] == \
        int(resumed.best["env_steps"][i])
    assert_trees_equal(params, jax.tree.map(lambda x: np.asarray(x[i]), {k: resumed.best[k] for k in ("policy", "q")}))
    assert ckpt.load(resumed.run_dir, i)[1]["params"] == "final"


# any metric of the evaluation can pick (the toy env's only one is a distance, so here the farthest wins)
@pytest.mark.parametrize("best_by", ["return", "goal_dist_final"])
def test_best_params_are_those_of_the_best_evaluation(best_by, tmp_path):
  """update_best keeps, per seed, exactly the params evaluated at the highest mean of the best_by metric."""
  cfg = dataclasses.replace(CFG, total_env_steps=600, best_by=best_by)
  seen = {}

  def on_chunk(step, ts, hist, best):
    seen[step] = jax.device_get({"policy": ts.agent.policy_params, "q": ts.agent.q_params})

  res = sac_train.run(ENV, cfg, [0, 3], on_chunk=on_chunk)
  ev, steps = res.history[f"eval/{best_by}"][:, 1:], res.history["eval/env_steps"][:, 1:]
  assert not np.array_equal(np.argmax(ev, 1), np.argmax(res.history["eval/return"][:, 1:], 1)) or best_by == "return"
  for i in range(2):
    at = int(steps[i, np.argmax(ev[i])])
    assert res.best["env_steps"][i] == at and res.best["score"][i] == ev[i].max()
    assert_trees_equal({k: jax.tree.map(lambda x: x[i], res.best[k]) for k in ("policy", "q")},
                       jax.tree.map(lambda x: np.asarray(x[i]), seen[at]))
  # the record only moves up, and a NaN score never wins
  nan = sac_train.update_best(res.best, seen[at], np.array([np.nan, -np.inf]), 10**6)
  assert_trees_equal(nan, res.best)


def test_a_best_by_metric_the_evaluation_lacks_is_refused_at_the_first_evaluation():
  with pytest.raises(ValueError, match=r"best_by='success_max': this env's evaluation has no such metric; use one of "
                                       r".*goal_dist_final.*return"):
    sac_train.run(ENV, dataclasses.replace(CFG, total_env_steps=100, best_by="success_max"), [0])


def test_same_config_and_seed_give_identical_metrics(uninterrupted, tmp_path):
  again = train(None)  # no out=: nothing written, same numbers
  for k, v in without_walltime(uninterrupted.history).items():
    assert np.array_equal(v, again.history[k], equal_nan=True), k
  assert_trees_equal(again.params, uninterrupted.params)


def test_resume_refuses_a_changed_config(resumed, tmp_path):
  changed = dataclasses.replace(CFG, actor_lr=1e-3)
  before = sorted(p.relative_to(resumed.run_dir) for p in resumed.run_dir.rglob("*"))
  with pytest.raises(ckpt.CheckpointError, match=r"actor_lr: saved 0\.0003, requested 0\.001"):
    train(resumed.run_dir, config=changed, resume=True)
  with pytest.raises(ckpt.CheckpointError, match=r"seeds: saved \[0, 3\], requested \[0\]"):
    train(resumed.run_dir, seeds=[0], resume=True)
  assert sorted(p.relative_to(resumed.run_dir) for p in resumed.run_dir.rglob("*")) == before


# ------------------------------------------------------------------------------------------------
# NaN guards.


@dataclasses.dataclass(frozen=True)
class NaNRewardAfter:
  """The toy env, whose rewards are NaN from its ``nan_at``-th step on (counted across episodes)."""

  nan_at: int = 150
  inner: PointGoal = PointGoal()
  observation_size, action_size, horizon = ENV.observation_size, ENV.action_size, ENV.horizon

  def reset(self, key):
    s = self.inner.reset(key)
    return s.replace(physics=(s.physics, jnp.zeros((), jnp.int32)))

  def step(self, state, action):
    pos, n = state.physics
    s = self.inner.step(state.replace(physics=pos), action)
    return s.replace(physics=(s.physics, n + 1), reward=jnp.where(n + 1 >= self.nan_at, jnp.nan, s.reward))


def test_nan_guard_names_term_and_step_and_keeps_last_good_state(tmp_path):
  env = NaNRewardAfter()
  first_nan = env.nan_at * CFG.num_envs  # env step of the first NaN reward
  with pytest.raises(sac_train.TrainingDiverged) as err:
    train(tmp_path / "run", env=env, seeds=[3], save_every=100, plugins=())
  e = err.value
  assert isinstance(e, FloatingPointError)
  assert e.term == "critic_loss" and e.seeds == [3] and e.env_step >= first_nan
  msg = str(e)
  assert f"critic_loss became NaN/inf at env step {e.env_step} (seed 3)" in msg, msg
  assert "learning rate" in msg and "last good training state is kept" in msg
  # The state on disk is the last good one: before the bad chunk, with finite parameters.
  ts, hist, info = saved_state(tmp_path / "run", seeds=[3], env=env, plugins=())
  assert info["env_steps"] < e.env_step <= info["env_steps"] + CFG.env_steps_per_chunk
  assert all(np.all(np.isfinite(x)) for x in jax.tree.leaves(ts.agent))
  assert np.all(np.isfinite(hist["critic_loss"]))
  assert not (tmp_path / "run" / "seed_0").exists()  # no final checkpoint of a diverged run


def test_check_finite_reports_the_earliest_term():
  flags = {"nonfinite/actor_loss": np.array([4, -1]), "nonfinite/critic_loss": np.array([4, 2]),
           "nonfinite/parameters": np.array([24, 24]), "nonfinite/disc/loss": np.array([-1, -1])}
  with pytest.raises(sac_train.TrainingDiverged, match=r"critic_loss became NaN/inf at env step 1012 \(seed 7\)"):
    sac_train.check_finite(flags, 1000, 4, [5, 7])
  sac_train.check_finite({"nonfinite/critic_loss": np.array([-1])}, 0, 4, [0])  # all finite: no error


def nan_rewards_for(seed_index: int, after: int):
  """A plug-in that makes the sampled rewards of the run's seed of index ``seed_index`` NaN once it has
  taken ``after`` env steps (the others' rewards are untouched): one seed of a program diverges."""
  from hdt.agents.plugins import Plugin
  init = lambda key, agent, i: (agent, dict(index=jnp.asarray(i, jnp.int32), steps=jnp.zeros((), jnp.int32)))
  update = lambda state, transitions, env_steps, key: (dict(state, steps=env_steps), {})
  reward = lambda state, batch: jnp.where((state["index"] == seed_index) & (state["steps"] > after), jnp.nan,
                                          batch.reward)
  return Plugin("nan_rewards", init=init, update=update, reward=reward)


def test_one_diverged_seed_stays_at_its_last_finite_state_while_the_others_train_on(tmp_path, capsys):
  after = 300  # seed 3 (index 1) diverges in the chunk of env steps 300..400
  run = train(tmp_path / "run", plugins=(nan_rewards_for(1, after),), save_every=100)
  err = capsys.readouterr().err
  assert "critic_loss became NaN/inf at env step" in err and "(seed 3)" in err and "1 other run train on" in err
  _, m0 = ckpt.load(run.run_dir, 0)
  p1, m1 = ckpt.load(run.run_dir, 1)
  assert "diverged_at_env_step" not in m0 and after < m1["diverged_at_env_step"] <= after + 100
  assert all(np.all(np.isfinite(x)) for x in jax.tree.leaves(p1))
  # Seed 0 trained as it would have with no NaN anywhere; seed 3 ends as that run at its last finite chunk.
  clean = train(tmp_path / "clean", plugins=(nan_rewards_for(99, after),))
  upto = train(tmp_path / "upto", config=dataclasses.replace(CFG, total_env_steps=after),
               plugins=(nan_rewards_for(99, after),))
  seed = lambda params, i: jax.tree.map(lambda x: np.asarray(x[i]), params)
  same = lambda a, b: all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))
  assert same(seed(run.params, 0), seed(clean.params, 0))
  assert same(seed(run.params, 1), seed(upto.params, 1))
  assert not same(seed(run.params, 1), seed(clean.params, 1))
  # Its saved state keeps it stopped: a resume does not bring it back.
  ts, _, _ = saved_state(run.run_dir, plugins=(nan_rewards_for(1, after),))
  assert list(np.asarray(ts.diverged_at)) == [-1, m1["diverged_at_env_step"]]


def test_a_state_saved_before_diverged_at_existed_loads_as_never_diverged(tmp_path):
  from flax import struct

  trainer = sac_train.make_train(ENV, CFG)
  ts = sac_train.vmapped(trainer).init(sac_train.seed_keys([0, 3]), sac_train.seed_indices(2))
  fields = [f.name for f in dataclasses.fields(sac_train.TrainState) if f.name != "diverged_at"]
  Old = struct.dataclass(type("TrainState", (), {"__annotations__": {f: object for f in fields}}))
  ckpt.save_state(tmp_path, Old(**{f: getattr(ts, f) for f in fields}), {}, {"config": {}})
  template = jax.eval_shape(lambda: ts)
  loaded = ckpt.load_state(tmp_path, template).tree
  assert list(np.asarray(loaded.diverged_at)) == [-1, -1]
  assert all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(loaded.agent), jax.tree.leaves(ts.agent)))


def test_a_best_record_saved_with_its_score_named_return_loads_as_score(tmp_path):
  """States saved before the rename kept the best record's score under "return"; they still resume."""
  params = {"policy": {"w": np.arange(6, dtype=np.float32).reshape(2, 3)}}
  best = sac_train.update_best(sac_train.empty_best(params), params, np.array([0.5, 0.9]), 1000)
  old = {("return" if k == "score" else k): v for k, v in best.items()}
  ckpt.save_state(tmp_path, {"x": np.zeros(2)}, {}, {"config": {}}, best=old)
  loaded = ckpt.load_state(tmp_path, {"x": np.zeros(2)}, jax.eval_shape(lambda: best)).best
  assert_trees_equal(loaded, best)
  np.testing.assert_array_equal(loaded["score"], np.float32([0.5, 0.9]))
  # a record that has neither name still refuses to load
  ckpt.save_state(tmp_path, {"x": np.zeros(2)}, {}, {"config": {}}, best={k: v for k, v in old.items() if k != "return"})
  with pytest.raises(ckpt.CheckpointError, match="does not fit this run"):
    ckpt.load_state(tmp_path, {"x": np.zeros(2)}, jax.eval_shape(lambda: best))


# ------------------------------------------------------------------------------------------------
# Atomic, versioned checkpoints.

# For each run dir (named <kind>-<point>): saves checkpoint 1, then, in a thread, a second one that
# blocks at <point>; when all are blocked it prints PAUSED and waits to be SIGKILLed.
_KILLED_SAVES = textwrap.dedent("""
    import os, sys, threading, time
    import numpy as np
    import orbax.checkpoint as ocp
    from hdt.transfer import checkpoint as ckpt
    runs = sys.argv[1:]
    blocked = threading.Semaphore(0)

    def save(run, value):
      tree = {"w": np.full((3, 4), value, np.float32)}
      if "seed-" in run:
        ckpt.save(run, 0, tree, {"level": "low", "value": value})
      else:
        ckpt.save_state(run, tree, {"critic_loss": np.full((2, 3), value)}, {"value": value})

    def block():
      blocked.release()
      time.sleep(600)

    # "writing": the arrays of the new checkpoint are on disk, its JSON is not
    real_save = ocp.PyTreeCheckpointer.save
    def slow_save(self, path, *a, **k):
      real_save(self, path, *a, **k)
      if "writing" in str(path) and state["second"]:
        block()
    # "renaming": between the two renames, the old checkpoint already moved to <name>.old
    real_replace = os.replace
    def slow_replace(src, dst):
      real_replace(src, dst)
      if "renaming" in str(dst) and str(dst).endswith(".old"):
        block()
    ocp.PyTreeCheckpointer.save, os.replace = slow_save, slow_replace

    state = {"second": False}
    for run in runs:
      save(run, 1.0)
    state["second"] = True
    for run in runs:
      threading.Thread(target=save, args=(run, 2.0), daemon=True).start()
    for run in runs:
      blocked.acquire()
    print("PAUSED", flush=True)
    time.sleep(600)
""")


def test_sigkill_during_save_leaves_previous_checkpoint_loadable(tmp_path):
  cases = [(kind, point) for kind in ("seed", "state") for point in ("writing", "renaming")]
  runs = [str(tmp_path / f"{kind}-{point}") for kind, point in cases]
  env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(Path(ckpt.__file__).parents[2]),
                                                      os.environ.get("PYTHONPATH", "")]))
  p = subprocess.Popen([sys.executable, "-c", _KILLED_SAVES, *runs], stdout=subprocess.PIPE,
                       stderr=subprocess.DEVNULL, text=True, env=env)
  try:
    lines = iter(p.stdout.readline, "")  # mujoco may print to stdout first
    assert any(line.strip() == "PAUSED" for line in lines)
  finally:
    os.kill(p.pid, signal.SIGKILL)
    p.wait(timeout=60)
  assert p.returncode == -signal.SIGKILL
  template = {"w": jax.ShapeDtypeStruct((3, 4), np.float32)}
  for (kind, point), run in zip(cases, map(Path, runs)):
    # the kill hit where intended: a complete new tree in the temp dir / the old one moved aside
    assert any(run.glob(".*.tmp")) and (point == "writing") == any(run.glob("*[0e]"))
    if kind == "seed":
      params, meta = ckpt.load(run, 0)
      assert meta["value"] == 1.0
    else:
      params, hist, meta = ckpt.load_state(run, template)[:3]
      assert meta["value"] == 1.0 and np.all(hist["critic_loss"] == 1.0)
    np.testing.assert_array_equal(params["w"], np.ones((3, 4), np.float32))
    # The next save completes and clears the leftovers of the killed one.
    (ckpt.save(run, 0, {"w": np.zeros((1,), np.float32)}, {}) if kind == "seed"
     else ckpt.save_state(run, {"w": np.zeros((1,), np.float32)}, {}, {}))
    assert sorted(p.name for p in run.iterdir()) == (["seed_0"] if kind == "seed" else ["state"])


@pytest.fixture()
def saved(tmp_path):
  run = tmp_path / "run"
  ckpt.save(run, 0, {"policy": {"w": np.arange(4, dtype=np.float32)}}, {"level": "high", "agent": "point"})
  ckpt.save_state(run, {"w": np.arange(4, dtype=np.float32)}, {"critic_loss": np.zeros((1, 2))}, {})
  return run


def _edit_json(path, **kw):
  path.write_text(json.dumps(kw if path.read_text().startswith("[") else json.loads(path.read_text()) | kw))


@pytest.mark.parametrize("version,fix", [(ckpt.FORMAT_VERSION + 1, "upgrade hdt"), (0, "re-train it"),
                                         (None, "re-train it")])
def test_other_format_versions_are_refused(saved, version, fix):
  _edit_json(saved / "seed_0" / "meta.json", format_version=version)
  with pytest.raises(ckpt.CheckpointError, match=f"format version {version!r} but this hdt .* reads "
                     f"version {ckpt.FORMAT_VERSION}: {fix}"):
    ckpt.load(saved, 0)
  _edit_json(saved / "state" / "state.json", format_version=version)
  with pytest.raises(ckpt.CheckpointError, match=f"format version {version!r}.*{fix}"):
    ckpt.load_state_info(saved)


def test_truncated_and_corrupt_files_are_clear(saved):
  meta = saved / "seed_0" / "meta.json"
  meta.write_text(meta.read_text()[: len(meta.read_text()) // 2])
  with pytest.raises(ckpt.CheckpointError, match="corrupt checkpoint metadata .*truncated or damaged: re-run"):
    ckpt.load(saved, 0)
  meta.write_text("[1, 2]")
  with pytest.raises(ckpt.CheckpointError, match="expected a JSON object"):
    ckpt.load(saved, 0)
  for d, name in ((saved / "seed_0" / "params", "checkpoint parameters"),
                  (saved / "state" / "arrays", "training state")):
    for f in d.rglob("*"):
      if f.is_file() and f.parent.name == "d":  # the array data files
        f.write_bytes(b"\x00garbage" * 8)
  _edit_json(meta, level="high", format_version=ckpt.FORMAT_VERSION)
  with pytest.raises(ckpt.CheckpointError, match="corrupt checkpoint parameters .*re-run training"):
    ckpt.load(saved, 0)
  with pytest.raises(ckpt.CheckpointError, match="corrupt training state .*delete"):
    ckpt.load_state(saved, {"w": jax.ShapeDtypeStruct((4,), np.float32)})


def test_checkpoint_of_another_kind_is_refused(saved):
  with pytest.raises(ckpt.CheckpointError, match="holds a 'high'-level policy where a low level was expected"):
    pipeline.load_low(saved)
  with pytest.raises(ckpt.CheckpointError, match=r"does not fit this run \(saved \['w'\] float32\[4\] where this run "
                     r"needs \['w'\] float32\[5\]\)"):
    ckpt.load_state(saved, {"w": jax.ShapeDtypeStruct((5,), np.float32)})
  _edit_json(ckpt.state_dir(saved) / "state.json", hdt_version="0.0.1")  # an older layout names its writer
  with pytest.raises(ckpt.CheckpointError, match=r"hdt 0.0.1 wrote it, and this is hdt \d"):
    ckpt.load_state(saved, {"w": jax.ShapeDtypeStruct((5,), np.float32)})
  with pytest.raises(ckpt.CheckpointError, match="no saved training state"):
    ckpt.load_state_info(saved / "seed_0")


def test_a_state_saved_with_per_layer_adam_moments_resumes_with_them_raveled(tmp_path):
  """States saved before the optimisers raveled each network (hdt.agents.sac.make_optimizers) hold one
  Adam moment per layer; they load as the raveled vector optax.flatten keeps, seed by seed."""
  import optax
  from jax.flatten_util import ravel_pytree
  from hdt.agents import networks as nets
  from hdt.agents.sac import init_sac_state

  cfg = SACConfig(hidden_sizes=(8, 8))
  n = nets.make_sac_networks(3, 2, cfg.hidden_sizes)
  new = jax.vmap(lambda k: init_sac_state(n, cfg, k))(jax.random.split(jax.random.PRNGKey(0), 2))
  rng = np.random.default_rng(0)
  noisy = lambda tree: jax.tree.map(lambda x: rng.normal(size=x.shape).astype(x.dtype) if x.dtype == np.float32 else x, tree)
  per_layer = lambda params: jax.vmap(optax.adam(1e-3).init)(params)  # the old optimiser state
  old = new.replace(policy_opt_state=noisy(per_layer(new.policy_params)),
                    q_opt_state=noisy(per_layer(new.q_params)), alpha_opt_state=noisy(per_layer(new.log_alpha)))
  ckpt.save_state(tmp_path / "run", {"agent": old}, {}, {})
  got = ckpt.load_state(tmp_path / "run", {"agent": new}).tree["agent"]
  assert jax.tree.structure(got) == jax.tree.structure(new)
  for name in ("policy_opt_state", "q_opt_state", "alpha_opt_state"):
    saved, loaded = getattr(old, name)[0], getattr(got, name)[0]
    np.testing.assert_array_equal(loaded.count, saved.count)
    for moment in ("mu", "nu"):
      want = np.stack([ravel_pytree(jax.tree.map(lambda x: x[s], getattr(saved, moment)))[0] for s in range(2)])
      np.testing.assert_array_equal(getattr(loaded, moment), want)
  np.testing.assert_array_equal(got.q_params["params"]["critics"]["out"]["kernel"],
                                old.q_params["params"]["critics"]["out"]["kernel"])


# ------------------------------------------------------------------------------------------------
# Bad inputs fail with a message naming the problem and the fix, before anything is written.

from hdt.envs import make  # noqa: E402
from hdt.transfer import configs  # noqa: E402
from hdt.transfer.align import align_low  # noqa: E402
from hdt.transfer.evaluate import compose, evaluate  # noqa: E402
from hdt.transfer.finetune import FinetuneSpec, finetune_high  # noqa: E402
from hdt.transfer.hierarchy import HighLevelEnv  # noqa: E402
from hdt.transfer import names, zoo  # noqa: E402
from hdt.transfer.pipeline import train_full, train_high, train_low  # noqa: E402

PCFG = configs.low_config("point", total_env_steps=400, num_envs=4, steps_per_chunk=25, batch_size=16,
                          buffer_size=1000, hidden_sizes=(16, 16), num_eval_episodes=2)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
  """Checkpoints written without training (their metadata is what the checks read)."""
  root = tmp_path_factory.mktemp("fake_runs")
  w = {"w": np.zeros((2,), np.float32)}

  def low(agent, **extra):
    return PolicyCard.from_env(make(agent, "reach"), "low", PCFG, env_overrides={}).to_json() | extra

  metas = dict(point_low=low("point"), arm_low=low("arm3"), point_low_box2=low("point", delta_max=2.0),
               point_high=low("point", level="high", task="waypoint"))
  for name, meta in metas.items():
    ckpt.save(root / name, 0, {"policy": policy_params(meta), "q": w}, dict(meta, seed=0))
  ckpt.save(root / "corrupt", 0, {"policy": w}, metas["point_low"])
  (root / "corrupt" / "seed_0" / "meta.json").write_text('{"level": "lo')  # truncated
  ckpt.save_state(root / "point_state", w, {}, dict(config=dataclasses.asdict(PCFG), seeds=[0],
                                                    meta=metas["point_low"]))
  (root / "a_file").write_text("not a run directory")
  (root / "foreign").mkdir()
  (root / "foreign" / "notes.txt").write_text("not hdt's")
  ckpt.save(root / "no_hidden", 0, {"policy": w}, {k: v for k, v in metas["point_low"].items() if k != "hidden_sizes"})
  (root / "user_meta").mkdir()  # the user's: a meta.json does not make a directory hdt's
  (root / "user_meta" / "meta.json").write_text('{"level": "low"}')
  (root / "cache_only" / ".cache.tmp").mkdir(parents=True)
  (root / "link").symlink_to(root / "point_state")
  return root


def policy_params(meta):
  """Parameters of the policy network a card describes (what a checkpoint of it holds)."""
  from hdt.agents import networks as nets
  net = nets.make_sac_networks(meta["obs_size"], meta["action_size"], tuple(meta["hidden_sizes"]))
  return net.policy_init(jax.random.PRNGKey(0))


def at(out, **kw) -> RunOptions:
  return RunOptions(out=out, **kw)


def _low(runs, **kw):
  """train_low of the point mass into ``out``; ``kw``: RunOptions fields, or env options."""
  run = {k: v for k, v in kw.items() if k in RunOptions.__dataclass_fields__}
  env = {k: v for k, v in kw.items() if k not in run}
  return lambda out: train_low("point", PCFG, options=at(out, quiet=True, **run), **env)


BAD_INPUTS = {
    # configuration
    "zero batch": (lambda r: lambda out: SACConfig(batch_size=0), "batch_size=0: must be a positive integer"),
    "negative buffer": (lambda r: lambda out: SACConfig(buffer_size=-5), "buffer_size=-5: must be a positive"),
    "batch > buffer": (lambda r: lambda out: configs.low_config("point", batch_size=2000, buffer_size=1000),
                       "batch_size=2000 > buffer_size=1000: lower batch_size or raise buffer_size"),
    "no hidden layers": (lambda r: lambda out: SACConfig(hidden_sizes=()), "give at least one hidden layer"),
    "zero learning rate": (lambda r: lambda out: SACConfig(actor_lr=0.0), "actor_lr=0.0: learning rates must be positive"),
    "partial chunk": (lambda r: lambda out: SACConfig(total_env_steps=1000, steps_per_chunk=300),
                      "not a multiple of num_envs\\*steps_per_chunk=300: set total_env_steps to 900"),
    "zero discriminator batch": (lambda r: lambda out: DiscConfig(batch_size=0, stop=2.0),
                                 "batch_size=0 must be a positive integer; stop=2.0 must be in \\(0, 1\\]"),
    # environments
    "unknown agent": (lambda r: lambda out: train_low("nope", PCFG, options=at(out)),
                      "unknown agent 'nope'; valid agents: point"),
    "unknown task": (lambda r: lambda out: make("point", "nope"), "unknown task 'nope'; valid tasks: reach"),
    "unsupported pair": (lambda r: lambda out: train_full("ant", "push1", options=at(out)),
                         "agent 'ant' cannot run task 'push1' .*tasks for ant: reach"),
    "unknown override": (lambda r: lambda out: train_low("point", PCFG, wheels=4, options=at(out)),
                         "unknown override"),
    "k <= 0 (HighLevelEnv)": (lambda r: lambda out: HighLevelEnv(make("point", "waypoint"), None, None, k=-1),
                              "k \\(LL steps per HL action\\) must be positive, got -1"),
    "zero sub-goal box": (lambda r: lambda out: HighLevelEnv(make("point", "waypoint"), None, None, delta_max=0),
                          "delta_max .* must be positive, got 0.0"),
    # seeds and run arguments
    "zero seeds": (lambda r: _low(r, seeds=0), "seeds=0: the number of seeds must be positive"),
    "negative seed count": (lambda r: _low(r, seeds=-2), "seeds=-2: the number of seeds must be positive"),
    "negative seed": (lambda r: _low(r, seeds=[0, -1]), "list of integers >= 0"),
    "repeated seeds": (lambda r: _low(r, seeds=[1, 1]), "seeds repeat"),
    "zero save_every": (lambda r: _low(r, save_every=0), "save_every=0: give a positive number of env steps"),
    "out is a file": (lambda r: lambda out: train_low("point", PCFG, options=at(r / "a_file")),
                      "is an existing file"),
    "resume without out": (lambda r: lambda out: train_low("point", PCFG, options=RunOptions(resume=True)),
                           "resume=True needs out=: the run directory of the interrupted run"),
    "resume missing run": (lambda r: _low(r, resume=True), "cannot resume: .* does not exist; start the run without resume"),
    "resume a run without state": (lambda r: lambda out: train_low("point", PCFG, options=at(r / "point_low", resume=True)),
                                   "has no saved training state"),
    "resume changed config": (lambda r: lambda out: train_low("point", configs.replace(PCFG, actor_lr=1e-3),
                                                              options=at(r / "point_state", resume=True)),
                              "config.actor_lr: saved 0.0003, requested 0.001.*another out= directory"),
    "resume another agent's run": (lambda r: lambda out: train_low("arm3", PCFG, options=at(out, resume=r / "point_state")),
                                   "meta.agent: saved 'point', requested 'arm3'"),
    "resume another level's run": (lambda r: lambda out: train_full("point", "waypoint", PCFG,
                                                                    options=at(out, resume=r / "point_state")),
                                   "meta.level: saved 'low', requested 'full'.*meta.task: saved 'reach', "
                                   "requested 'waypoint'"),
    # hand-offs between levels
    "missing LL run": (lambda r: lambda out: train_high("waypoint", r / "nope", options=at(out)),
                       "nope does not exist"),
    "HL where LL expected": (lambda r: lambda out: train_high("waypoint", r / "point_high", options=at(out)),
                             "holds a 'high'-level policy where a low level was expected"),
    "LL seed out of range": (lambda r: lambda out: train_high("waypoint", LowRef(r / "point_low", seed_index=3),
                                                              options=at(out)),
                             "no checkpoint for seed 3 .*seeds present: \\[0\\]"),
    "HL k = 0": (lambda r: lambda out: train_high("waypoint", r / "point_low", k=0, options=at(out)),
                 "k \\(LL steps per HL action\\) must be positive, got 0"),
    "HL unknown task": (lambda r: lambda out: train_high("nope", r / "point_low", options=at(out)),
                        "unknown task 'nope'"),
    "nav HL on arm LL": (lambda r: lambda out: train_high("waypoint", r / "arm_low", options=at(out)),
                         "agent 'arm3' cannot run task 'waypoint'"),
    "finetune from an LL": (lambda r: lambda out: finetune_high(r / "point_low", r / "point_low", "waypoint",
                                                                options=at(out)),
                            "finetune_high needs an HL"),
    "negative KL weight": (lambda r: lambda out: FinetuneSpec(kl_weight=-1), "kl_weight=-1: the KL weight must be"),
    "align across families": (lambda r: lambda out: align_low("arm3", r / "point_low", options=at(out)),
                              "cannot align 'arm3' .*goal spaces differ"),
    "imitate an HL": (lambda r: lambda out: train_low("point", PCFG, imitate=r / "point_high", options=at(out)),
                      "where a low level was expected"),
    "compose LL as HL": (lambda r: lambda out: compose(r / "point_low", r / "point_low"), "compose needs an HL"),
    "compose nav HL, arm LL": (lambda r: lambda out: compose(r / "point_high", r / "arm_low"),
                               "goal spaces do not match.*pair an HL and an LL of the same family"),
    "compose other goal box": (lambda r: lambda out: compose(r / "point_high", r / "point_low_box2"),
                               "goal boxes differ.*pass box='scale'"),
    "compose corrupt run": (lambda r: lambda out: compose(r / "point_high", r / "corrupt"),
                            "corrupt checkpoint metadata .*re-run training"),
    "evaluate 0 episodes": (lambda r: lambda out: evaluate(compose(r / "point_high", r / "point_low"), episodes=0),
                            "episodes=0: the number of evaluation episodes must be a positive"),
    "evaluate unknown task": (lambda r: lambda out: evaluate(compose(r / "point_high", r / "point_low"), "nope"),
                              "unknown task 'nope'"),
    "evaluate missing seed": (lambda r: lambda out: evaluate(compose(r / "point_high", r / "point_low"), seeds=[2]),
                              "seeds=\\[2\\]: pick seed indices of the policy, in 0..0"),
    # run directories and sizes
    "empty out": (lambda r: lambda out: train_low("point", PCFG, options=at("")),
                  "out is empty, which would write into the current"),
    "out under a file": (lambda r: lambda out: train_low("point", PCFG, options=at(r / "a_file" / "run")),
                         "lies under the file"),
    "out a system dir": (lambda r: lambda out: train_low("point", PCFG, options=at("/etc/hdt")),
                         "is a system directory"),
    "out an existing run": (lambda r: lambda out: train_low("point", PCFG, options=at(r / "point_state")),
                            "already holds a run: pass --resume \\(resume=True\\)"),
    "out not an hdt dir": (lambda r: lambda out: train_low("point", PCFG, options=at(r / "foreign", overwrite=True)),
                           "is not an hdt directory and not empty \\(it holds notes.txt\\)"),
    "resume and overwrite": (lambda r: _low(r, resume=True, overwrite=True), "resume and overwrite exclude each other"),
    "seeds beyond memory": (lambda r: _low(r, seeds=10**9), "GiB of memory are available: lower the number of seeds"),
    "override of wrong type": (lambda r: _low(r, delta_max="abc"), "option delta_max='abc': expected a finite number > 0"),
    "override k=0": (lambda r: _low(r, k=0), "option k=0: expected an integer > 0"),
    "unknown low_params": (lambda r: lambda out: LowRef(r / "point_low", params="worst"),
                           "params='worst': load the 'final' parameters or the 'best'"),
    "unknown which": (lambda r: lambda out: compose(r / "point_high", r / "point_low", which="last"),
                      "which='last': load the 'final' parameters"),
    "LL meta missing a key": (lambda r: lambda out: train_high("waypoint", r / "no_hidden", options=at(out)),
                              "has no 'hidden_sizes': the file was edited or damaged"),
    "episodes beyond memory": (lambda r: lambda out: evaluate(compose(r / "point_high", r / "point_low"), episodes=10**12),
                               "lower the number of episodes"),
    # the Python API names the argument
    "fractional hidden size": (lambda r: lambda out: SACConfig(hidden_sizes=(64.7,)),
                               "hidden_sizes=\\(64.7,\\): give at least one hidden layer, all sizes positive integers"),
    "bool batch size": (lambda r: lambda out: SACConfig(batch_size=True), "batch_size=True: must be a positive integer"),
    "learning rate as text": (lambda r: lambda out: SACConfig(actor_lr="3e-4"), "actor_lr='3e-4': must be a number"),
    "budget past int32": (lambda r: lambda out: SACConfig(total_env_steps=2**32, steps_per_chunk=1024),
                          "total_env_steps=4294967296: must be below 2\\*\\*31"),
    "learning starts past the budget": (lambda r: lambda out: configs.low_config("point", total_env_steps=400,
                                                                                 learning_starts=500),
                                        "learning_starts=500 >= total_env_steps=400"),
    "config a dict": (lambda r: lambda out: train_low("point", {}, options=at(out)),
                      "config=\\{\\}: pass a hdt.agents.sac.SACConfig"),
    "out a number": (lambda r: lambda out: train_low("point", PCFG, options=at(123)),
                     "out=123: give the run directory as a path"),
    "compose box unknown": (lambda r: lambda out: compose(r / "point_high", r / "point_low", box="bogus"),
                            "box='bogus': pass 'refuse'"),
    "anneal fraction 2": (lambda r: lambda out: FinetuneSpec(anneal_frac=2), "anneal_frac=2: must be in \\[0, 1\\]"),
    "networks beyond memory": (lambda r: lambda out: train_low("point", configs.replace(PCFG, hidden_sizes=(200_000,) * 2),
                                                                options=at(out, quiet=True)),
                               "networks \\[200000, 200000\\].*GiB of memory"),
    "two grid points, one out": (lambda r: lambda out: sweep.sweep("low", [(PCFG, out), (PCFG, out)], agent="point",
                                                                   options=RunOptions(quiet=True)),
                                 "two grid points would write the same directory"),
    # never an input, another run, the zoo or the user's directory
    "out is the input LL": (lambda r: lambda out: train_high("waypoint", r / "point_low",
                                                             options=at(r / "point_low", overwrite=True)),
                            "is the low run .* this command reads"),
    "out inside a run": (lambda r: lambda out: train_low("point", PCFG, options=at(r / "point_state" / "state" / "x")),
                         "lies inside the hdt run directory"),
    "out in the zoo": (lambda r: lambda out: train_low("point", PCFG,
                                                       options=at(names.ZOO_DIR / "point" / "low", overwrite=True)),
                       "lies in the model zoo"),
    "out a user dir with meta.json": (lambda r: lambda out: train_low("point", PCFG,
                                                                      options=at(r / "user_meta", overwrite=True)),
                                      "is not an hdt directory and not empty \\(it holds meta.json\\)"),
    "out holding only .cache.tmp": (lambda r: lambda out: train_low("point", PCFG,
                                                                    options=at(r / "cache_only", overwrite=True)),
                                    "is not an hdt directory and not empty \\(it holds .cache.tmp/\\)"),
    "out a link to a run": (lambda r: lambda out: train_low("point", PCFG, options=at(r / "link", overwrite=True)),
                            "is a symbolic link"),
    "zoo export name a path": (lambda r: lambda out: zoo.export(r / "point_low", "../../victim", "test", overwrite=True),
                               "zoo name '../../victim'"),
    "zoo export 0 episodes": (lambda r: lambda out: zoo.export(r / "point_low", "t/x", "test", episodes=0),
                              "episodes=0: the evaluation recorded with the entry needs a positive number"),
    "zoo: a path": (lambda r: lambda out: compose("zoo:../../x", r / "point_low"), "zoo name '../../x'"),
}


def _snapshot(root: Path) -> dict:
  """Content hash of every file and directory name in the tree (what a refused call must not change)."""
  return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
          for p in root.rglob("*")}


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_bad_input_fails_clearly_and_writes_nothing(case, runs, tmp_path):
  make_call, message = BAD_INPUTS[case]
  out = tmp_path / "out"
  before = _snapshot(runs)
  zoo_before = _snapshot(names.ZOO_DIR) if "zoo" in case else None
  with pytest.raises(ValueError, match=message):  # CheckpointError is a ValueError
    make_call(runs)(out)
  assert not out.exists()
  assert _snapshot(runs) == before
  assert zoo_before is None or _snapshot(names.ZOO_DIR) == zoo_before


# ------------------------------------------------------------------------------------------------
# Run directories: ownership, overwrite, locks, every state a kill can leave.

import shutil  # noqa: E402

from hdt import interrupt  # noqa: E402
from hdt.transfer import rundir  # noqa: E402

SMALL = dataclasses.replace(CFG, total_env_steps=200)


def test_overwrite_replaces_the_whole_run_and_never_mixes_seeds(uninterrupted, tmp_path):
  run = tmp_path / "run"
  shutil.copytree(uninterrupted.run_dir, run)
  assert ckpt.list_seeds(run) == [0, 1] and (run / "tb" / "seed_3").is_dir()
  (run / "seed_1" / "stale.txt").write_text("from the old run")
  backup = tmp_path / ".run.replaced-backup"  # the user's, named like hdt's temporaries once were
  backup.mkdir()
  (backup / "keep.txt").write_text("mine")
  (tmp_path / ".run.hdt-replaced-mine").mkdir()  # even hdt's naming: without hdt's tag it is not hdt's
  (tmp_path / ".run.hdt-replaced-mine" / "keep.txt").write_text("mine too")
  with pytest.raises(rundir.RunDirError, match="already holds a run: pass --resume .* --overwrite"):
    train(run, config=SMALL, seeds=[5], plugins=())
  res = train(run, config=SMALL, seeds=[5], plugins=(), overwrite=True)
  assert ckpt.list_seeds(run) == [0] and not (run / "seed_1").exists()
  assert sorted(p.name for p in (run / "tb").iterdir()) == ["seed_5"]
  assert json.loads((run / "meta.json").read_text())["seeds"] == [5]
  assert sorted(p.name for p in tmp_path.iterdir()) == [".run.hdt-replaced-mine", ".run.replaced-backup", "run"]
  assert (backup / "keep.txt").read_text() == "mine"  # the old run is gone, and nothing else
  assert_trees_equal(ckpt.load(run, 0)[0]["policy"], jax.tree.map(lambda x: np.asarray(x[0]), res.params["policy"]))


def test_directories_hdt_does_not_own_are_refused_even_with_overwrite(tmp_path):
  foreign = tmp_path / "data"
  foreign.mkdir()
  (foreign / "config.json").write_text("{}")
  (foreign / "seed_0").mkdir()
  before = _snapshot(tmp_path)
  for kw in ({}, {"overwrite": True}):
    with pytest.raises(rundir.RunDirError, match=r"not an hdt directory and not empty \(it holds config.json, seed_0/\)"):
      train(foreign, config=SMALL, plugins=(), **kw)
  assert _snapshot(tmp_path) == before


def test_directories_written_before_the_marker_are_hdts_only_with_all_of_hdts_files(uninterrupted, tmp_path):
  old = tmp_path / "old_run"
  shutil.copytree(uninterrupted.run_dir, old)
  (old / rundir.MARKER).unlink()  # as written before the marker existed
  assert rundir.owner_kind(old) == "run"
  assert rundir.check_claimable(old, overwrite=True) == old
  for missing in ("config.json", "seed_0", "seed_1", "state"):
    (shutil.rmtree if (old / missing).is_dir() else os.unlink)(old / missing)
  assert rundir.owner_kind(old) is None  # meta.json, metrics.csv, tb/ alone: the user's, as far as hdt knows
  with pytest.raises(rundir.RunDirError, match="is not an hdt directory"):
    rundir.check_claimable(old, overwrite=True)
  # an experiment's directory from before the marker: its runs and its own tables, nothing else
  exp = tmp_path / "table1-smoke"
  shutil.copytree(uninterrupted.run_dir, exp / "point_low")
  (exp / "table1_smoke.md").write_text("| table |")
  legacy = lambda path: rundir.holds_only_runs(path, lambda name: name.startswith("table1_"))
  assert rundir.check_claimable(exp, "experiment", reuse=True, legacy=legacy) == exp
  (exp / "notes.txt").write_text("mine")
  with pytest.raises(rundir.RunDirError, match="is not an hdt directory"):
    rundir.check_claimable(exp, "experiment", reuse=True, legacy=legacy)


_HOLD_LOCK = textwrap.dedent("""
    import sys, time
    from hdt.transfer import rundir
    with rundir.claim(sys.argv[1]):
      print("LOCKED", flush=True)
      time.sleep(600)
""")


def test_a_second_writer_is_refused_naming_the_pid_and_a_dead_holder_is_taken_over(tmp_path, capsys):
  from hdt.cli import main
  run = tmp_path / "run"
  env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(Path(ckpt.__file__).parents[2]),
                                                      os.environ.get("PYTHONPATH", "")]))
  p = subprocess.Popen([sys.executable, "-c", _HOLD_LOCK, str(run)], stdout=subprocess.PIPE, text=True, env=env)
  try:
    assert any(line.strip() == "LOCKED" for line in iter(p.stdout.readline, ""))
    with pytest.raises(rundir.RunDirError, match=f"is in use by PID {p.pid}, which is writing to it"):
      train(run, config=SMALL, plugins=())
    assert main(["train", "low", "--agent", "point", "--preset", "smoke", "--quiet", "--out", str(run),
                 "--overwrite"]) == 2
    err = capsys.readouterr().err.strip()
    assert f"in use by PID {p.pid}" in err and len(err.splitlines()) == 1
    # the directory itself is locked: deleting .hdt-lock does not let a second writer replace the run
    (run / rundir.LOCK).unlink()
    before = _snapshot(run)
    with pytest.raises(rundir.RunDirError, match="is in use by another process, which is writing to it"):
      train(run, config=SMALL, plugins=(), overwrite=True)
    assert _snapshot(run) == before
  finally:
    os.kill(p.pid, signal.SIGKILL)
    p.wait(timeout=60)
  res = train(run, config=SMALL, plugins=())  # the dead process's lock is taken over
  assert ckpt.list_seeds(res.run_dir) == [0, 1]


@pytest.mark.parametrize("how", ["deleted", "replaced"])
def test_a_run_whose_directory_was_deleted_or_replaced_writes_nothing_more(how, tmp_path):
  """A user deletes a live run's directory (or moves it) and starts a new run there while the old
  process is still saving (on Ctrl-C it saves its state): the old one must not write into the new one."""
  run = tmp_path / "run"
  tree = {"w": np.ones(3, np.float32)}
  with rundir.claim(run):
    ckpt.save_state(run, tree, {}, {"env_steps": 1})
    shutil.rmtree(run) if how == "deleted" else run.rename(tmp_path / "moved")
    if how == "replaced":
      run.mkdir()
      (run / "theirs.txt").write_text("a new run's file")
    before = _snapshot(run) if run.exists() else None
    with pytest.raises(rundir.RunDirError, match="was deleted or replaced while this process wrote it"):
      ckpt.save_state(run, tree, {}, {"env_steps": 2})
    with pytest.raises(rundir.RunDirError, match="was deleted or replaced"):
      ckpt.save(run, 0, tree, {})
    assert (_snapshot(run) if run.exists() else None) == before
  if how == "replaced":
    assert ckpt.load_state_info(tmp_path / "moved")["env_steps"] == 1  # the moved run is intact


def test_resume_from_every_state_a_kill_can_leave(uninterrupted, tmp_path):
  """state/ (tested above), state.old (killed between the two renames), and only a temporary
  directory (killed during the first save: nothing to resume, a fresh start needs no --overwrite)."""
  run = tmp_path / "run"
  shutil.copytree(uninterrupted.run_dir, run)
  os.replace(run / "state", run / "state.old")
  (run / "meta.json").unlink()  # as if killed before the run's outputs were written
  assert ckpt.has_state(run)
  res = train(run, resume=True)
  assert_trees_equal(res.params, uninterrupted.params)
  assert_trees_equal(res.best, uninterrupted.best)
  fresh = tmp_path / "fresh"
  fresh.mkdir()
  (fresh / rundir.MARKER).write_text('{"kind": "run"}')
  (fresh / ".state.abc.tmp").mkdir()
  assert not ckpt.has_state(fresh)
  with pytest.raises(ckpt.CheckpointError, match="no saved training state"):
    train(fresh, resume=True)
  assert rundir.check_claimable(fresh) == fresh  # hdt's own leftovers only: counts as empty


def test_ctrl_c_during_a_save_finishes_the_save_first(tmp_path):
  """SIGINT while a checkpoint is written is delivered after it: no partial checkpoint."""
  run = tmp_path / "run"
  real = ckpt.write_json_atomic

  def interrupted_write(path, obj):
    if Path(path).name == "meta.json" and "seed_index" in obj:
      os.kill(os.getpid(), signal.SIGINT)
    real(path, obj)

  mp = pytest.MonkeyPatch()
  mp.setattr(ckpt, "write_json_atomic", interrupted_write)
  # A shell's background job starts with SIGINT ignored; this test needs Python's own handler.
  previous = signal.signal(signal.SIGINT, signal.default_int_handler)
  try:
    with pytest.raises(KeyboardInterrupt):
      with interrupt.deferred():
        ckpt.save(run, 0, {"w": np.ones(3, np.float32)}, {"level": "low"})
  finally:
    mp.undo()
    signal.signal(signal.SIGINT, previous)
  assert ckpt.load(run, 0)[1]["level"] == "low"


@pytest.mark.parametrize("umask", [0o022, 0o002])
def test_run_files_follow_the_users_umask(tmp_path, umask):
  """A shared run is readable by whom the umask allows (tempfile alone makes files 0600, dirs 0700)."""
  previous = os.umask(umask)
  try:
    run = tmp_path / "run"
    with rundir.claim(run):
      ckpt.save(run, 0, {"w": np.ones(3, np.float32)}, {"level": "low"})
      ckpt.save_state(run, {"w": np.ones(3, np.float32)}, {}, {})
      ckpt.write_json_atomic(run / "meta.json", {"seeds": [0]})
      runner.write_metrics_csv(run / "metrics.csv", {"critic_loss": np.zeros((1, 2))}, [0])
  finally:
    os.umask(previous)
  mode = lambda p: p.stat().st_mode & 0o777
  for path in (run, run / rundir.MARKER, run / "meta.json", run / "metrics.csv", run / "seed_0",
               run / "seed_0" / "meta.json", run / "state", run / "state" / "state.json"):
    assert mode(path) == (0o777 if path.is_dir() else 0o666) & ~umask, (path, oct(mode(path)))


@pytest.fixture()
def small_disk(tmp_path):
  """A 300 kB tmpfs (root only; skipped elsewhere)."""
  mnt = tmp_path / "small"
  mnt.mkdir()
  if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=300k", "tmpfs", str(mnt)], capture_output=True).returncode:
    pytest.skip("cannot mount a small tmpfs here (needs root)")
  yield mnt
  subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def test_a_full_disk_is_one_line_and_leaves_no_half_written_run(small_disk, tmp_path, capfd):
  """The first save fails: the error names the path, the run directory it created is removed, and
  none of orbax's writer-thread tracebacks is printed (API and the command)."""
  with pytest.raises(OSError) as e:
    train(small_disk / "run", config=dataclasses.replace(SMALL, hidden_sizes=(256, 256)), plugins=())
  assert e.value.errno == errno.ENOSPC and str(small_disk / "run" / "state") in e.value.filename
  assert not any(small_disk.iterdir())
  assert "Traceback" not in capfd.readouterr().err
  env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(Path(ckpt.__file__).parents[2]),
                                                      os.environ.get("PYTHONPATH", "")]))
  out = subprocess.run([sys.executable, "-m", "hdt.cli", "train", "low", "--agent", "point", "--preset", "smoke",
                        "--quiet", "--out", str(small_disk / "cli")], capture_output=True, text=True, env=env,
                       cwd=tmp_path)
  assert out.returncode == 1 and out.stderr.strip().splitlines() == [out.stderr.strip()], out.stderr[-3000:]
  assert out.stderr.startswith(f"hdt: error: no space left on the device of {small_disk / 'cli' / 'state'}")
  assert "free space there or pass an --out on another disk" in out.stderr
  assert not any(small_disk.iterdir()), sorted(map(str, small_disk.rglob("*")))


def test_a_read_only_out_is_one_line_before_anything_is_loaded(tmp_path, capsys):
  """A read-only mount (which root's os.access does not see) is refused before anything is written."""
  from hdt.cli import main
  ro = tmp_path / "ro"
  ro.mkdir()
  if subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(ro)], capture_output=True).returncode:
    pytest.skip("cannot mount a read-only tmpfs here (needs root)")
  try:
    assert main(["train", "low", "--agent", "point", "--preset", "smoke", "--quiet", "--out", str(ro / "run")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"error: --out={ro / 'run'}: cannot write in {ro} (permission denied or a read-only file "
                   f"system); pass a directory you can write to"), err
  finally:
    subprocess.run(["umount", "-l", str(ro)], capture_output=True)


def test_a_ctrl_c_a_library_swallowed_still_stops_the_run(tmp_path):
  """A KeyboardInterrupt raised where it cannot propagate (JAX's gc callback prints "Exception ignored"
  and goes on) is remembered: the run stops before training, its empty directory removed."""
  previous = signal.getsignal(signal.SIGINT)
  # as at a terminal: a suite started as a background job (nohup ... &) inherits SIGINT ignored
  signal.signal(signal.SIGINT, signal.default_int_handler)
  interrupt.catch()
  try:
    try:
      os.kill(os.getpid(), signal.SIGINT)
      time.sleep(1)
    except KeyboardInterrupt:
      pass  # swallowed, as a finalizer would
    with pytest.raises(KeyboardInterrupt):
      train(tmp_path / "run", config=SMALL, plugins=())
    assert not (tmp_path / "run").exists()
  finally:
    signal.signal(signal.SIGINT, previous)
    interrupt.catch.__globals__["_PRESSED"].clear()


def test_numpy_integers_are_budgets_and_counts():
  cfg = SACConfig(total_env_steps=np.int64(2000), num_envs=np.int32(4), steps_per_chunk=np.int64(50),
                  hidden_sizes=np.array([16, 16]), learning_starts=np.uint16(40))
  assert cfg.total_env_steps == 2000 and type(cfg.total_env_steps) is int and cfg.hidden_sizes == (16, 16)
  assert type(cfg.num_envs) is int and hash(cfg) == hash(SACConfig(total_env_steps=2000, num_envs=4, steps_per_chunk=50,
                                                                    hidden_sizes=(16, 16), learning_starts=40))
  assert configs.low_config("point", total_env_steps=np.int64(4000)).total_env_steps == 4000


def test_mujoco_warnings_are_counted_not_printed(capfd):
  import jax.numpy as jnp
  env = make("ant", "reach")
  s = env.reset(jax.random.PRNGKey(0))
  s = s.replace(physics=jax.tree.map(lambda x: x * 1e30 if jnp.issubdtype(x.dtype, jnp.floating) else x, s.physics))
  with runner.counted_mujoco_warnings() as warned:
    jax.block_until_ready(jax.jit(env.step)(s, jnp.full(env.action_size, 1e30)))
  out, err = capfd.readouterr()
  assert warned and "unstable" in warned[0] and "WARNING" not in out + err.replace("simulation warning", "")
  assert len(err.strip().splitlines()) == 1 and err.startswith(f"MuJoCo reported {len(warned)} simulation warning")


def test_a_run_saved_before_a_sac_field_existed_resumes_under_its_old_value(monkeypatch):
  """A state whose config lacks a SACConfig field added since resumes when the run asks for the
  behaviour it had (sac.ADDED_FIELDS), and names the field when it asks for another."""
  from hdt.agents import sac as sac_lib
  def info(**cfg):
    return dict(config=dict(total_env_steps=10, **cfg), seeds=[0], meta=dict(level="low"))
  monkeypatch.setattr(runner.ckpt, "load_state_info", lambda source: info())
  runner._check_resumable(Path("old"), info(**sac_lib.ADDED_FIELDS))
  with pytest.raises(ckpt.CheckpointError, match="critic_layer_norm: saved False, requested True"):
    runner._check_resumable(Path("old"), info(**(sac_lib.ADDED_FIELDS | {"critic_layer_norm": True})))


def test_an_alignment_saved_before_a_disc_field_existed_resumes_under_its_old_value(monkeypatch):
  """A run saved before a DiscConfig field existed ran with that field's earlier behaviour
  (disc_lib.ADDED_FIELDS): asking for that value resumes it, the new default is named as a difference.
  Checked once end to end: a point alignment written by 40024db (before expert_prev_obs) resumed with
  --disc-expert-prev-obs post_restart and repeated its final evaluation."""
  def info(**disc):
    return dict(config={"total_env_steps": 10}, seeds=[0],
                meta=dict(level="low", discriminator=dataclasses.asdict(DiscConfig(**disc))))
  saved = info()
  for field in disc_lib.ADDED_FIELDS:
    del saved["meta"]["discriminator"][field]
  monkeypatch.setattr(runner.ckpt, "load_state_info", lambda source: saved)
  legacy = {"discriminator": disc_lib.ADDED_FIELDS}  # align_stage's Stage.legacy_meta (test_defaults checks)
  runner._check_resumable(Path("old"), info(**disc_lib.ADDED_FIELDS), legacy_meta=legacy)
  with pytest.raises(ckpt.CheckpointError, match="expert_prev_obs: saved 'post_restart', requested 'pre_restart'"):
    runner._check_resumable(Path("old"), info(), legacy_meta=legacy)
