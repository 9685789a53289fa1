"""The hdt command line end to end at a tiny budget: train -> checkpoint -> eval -> report."""

import csv
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from hdt.cli import COMMANDS, main

REPO = Path(__file__).resolve().parents[1]

TINY_LOW = ["--preset", "smoke", "--seeds", "2", "--quiet", "--total-env-steps", "800", "--steps-per-chunk", "50",
            "--hidden-sizes", "32", "32"]
TINY_HIGH = ["--preset", "smoke", "--seeds", "2", "--quiet", "--total-env-steps", "160", "--steps-per-chunk", "10",
             "--num-eval-episodes", "2"]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
  root = tmp_path_factory.mktemp("cli")
  assert main(["train", "low", "--agent", "point", "--out", str(root / "low"), *TINY_LOW]) == 0
  assert main(["train", "high", "--task", "waypoint", "--low", str(root / "low"), "--out", str(root / "high"),
               *TINY_HIGH]) == 0
  return root


def _numbers(path):
  with open(path) as f:
    rows = list(csv.DictReader(f))
  return [float(v) for r in rows for k, v in r.items() if k not in ("kind",) and v not in ("", None)]


def test_train_writes_run_directories(runs):
  for name in ("low", "high"):
    d = runs / name
    assert (d / "config.json").exists() and (d / "seed_0").is_dir() and (d / "seed_1").is_dir()
    meta = json.loads((d / "meta.json").read_text())
    assert meta["level"] == name and meta["seeds"] == [0, 1]
    assert len(_numbers(d / "metrics.csv")) > 10
    assert len(list((d / "tb").rglob("events.out.tfevents.*"))) == 2, "TensorBoard event files missing"
  assert json.loads((runs / "low" / "config.json").read_text())["total_env_steps"] == 800
  # budgets say their unit: LL env steps, HL decisions (the paper's)
  assert json.loads((runs / "low" / "config.json").read_text())["budget_unit"] == "env steps"
  assert json.loads((runs / "high" / "config.json").read_text())["budget_unit"] == "HL decisions"


def test_eval_and_report_hold_numbers(runs, capsys):
  out = runs / "eval"
  assert main(["eval", "--high", str(runs / "high"), "--low", str(runs / "low"), "--episodes", "2",
               "--out", str(out)]) == 0
  ev = json.loads((out / "eval_waypoint.json").read_text())
  assert len(ev["per_seed"]["return"]) == 2 and isinstance(ev["return_mean"], float)
  assert main(["report", str(runs / "high"), str(runs / "low")]) == 0
  for name in ("high", "low"):
    rep = (runs / name / "report" / "report.md").read_text()
    assert "±" in rep and "curve_return.png" in rep
    assert (runs / name / "report" / "curve_return.png").stat().st_size > 5000
  assert (runs / "high" / "report" / "trajectory.png").stat().st_size > 5000
  assert "| return |" in capsys.readouterr().out


def test_eval_of_best_params_says_so(runs, capsys):
  """Each seed keeps its best periodic evaluation beside its final params; the HL trained over the
  LL's best (as the authors compose) and records it; `hdt eval --params best` loads the HL's best."""
  for name in ("low", "high"):
    meta = json.loads((runs / name / "seed_1" / "meta.json").read_text())
    assert (runs / name / "seed_1" / "best" / "params").is_dir() and meta["best"]["env_steps"] > 0
  low_rec = json.loads((runs / "high" / "meta.json").read_text())["low"]
  assert low_rec["params"] == "best" and low_rec["params_env_steps"] > 0
  for which in ("best", "final"):
    out = runs / f"eval-{which}"
    assert main(["eval", "--high", str(runs / "high"), "--low", str(runs / "low"), "--episodes", "2",
                 "--params", which, "--out", str(out)]) == 0
    ev = json.loads((out / "eval_waypoint.json").read_text())
    assert ev["params"] == which and ev["low_params"] == "best"
    assert f"parameters: params {which}, low params best" in capsys.readouterr().out


def test_eval_matrix_writes_heatmap(runs, capsys):
  out = runs / "matrix"
  assert main(["eval", "--high", f"pm={runs / 'high'}", "--high", f"pm2={runs / 'high'}", "--low", f"pm={runs / 'low'}",
               "--episodes", "2", "--params", "best", "--out", str(out)]) == 0
  m = json.loads((out / "matrix_waypoint.json").read_text())
  assert set(m["cells"]) == {"pm|pm", "pm|pm2"}
  assert {tuple(v.values()) for v in m["params"].values()} == {("best", "best")}
  assert "parameters: HL best, LL best" in capsys.readouterr().out
  assert m["cells"]["pm|pm"][0] == m["cells"]["pm|pm2"][0]  # same runs, same episodes
  assert (out / "matrix_waypoint.png").stat().st_size > 5000
  # a zoo LL keeps one set of params (zoo:arm_point/low its final ones): the printed parameters are the ones
  # the cells used, not the ones asked for (--low-params best by default)
  zoo_out = runs / "matrix_zoo"
  assert main(["eval", "--high", "a=zoo:arm_point/push1", "--high", "b=zoo:arm_point/push1", "--low",
               "pm=zoo:arm_point/low", "--task", "push1", "--episodes", "1", "--out", str(zoo_out)]) == 0
  zm = json.loads((zoo_out / "matrix_push1.json").read_text())
  used = {tuple(v.values()) for v in zm["params"].values()}
  assert len(used) == 1 and "parameters: HL {}, LL {}".format(*used.pop()) in capsys.readouterr().out


def test_existing_run_is_not_overwritten(runs, capsys):
  before = (runs / "low" / "metrics.csv").read_text()
  assert main(["train", "low", "--agent", "point", "--out", str(runs / "low"), *TINY_LOW]) == 2
  err = capsys.readouterr().err
  assert "already holds a run" in err and "--resume" in err and len(err.strip().splitlines()) == 1
  assert (runs / "low" / "metrics.csv").read_text() == before


def test_mjx_is_imported_only_by_its_backend_and_quietly():
  """The native backend never imports mujoco.mjx (slow to import); the MJX backend does, muting its
  "Failed to import warp" notice on stdout (the CLI's output)."""
  code = ("import sys, hdt; assert 'mujoco.mjx' not in sys.modules; hdt.envs.make('point', 'reach'); "
          "assert 'mujoco.mjx' not in sys.modules; hdt.envs.make('point', 'reach', backend='mjx'); "
          "assert 'mujoco.mjx' in sys.modules")
  out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
  assert out.returncode == 0, out.stderr[-2000:]
  assert "Failed to import" not in out.stdout


def test_help_of_every_command():
  out = subprocess.run([sys.executable, "-m", "hdt.cli", "--help"], capture_output=True, text=True)
  assert out.returncode == 0 and all(c in out.stdout for c in COMMANDS)
  assert "Failed to import" not in out.stdout + out.stderr
  for argv in (["train", "low"], ["train", "high"], ["train", "full"], ["align"], ["finetune"], ["eval"],
               ["sweep"], ["reproduce"], ["report"], ["quickstart"]):
    with pytest.raises(SystemExit) as e:
      main([*argv, "--help"])
    assert e.value.code == 0


@pytest.mark.parametrize("argv, fragment", [
    (["train", "low"], "required: --agent"),
    (["train", "low", "--agent", "robot"], "unknown agent 'robot'"),
    (["train", "low", "--agent", "point", "--preset", "huge"], "invalid choice: 'huge'"),
    (["train", "low", "--agent", "point", "--batch-size", "many"], "invalid int value: 'many'"),
    (["train", "low", "--agent", "point", "--seeds", "0"], "--seeds 0"),
    (["train", "low", "--agent", "point", "--set", "gear"], "expected KEY=VALUE"),
    (["train", "high", "--task", "juggle", "--low", "x"], "unknown task 'juggle'"),
    (["train", "full", "--agent", "point", "--task", "push1"], "cannot run task 'push1'"),
    (["eval", "--task", "waypoint"], "give --high RUN and --low RUN"),
    (["sweep", "low", "--agent", "point", "--grid", "lr=1,2"], "not a SAC field"),
    (["frobnicate"], "invalid choice: 'frobnicate'"),
])
def test_bad_options_give_one_line_errors(argv, fragment, capsys, tmp_path):
  code = main([*argv, "--out", str(tmp_path / "run")] if argv[0] != "frobnicate" else argv)
  err = capsys.readouterr().err.strip()
  assert code != 0 and fragment in err, err
  assert len(err.splitlines()) == 1, err
  assert not (tmp_path / "run").exists()


def test_missing_checkpoint_is_a_clear_error(tmp_path, capsys):
  assert main(["train", "high", "--task", "waypoint", "--low", str(tmp_path / "nope"), "--out",
               str(tmp_path / "h"), "--preset", "smoke"]) == 1
  err = capsys.readouterr().err
  assert "does not exist" in err and not (tmp_path / "h").exists()


# ------------------------------------------------------------------------------------------------
# Bad inputs from the shell: one line naming the problem and the fix, a non-zero exit, no traceback,
# and no pre-existing file changed (content hash of the whole tree, and nothing new in the cwd).

import dataclasses  # noqa: E402
import hashlib  # noqa: E402
from pathlib import Path  # noqa: E402

import jax  # noqa: E402
import numpy as np  # noqa: E402

from hdt.transfer import checkpoint as ckpt  # noqa: E402
from hdt.transfer import names, zoo  # noqa: E402


def tree_hash(root: Path) -> dict:
  return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
          for p in sorted(root.rglob("*"))}


@pytest.fixture(scope="module")
def fakes(tmp_path_factory):
  """Run directories written without training (the checks read their metadata), and things that are
  not runs."""
  from hdt.envs import make
  from hdt.transfer import configs
  from hdt.transfer.card import PolicyCard
  root = tmp_path_factory.mktemp("fakes")
  cfg = configs.low_config("point", total_env_steps=400, num_envs=4, steps_per_chunk=25, batch_size=16,
                           buffer_size=1000, hidden_sizes=(16, 16), num_eval_episodes=2)
  w = {"w": np.zeros((2,), np.float32)}
  low_meta = PolicyCard.from_env(make("point", "reach"), "low", cfg, env_overrides={}).to_json()

  from hdt.agents import networks as nets
  policy = nets.make_sac_networks(low_meta["obs_size"], low_meta["action_size"],
                                  tuple(low_meta["hidden_sizes"])).policy_init(jax.random.PRNGKey(0))

  def run(name, meta, seed_meta=None):  # as hdt writes a run: marker, config.json, seeds, meta.json
    ckpt.save(root / name, 0, {"policy": policy, "q": w}, dict(seed_meta or meta, seed=0))
    ckpt.write_json_atomic(root / name / "config.json", dataclasses.asdict(cfg))
    ckpt.write_json_atomic(root / name / "meta.json", dict(meta, seeds=[0]))

  run("low", low_meta)
  run("high", low_meta | dict(level="high", task="waypoint", low=dict(path=str(root / "low"), seed_index=0)))
  run("k0_low", low_meta | dict(k=0))
  run("bad_types", low_meta, low_meta | dict(obs_size="x"))
  run("missing_keys", low_meta, {k: v for k, v in low_meta.items() if k != "hidden_sizes"})
  run("corrupt", low_meta)
  run("mixed", low_meta)
  ckpt.save(root / "mixed", 1, {"policy": policy, "q": w}, dict(low_meta, seed=1))  # a stale seed of an older run
  (root / "corrupt" / "seed_0" / "meta.json").write_text('{"level": "lo')
  ckpt.save_state(root / "bad_state", w, {}, dict(config=["not", "a", "dict"], seeds=[0], meta=low_meta))
  (root / "foreign").mkdir()
  (root / "foreign" / "notes.txt").write_text("my thesis")
  (root / "afile").write_text("not a directory")
  # edited cards: k of the wrong type, hidden sizes that are not the saved network's
  run("k_list", low_meta, low_meta | dict(k=[1, 2]))
  run("k_str", low_meta, low_meta | dict(k="32"))
  run("wrong_hidden", low_meta, low_meta | dict(hidden_sizes=[32, 32]))
  run("garbage_metrics", low_meta)
  (root / "garbage_metrics" / "metrics.csv").write_bytes(b"\x8f\x00garbage\xff" * 20)
  run("text_metrics", low_meta)
  (root / "text_metrics" / "metrics.csv").write_text("seed,kind,env_steps,eval/return\n0,eval,100,abc\n")
  # the user's own directories, which hdt must never take for its own
  (root / "user_meta").mkdir()
  (root / "user_meta" / "meta.json").write_text('{"level": "low", "agent": "point"}')
  (root / "user_meta" / "notes.txt").write_text("my results")
  (root / "cache_only" / ".cache.tmp").mkdir(parents=True)
  (root / "user_tables").mkdir()
  (root / "user_tables" / "table1_smoke.md").write_text("my own table")
  (root / "link_to_low").symlink_to(root / "low")
  return root


LOW = ["train", "low", "--agent", "point", "--preset", "smoke", "--quiet"]
HIGH = ["train", "high", "--task", "waypoint", "--preset", "smoke", "--quiet", "--low"]
EVAL = ["eval", "--high", "{high}", "--low", "{low}", "--episodes", "2"]
SWEEP = ["sweep", "low", "--agent", "point", "--preset", "smoke", "--quiet"]
FRESH = ["--out", "{new}"]

BAD_CLI = {
    # where output goes
    "empty --out": ([*LOW, "--out", ""], "--out is empty, which would write into the current directory"),
    "blank --out": ([*LOW, "--out", "  "], "--out is empty"),
    "--out not an hdt dir": ([*LOW, "--out", "{foreign}"], "is not an hdt directory and not empty (it holds notes.txt)"),
    "--out is a file": ([*LOW, "--out", "{afile}"], "is an existing file"),
    "--out under a file": ([*LOW, "--out", "{afile}/run"], "lies under the file"),
    "--out system dir": ([*LOW, "--out", "/usr/hdt-run"], "is a system directory"),
    "--out in /proc": ([*LOW, "--out", "/proc/hdt-run"], "is a system directory"),
    "--out root": ([*LOW, "--out", "/"], "is a system directory"),
    "existing run": ([*LOW, "--out", "{low}"], "already holds a run: pass --resume"),
    "resume and overwrite": ([*LOW, "--out", "{low}", "--resume", "--overwrite"], "pass one of them"),
    "resume nothing": ([*LOW, *FRESH, "--resume"], "holds no saved training state"),
    "resume a run without state": ([*LOW, "--out", "{low}", "--resume"], "holds no saved training state"),
    "resume damaged state.json": ([*LOW, "--out", "{bad_state}", "--resume"], "config=['not', 'a', 'dict']"),
    "overwrite a foreign dir": ([*LOW, "--out", "{foreign}", "--overwrite"], "is not an hdt directory"),
    "sweep into a run": ([*SWEEP, "--grid", "actor_lr=1e-3", "--out", "{low}"], "holds an hdt run directory where this command writes a sweep"),
    "sweep into a foreign dir": ([*SWEEP, "--grid", "actor_lr=1e-3", "--out", "{foreign}"], "not an hdt directory"),
    "quickstart into a foreign dir": (["quickstart", "--out", "{foreign}"], "not an hdt directory"),
    "quickstart into a file": (["quickstart", "--out", "{afile}"], "is an existing file"),
    "quickstart into a run": (["quickstart", "--out", "{low}"], "holds an hdt run directory where this command writes a quickstart"),
    "eval --out a file": ([*EVAL, "--out", "{afile}"], "is an existing file"),
    "eval --out foreign": ([*EVAL, "--out", "{foreign}"], "not an hdt directory"),
    "eval --out a run": ([*EVAL, "--out", "{k0_low}"], "holds an hdt run directory where this command writes an eval"),
    # --set values
    "--set not KEY=VALUE": ([*LOW, *FRESH, "--set", "gear"], "expected KEY=VALUE"),
    "--set text for a number": ([*LOW, *FRESH, "--set", "delta_max=abc"], "delta_max='abc': expected a finite number > 0"),
    "--set nan": ([*LOW, *FRESH, "--set", "delta_max=nan"], "delta_max='nan': expected a finite number"),
    "--set inf": ([*LOW, *FRESH, "--set", "reset_prob=inf"], "reset_prob='inf': expected a finite number"),
    "--set k=0 on an LL": ([*LOW, *FRESH, "--set", "k=0"], "k=0: expected an integer > 0"),
    "--set fractional k": ([*LOW, *FRESH, "--set", "k=2.5"], "k=2.5: expected an integer"),
    "--set negative box": ([*LOW, *FRESH, "--set", "delta_max=-1"], "delta_max=-1: expected a finite number > 0"),
    "--set number for a name": ([*HIGH, "{low}", *FRESH, "--task", "maze", "--set", "goal=3"], "goal=3: expected str"),
    "--set unknown option": ([*LOW, *FRESH, "--set", "wheels=4"], "unknown override"),
    "--set on eval": ([*EVAL, *FRESH, "--set", "hl_horizon=0"], "hl_horizon=0: expected an integer > 0"),
    # sizes and hyper-parameters
    "zero seeds": ([*LOW, *FRESH, "--seeds", "0"], "--seeds 0"),
    "negative seeds": ([*LOW, *FRESH, "--seeds", "-3"], "--seeds -3"),
    "seeds beyond memory": ([*LOW, *FRESH, "--seeds", "1000000000"], "GiB of memory are available: lower the number of seeds"),
    "buffer beyond memory": ([*LOW, *FRESH, "--buffer-size", "2000000000", "--batch-size", "16"], "GiB of memory"),
    "episodes beyond memory": ([*EVAL, *FRESH, "--episodes", "1000000000000"], "lower the number of episodes"),
    "zero episodes": ([*EVAL[:-2], *FRESH, "--episodes", "0"], "--episodes 0"),
    "non-numeric batch": ([*LOW, *FRESH, "--batch-size", "many"], "invalid int value: 'many'"),
    "zero batch": ([*LOW, *FRESH, "--batch-size", "0"], "batch_size=0: must be a positive integer"),
    "zero learning rate": ([*LOW, *FRESH, "--actor-lr", "0"], "actor_lr=0.0: learning rates must be positive"),
    "batch > buffer": ([*LOW, *FRESH, "--buffer-size", "8", "--batch-size", "16"], "batch_size=16 > buffer_size=8"),
    "unknown preset": ([*LOW, *FRESH, "--preset", "huge"], "invalid choice: 'huge'"),
    # agents, tasks, commands
    "unknown command": (["frobnicate"], "invalid choice: 'frobnicate'"),
    "missing agent": (["train", "low", *FRESH], "required: --agent"),
    "unknown agent": (["train", "low", "--agent", "robot", *FRESH], "unknown agent 'robot'"),
    "unknown task": ([*HIGH, "{low}", *FRESH, "--task", "juggle"], "unknown task 'juggle'"),
    "unsupported pair": (["train", "full", "--agent", "point", "--task", "push1", *FRESH], "cannot run task 'push1'"),
    # checkpoints handed between levels
    "missing LL": ([*HIGH, "{new}/nope", "--out", "{new}/h"], "does not exist"),
    "HL given as LL": ([*HIGH, "{high}", *FRESH], "where a low level was expected"),
    "LL with k=0": ([*HIGH, "{k0_low}", *FRESH], "trained with k=0"),
    "LL meta of wrong type": ([*HIGH, "{bad_types}", *FRESH], "has obs_size='x' (str)"),
    "LL meta missing a key": ([*HIGH, "{missing_keys}", *FRESH], "has no 'hidden_sizes'"),
    "corrupt LL meta": ([*HIGH, "{corrupt}", *FRESH], "corrupt checkpoint metadata"),
    "HL --k 0": ([*HIGH, "{low}", *FRESH, "--k", "0"], "--k 0: give a positive number"),
    "unknown --low-params": ([*HIGH, "{low}", *FRESH, "--low-params", "worst"], "invalid choice: 'worst'"),
    "LL seed out of range": ([*HIGH, "{low}", *FRESH, "--low-seed", "3"], "no checkpoint for seed 3"),
    "finetune from an LL": (["finetune", "--high", "{low}", "--low", "{low}", "--task", "waypoint", "--preset",
                             "smoke", *FRESH], "finetune_high needs an HL"),
    "negative KL": (["finetune", "--high", "{high}", "--low", "{low}", "--task", "waypoint", "--kl-weight", "-1",
                     "--preset", "smoke", *FRESH], "kl_weight=-1.0: the KL weight must be"),
    "align across families": (["align", "--agent", "arm3", "--imitate", "{low}", "--preset", "smoke", *FRESH],
                              "goal spaces differ"),
    "imitate an HL": (["align", "--agent", "point", "--imitate", "{high}", "--preset", "smoke", *FRESH],
                      "where a low level was expected"),
    # evaluation
    "eval without runs": (["eval", "--task", "waypoint", *FRESH], "give --high RUN and --low RUN"),
    "eval --policy and --high": (["eval", "--policy", "{low}", "--high", "{high}", *FRESH], "do not combine"),
    "eval LL as HL": (["eval", "--high", "{low}", "--low", "{low}", *FRESH], "compose needs an HL"),
    "eval unknown --params": ([*EVAL, *FRESH, "--params", "worst"], "invalid choice: 'worst'"),
    "eval missing seeds": ([*EVAL, *FRESH, "--seeds", "5"], "pick seed indices of the policy"),
    "eval unknown task": ([*EVAL, *FRESH, "--task", "nope"], "unknown task 'nope'"),
    "eval corrupt LL": (["eval", "--high", "{high}", "--low", "{corrupt}", *FRESH], "corrupt checkpoint metadata"),
    "eval a run with a stale seed": (["eval", "--high", "{high}", "--low", "{mixed}", *FRESH], "it mixes two runs"),
    "eval meta missing a key": (["eval", "--high", "{high}", "--low", "{missing_keys}", *FRESH], "has no 'hidden_sizes'"),
    # sweeps
    "grid not a SAC field": ([*SWEEP, *FRESH, "--grid", "lr=1,2"], "not a SAC field"),
    "grid text value": ([*SWEEP, *FRESH, "--grid", "actor_lr=abc"], "actor_lr='abc': expected a finite number"),
    "grid empty value": ([*SWEEP, *FRESH, "--grid", "actor_lr="], "actor_lr='': expected a finite number"),
    "grid trailing comma": ([*SWEEP, *FRESH, "--grid", "actor_lr=1e-3,"], "actor_lr='': expected"),
    "grid nan": ([*SWEEP, *FRESH, "--grid", "actor_lr=nan"], "actor_lr='nan': expected a finite number"),
    "grid fractional int": ([*SWEEP, *FRESH, "--grid", "batch_size=1.5"], "batch_size='1.5': expected an integer"),
    "grid tuple field": ([*SWEEP, *FRESH, "--grid", "hidden_sizes=32"], "tuple fields cannot be swept"),
    "grid field twice": ([*SWEEP, *FRESH, "--grid", "actor_lr=1e-3", "--grid", "actor_lr=1e-4"], "is given twice"),
    "grid without =": ([*SWEEP, *FRESH, "--grid", "actor_lr"], "expected FIELD=V1,V2"),
    "no grid": ([*SWEEP, *FRESH], "give at least one --grid"),
    "grid and option": ([*SWEEP, *FRESH, "--grid", "actor_lr=1e-3,3e-4", "--actor-lr", "1e-3"],
                        "--actor-lr is also swept by --grid"),
    "sweep without agent": (["sweep", "low", "--grid", "actor_lr=1e-3", *FRESH], "sweep low needs --agent"),
    "sweep high without LL": (["sweep", "high", "--task", "waypoint", "--grid", "actor_lr=1e-3", *FRESH],
                              "sweep high needs --low"),
    # never destroy an input, a zoo entry or a user's directory (each refusal before anything is written)
    "--out is the input LL": ([*HIGH, "{low}", "--out", "{low}", "--overwrite"],
                              "is the --low run {low} this command reads; writing there would destroy"),
    "--out is the input LL by a link": ([*HIGH, "{link_to_low}", "--out", "{low}", "--overwrite"],
                                        "is the --low run {low} this command reads"),
    "--out is the input HL": (["finetune", "--high", "{high}", "--low", "{low}", "--task", "waypoint", "--preset",
                               "smoke", "--out", "{high}", "--overwrite"], "is the --high run {high} this command reads"),
    "--out holds the input LL": ([*HIGH, "{low}", "--out", "{fakes}", "--overwrite"], "holds the --low run {low}"),
    "--out is the imitated LL": (["align", "--agent", "point", "--imitate", "{low}", "--preset", "smoke", "--out",
                                  "{low}", "--overwrite"], "is the --imitate run"),
    "--out inside a run": ([*LOW, "--out", "{low}/seed_0/nested"], "lies inside the hdt run directory {low}"),
    "--out in the zoo": ([*LOW, "--out", "{zoo}/point/low", "--overwrite"], "lies in the model zoo"),
    "--out a new entry in the zoo": ([*LOW, "--out", "{zoo}/point/mine"], "lies in the model zoo"),
    "--out a user dir with meta.json": ([*LOW, "--out", "{user_meta}", "--overwrite"],
                                        "is not an hdt directory and not empty (it holds meta.json, notes.txt)"),
    "--out holding only .cache.tmp": ([*LOW, "--out", "{cache_only}", "--overwrite"],
                                      "is not an hdt directory and not empty (it holds .cache.tmp/)"),
    "--out a link to a run": ([*LOW, "--out", "{link_to_low}", "--overwrite"], "is a symbolic link"),
    "reproduce into a user dir": (["reproduce", "table1", "--preset", "smoke", "--out",
                                   "{user_tables}"], "is not an hdt directory and not empty (it holds table1_smoke.md)"),
    "report of a user dir": (["report", "{user_meta}"], "is not an hdt directory"),
    "report of a zoo entry": (["report", "{zoo}/point/low"], "lies in the model zoo"),
    "report of garbage bytes": (["report", "{garbage_metrics}"], "metrics.csv is damaged (not CSV text"),
    "report of a garbage number": (["report", "{text_metrics}"], "metrics.csv is damaged (line 2 has eval/return='abc'"),
    # zoo names are names
    "zoo export up the tree": (["zoo", "export", "{low}", "--name", "../../..", "--overwrite", "--episodes", "2"],
                               "zoo name '../../..': a name is one or two parts"),
    "zoo export onto a user dir": (["zoo", "export", "{low}", "--name", "../../victim", "--overwrite"], "zoo name"),
    "zoo export the whole zoo": (["zoo", "export", "{low}", "--name", "point/..", "--overwrite"], "zoo name 'point/..'"),
    "zoo export an absolute path": (["zoo", "export", "{low}", "--name", "{new}"], "zoo name '/"),
    "zoo export a third level": (["zoo", "export", "{low}", "--name", "point/low/x"], "zoo name 'point/low/x'"),
    "zoo export 0 episodes": (["zoo", "export", "{low}", "--name", "t/new_entry", "--episodes", "0"], "--episodes 0"),
    "zoo export over an entry": (["zoo", "export", "{low}", "--name", "point/low"], "zoo entry 'point/low' exists"),
    "zoo: outside the zoo": (["eval", "--high", "zoo:../../somewhere", "--low", "{low}", *FRESH],
                             "zoo name '../../somewhere'"),
    # ranges, checked before anything is compiled
    "hidden sizes beyond memory": ([*LOW, *FRESH, "--hidden-sizes", "200000", "200000"],
                                   "networks [200000, 200000], replay buffer"),
    "eval episodes beyond memory": ([*LOW, *FRESH, "--num-eval-episodes", "100000000"], "GiB of memory"),
    "zero envs": ([*LOW, *FRESH, "--num-envs", "0"], "num_envs=0: must be a positive integer"),
    "budget past int32": ([*LOW, *FRESH, "--total-env-steps", "4294967600"], "must be below 2**31"),
    "learning starts past the budget": ([*LOW, *FRESH, "--learning-starts", "1000000"],
                                        "learning_starts=1000000 >= total_env_steps=2000"),
    "finetune learning starts past the budget": (["finetune", "--high", "{high}", "--low", "{low}", "--task", "waypoint",
                                                  "--preset", "smoke", *FRESH, "--learning-starts", "400"],
                                                 "learning_starts=400 >= total_env_steps=400"),
    "anneal fraction 2": (["finetune", "--high", "{high}", "--low", "{low}", "--task", "waypoint", "--preset", "smoke",
                           *FRESH, "--anneal-frac", "2"], "anneal_frac=2.0: must be in [0, 1]"),
    "sweep anneal fraction -1": (["sweep", "finetune", "--high", "{high}", "--low", "{low}", "--task", "waypoint",
                                  "--grid", "kl_weight=0,1", "--anneal-frac", "-1", *FRESH], "anneal_frac=-1.0"),
    "grid value twice": ([*SWEEP, *FRESH, "--grid", "actor_lr=1e-3,0.001"], "lists the value 0.001 twice"),
    "eval names twice": (["eval", "--high", "A={high}", "--high", "A={high}", "--low", "{low}", *FRESH],
                         "two runs are named 'A'"),
    # cards checked by type on load
    "LL meta k a list": ([*HIGH, "{k_list}", *FRESH], "has k=[1, 2] (list)"),
    "LL meta k a string": ([*HIGH, "{k_str}", *FRESH], "has k='32' (str)"),
    "LL meta hidden sizes not the network's": ([*HIGH, "{wrong_hidden}", *FRESH],
                                               "does not match its metadata (hidden_sizes=[32, 32]"),
    "HL meta k a list": (["finetune", "--high", "{k_list}", "--low", "{low}", "--task", "waypoint", *FRESH],
                         "has k=[1, 2] (list)"),
}


@pytest.mark.parametrize("case", list(BAD_CLI))
def test_bad_cli_input_is_one_line_and_changes_nothing(case, fakes, tmp_path, capsys, monkeypatch):
  argv, fragment = BAD_CLI[case]
  cwd = tmp_path / "cwd"
  cwd.mkdir()
  monkeypatch.chdir(cwd)  # default --out directories would appear here
  paths = {p.name: str(p) for p in fakes.iterdir()} | {"new": str(tmp_path / "new"), "fakes": str(fakes),
                                                      "zoo": str(names.ZOO_DIR)}
  argv, fragment = [a.format(**paths) for a in argv], fragment.format(**paths)
  touches_zoo = any("zoo" in a for a in argv)
  before, zoo_before = tree_hash(fakes), tree_hash(names.ZOO_DIR) if touches_zoo else None
  code = main(argv)
  err = capsys.readouterr().err.strip()
  assert code != 0 and fragment in err, err
  assert len(err.splitlines()) == 1 and "Traceback" not in err, err
  assert "internal error" not in err, err  # each case has its own message, not the catch-all
  assert not ("not an hdt directory" in err and "overwrite" in err), err  # never advice to destroy the user's
  assert tree_hash(fakes) == before
  assert zoo_before is None or tree_hash(names.ZOO_DIR) == zoo_before
  assert not (tmp_path / "new").exists() and not any(cwd.iterdir())


def test_bad_cli_table_is_large():
  assert len(BAD_CLI) >= 60


# ------------------------------------------------------------------------------------------------
# Resume, dependencies, sweep paths, Ctrl-C.

import os  # noqa: E402
import shutil  # noqa: E402
import signal  # noqa: E402


def test_cli_resumes_a_state_left_as_state_old(runs, tmp_path, capsys):
  run = tmp_path / "low"
  shutil.copytree(runs / "low", run)
  os.replace(run / "state", run / "state.old")  # killed between the two renames of the last save
  (run / "meta.json").unlink()
  assert main(["train", "low", "--agent", "point", "--out", str(run), "--resume", *TINY_LOW]) == 0
  assert (run / "meta.json").exists() and (run / "state").is_dir() and not (run / "state.old").exists()
  assert ckpt.load(run, 1)[1]["seed"] == 1


def _rewrite_low_path(high: Path, low: Path) -> None:
  """Points a copied HL's recorded LL at a copied LL (same bytes, so the same content hash)."""
  for path in [*high.glob("seed_*/meta.json"), high / "meta.json", high / "state" / "state.json"]:
    obj = json.loads(path.read_text())
    meta = obj["meta"] if "meta" in obj and path.name == "state.json" else obj
    meta["low"]["path"] = str(low)
    if path == high / "meta.json":  # the seeds' files changed: record their new hashes
      meta[ckpt.SEED_HASHES] = [ckpt.content_hash(high, i) for i in range(len(meta["seeds"]))]
    ckpt.write_json_atomic(path, obj)


def test_eval_and_resume_refuse_an_hl_whose_ll_changed(runs, tmp_path, capsys):
  low, high = tmp_path / "low", tmp_path / "high"
  shutil.copytree(runs / "low", low)
  shutil.copytree(runs / "high", high)
  _rewrite_low_path(high, low)
  ev = ["eval", "--high", str(high), "--low", str(low), "--episodes", "2", "--out", str(tmp_path / "ev")]
  assert main(ev) == 0
  seed_meta = low / "seed_0" / "meta.json"  # "retrain" the LL: its checkpoint's bytes change
  ckpt.write_json_atomic(seed_meta, json.loads(seed_meta.read_text()) | {"retrained": True})
  run_meta = json.loads((low / "meta.json").read_text())  # as a retraining rewrites it: the new hashes
  ckpt.write_json_atomic(low / "meta.json", run_meta | {ckpt.SEED_HASHES: [ckpt.content_hash(low, i) for i in
                                                                           range(len(run_meta["seeds"]))]})
  capsys.readouterr()
  assert main(ev) == 1
  err = capsys.readouterr().err.strip()
  assert "changed after the HL" in err and "retrain the HL" in err and len(err.splitlines()) == 1
  before = tree_hash(high)
  assert main(["train", "high", "--task", "waypoint", "--low", str(low), "--out", str(high), "--resume",
               *TINY_HIGH]) == 1
  err = capsys.readouterr().err.strip()
  assert "a checkpoint it depends on changed since it started (low content hash differs" in err, err
  assert tree_hash(high) == before


def test_an_hl_that_records_no_ll_hash_is_refused_over_an_ll_whose_seed_was_replaced(runs, tmp_path, capsys):
  """The LL's own meta.json records its seeds' hashes: an HL composed over it learns that its seed_0 is
  another run's even when the HL (as runs of older hdt versions) recorded no hash of it."""
  low, high = tmp_path / "low", tmp_path / "high"
  shutil.copytree(runs / "low", low)
  shutil.copytree(runs / "high", high)
  for path in [*high.glob("seed_*/meta.json"), high / "meta.json"]:  # an HL that recorded no hash of its LL
    meta = json.loads(path.read_text())
    meta["low"].pop("sha256")
    ckpt.write_json_atomic(path, meta)
  _rewrite_low_path(high, low)
  shutil.rmtree(low / "seed_0")
  shutil.copytree(low / "seed_1", low / "seed_0")
  before = tree_hash(tmp_path)
  assert main(["eval", "--high", str(high), "--low", str(low), "--episodes", "2", "--out", str(tmp_path / "ev")]) == 1
  err = capsys.readouterr().err.strip()
  assert f"the checkpoint {low / 'seed_0'} is not the one {low / 'meta.json'} records (its content hash differs" in err
  assert len(err.splitlines()) == 1 and tree_hash(tmp_path) == before


def test_sweep_sac_options_apply_to_every_grid_point(monkeypatch, tmp_path):
  """`hdt sweep` takes `hdt train`'s SAC options: fixed for every point, the grid's field varying."""
  from types import SimpleNamespace
  from hdt.transfer import sweep as sweep_mod
  seen = []

  def fake_sweep(level, runs, options, **kw):  # what would be trained, without training it
    seen.extend(runs)
    return [SimpleNamespace(history={"eval/success_max": np.zeros((options.seeds, 1))}) for _ in runs]

  monkeypatch.setattr(sweep_mod, "sweep", fake_sweep)
  assert main(["sweep", "low", "--agent", "arm3", "--preset", "smoke", "--quiet", "--grid", "target_entropy=-3,-9",
               "--num-envs", "4", "--batch-size", "8", "--out", str(tmp_path / "sw")]) == 0
  assert [c.target_entropy for c, _, _ in seen] == [-3, -9]
  assert {(c.num_envs, c.batch_size) for c, _, _ in seen} == {(4, 8)}


def test_named_runs_accept_paths_with_equals(tmp_path):
  from hdt.cli import named_runs
  sweep_run = tmp_path / "sweep" / "actor_lr=0.001,batch_size=16"
  sweep_run.mkdir(parents=True)
  assert named_runs([str(sweep_run)]) == {sweep_run.name: sweep_run}
  assert named_runs([f"pm={sweep_run}"]) == {"pm": sweep_run}
  assert named_runs(["pm=runs/x"]) == {"pm": Path("runs/x")}


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_ctrl_c_or_sigterm_saves_the_chunk_under_way_and_exits_with_a_resume_hint(sig, code, tmp_path):
  """Stopped between save points (every 10% of the budget), a run keeps the chunk it was in, not only
  the last save point, and says how to resume, in one line."""
  import re
  out = tmp_path / "run"
  env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(Path(ckpt.__file__).parents[2]),
                                                      os.environ.get("PYTHONPATH", "")]))
  argv = [sys.executable, "-m", "hdt.cli", "train", "low", "--agent", "point", "--out", str(out),
          *[a for a in TINY_LOW if a != "--quiet"], "--total-env-steps", "80000"]
  # SIG_DFL in the child: a shell's background job (e.g. CI under nohup) would pass SIGINT on ignored.
  p = subprocess.Popen(argv, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env,
                       preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
  try:
    for line in iter(p.stderr.readline, ""):
      m = re.search(r"(\d+)/80000 steps", line)
      if m and "ETA" in line and int(m.group(1)) % 8000 and ckpt.has_state(out):
        at = int(m.group(1))  # past a save point (8000), before the next
        break
    p.send_signal(sig)
    _, rest = p.communicate(timeout=300)
  finally:
    p.kill()
  assert p.returncode == code, rest
  lines = [l for l in rest.strip().splitlines() if "ETA" not in l]
  assert len(lines) == 1 and "Traceback" not in rest, rest
  assert lines[0].startswith("hdt: interrupted;") and "--resume" in lines[0] and str(out) in lines[0]
  assert ckpt.has_state(out) and not list(out.glob(".*.tmp")) and "Failed to import" not in rest
  assert not (out / "meta.json").exists() and (out / "metrics.csv").exists()  # unfinished, its curves so far kept
  steps = ckpt.load_state_info(out)["env_steps"]
  assert steps >= at and f"({steps} env steps)" in lines[0]
  assert f"or with --resume --total-env-steps {steps} to end it there" in lines[0]
  if sig == signal.SIGTERM:  # the hint's second command ends the run at its save, whole
    done = subprocess.run(argv[:-1] + [str(steps), "--resume"], capture_output=True, text=True, env=env, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert (out / "meta.json").exists() and ckpt.load_state_info(out)["env_steps"] == steps


@pytest.mark.parametrize("after", [0.3, 1.0])
def test_ctrl_c_in_the_first_seconds_exits_130_and_writes_nothing(tmp_path, after):
  """While Python still imports JAX (the first seconds) Ctrl-C was lost or a traceback: now it is the
  same one line and exit 130 (the imports finish first: an import interrupted half way can crash)."""
  import time
  out = tmp_path / "run"
  env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(Path(ckpt.__file__).parents[2]),
                                                      os.environ.get("PYTHONPATH", "")]))
  p = subprocess.Popen([sys.executable, "-m", "hdt.cli", "train", "low", "--agent", "point", "--out", str(out),
                        *TINY_LOW], stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env,
                       preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
  try:
    time.sleep(after)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=300)
  finally:
    p.kill()
  assert p.returncode == 130 and err.strip() == "hdt: interrupted; nothing was written", err[-3000:]
  assert not out.exists()


def test_a_corrupt_checkpoint_is_one_line_with_no_library_traceback_at_exit(fakes, tmp_path):
  """orbax's threads and asyncio loops print tracebacks at interpreter exit after a failed restore:
  the command ends with its one line."""
  run = tmp_path / "run"
  shutil.copytree(fakes / "low", run)
  for f in (run / "seed_0" / "params").rglob("*"):
    if f.is_file() and f.parent.name == "d":
      f.write_bytes(b"\x00garbage" * 8)
  env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(Path(ckpt.__file__).parents[2]),
                                                      os.environ.get("PYTHONPATH", "")]))
  out = subprocess.run([sys.executable, "-m", "hdt.cli", "eval", "--policy", str(run), "--episodes", "1", "--out",
                        str(tmp_path / "ev")], capture_output=True, text=True, env=env, cwd=tmp_path)
  assert out.returncode == 1 and len(out.stderr.strip().splitlines()) == 1, out.stderr[-3000:]
  assert out.stderr.startswith("hdt: error: corrupt checkpoint parameters in") and not (tmp_path / "ev").exists()


# -- bring your own robot (ROBOTS.md): robots that exist only as an MJCF file ----------------------

ROBOTS = REPO / "examples" / "robots"


# One seed, two chunks, one evaluation episode: compiling dominates (each run is a new program).
ROBOT_LOW = ["--preset", "smoke", "--seeds", "1", "--quiet", "--total-env-steps", "400", "--steps-per-chunk", "50",
             "--hidden-sizes", "32", "32", "--num-eval-episodes", "1"]


def _robot_low_and_zero_shot(runs, robot, high, task):
  """An LL of the robot file at the smoke preset, then the point-mass HL in ``high`` zero-shot on it
  through `hdt eval --high --low`."""
  xml = ROBOTS / f"{robot}.xml"
  low = runs / f"{robot}_low"
  assert main(["train", "low", "--agent", str(xml), "--out", str(low), *ROBOT_LOW]) == 0
  meta = json.loads((low / "meta.json").read_text())
  assert meta["agent"] == str(xml.resolve()) and len(meta["robot_sha256"]) == 64
  out = runs / f"eval_{robot}"
  assert main(["eval", "--high", str(high), "--low", str(low), "--task", task, "--episodes", "1",
               "--out", str(out)]) == 0
  ev = json.loads((out / f"eval_{task}.json").read_text())
  assert ev["per_seed"]["return"] and all(map(math.isfinite, ev["per_seed"]["return"]))
  return low


def test_hexapod_file_trained_transferred_to_and_aligned(runs):
  """The hexapod exists only as examples/robots/hexapod.xml: its LL, the PM Waypoint HL on it, and
  its LL aligned to the point mass's (`hdt align`)."""
  _robot_low_and_zero_shot(runs, "hexapod", runs / "high", "waypoint")
  aligned = runs / "hexapod_aligned"
  assert main(["align", "--agent", str(ROBOTS / "hexapod.xml"), "--imitate", str(runs / "low"),
               "--out", str(aligned), "--n-offline", "100", *ROBOT_LOW]) == 0
  meta = json.loads((aligned / "meta.json").read_text())
  assert meta["aligned_to"]["agent"] == "point" and meta["agent"].endswith("hexapod.xml")


@pytest.mark.slow  # three more programs to compile (~4 min under load): `pytest -m slow`
def test_arm5_file_trained_and_transferred_to(runs):
  """The 5-link arm exists only as examples/robots/arm5.xml: its LL, and an arm_point HL on
  BlockPush 1 (trained here at a tiny budget) on it."""
  arm_low, arm_high = runs / "arm_point_low", runs / "arm_point_high"
  assert main(["train", "low", "--agent", "arm_point", "--out", str(arm_low), *ROBOT_LOW]) == 0
  assert main(["train", "high", "--task", "push1", "--low", str(arm_low), "--out", str(arm_high),
               *TINY_HIGH[:3], "1", *TINY_HIGH[4:]]) == 0
  _robot_low_and_zero_shot(runs, "arm5", arm_high, "push1")


def test_broken_robot_file_is_a_one_line_error(tmp_path, capsys):
  bad = tmp_path / "robot.xml"
  bad.write_text((ROBOTS / "arm5.xml").read_text().replace('<site name="goal_point" pos="0 0 0" size="0.005"/>', ""))
  assert main(["train", "low", "--agent", str(bad), "--out", str(tmp_path / "run"), "--preset", "smoke"]) == 1
  err = capsys.readouterr().err.strip()
  assert "no site named 'goal_point'" in err and "ROBOTS.md" in err and len(err.splitlines()) == 1, err
  assert not (tmp_path / "run").exists()


def test_resume_with_a_larger_budget_extends_a_finished_run_exactly(runs, tmp_path, capsys):
  run, straight = tmp_path / "low", tmp_path / "straight"
  shutil.copytree(runs / "low", run)  # finished at 800 env steps
  longer = [a if a != "800" else "1200" for a in TINY_LOW]
  assert main(["train", "low", "--agent", "point", "--out", str(run), "--resume", *longer]) == 0
  assert main(["train", "low", "--agent", "point", "--out", str(straight), *longer]) == 0
  assert json.loads((run / "config.json").read_text())["total_env_steps"] == 1200
  drop_time = lambda path: [r for r in csv.DictReader(open(path))]
  a, b = drop_time(run / "metrics.csv"), drop_time(straight / "metrics.csv")
  assert len(a) == len(b) and len(a) > 0
  for ra, rb in zip(a, b):
    assert {k: v for k, v in ra.items() if k != "walltime"} == {k: v for k, v in rb.items() if k != "walltime"}
  for i in (0, 1):
    pa, pb = ckpt.load(run, i)[0], ckpt.load(straight, i)[0]
    assert all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(pa), jax.tree.leaves(pb)))
  # a budget below what was trained is refused in one line
  assert main(["train", "low", "--agent", "point", "--out", str(run), "--resume", *TINY_LOW]) != 0
  assert "already trained 1200 env steps" in capsys.readouterr().err


def test_finetune_takes_the_papers_beta_and_learning_rate_of_the_task(monkeypatch, tmp_path):
  # Paper, Appendix: beta 1 and lr 0.01 for Waypoint and manipulation; Maze/Steps beta 0.01, lr 0.001.
  import hdt.transfer.finetune as ft
  seen = {}

  class Result:
    history, run_dir, best = {}, tmp_path, None

  def fake(high, low, task, config, spec, **kw):
    seen.clear()
    seen.update(kw, task=task, config=config, kl_weight=spec.kl_weight, lr=spec.lr)
    return Result

  monkeypatch.setattr(ft, "finetune_high", fake)
  run = lambda high, task, *extra: main(["finetune", "--high", high, "--low", "zoo:point/low", "--task", task,
                                         "--preset", "smoke", "--quiet", "--out", str(tmp_path / "o"), *extra])
  lrs = lambda: (seen["config"].actor_lr, seen["config"].critic_lr, seen["config"].alpha_lr)
  assert run("zoo:point/waypoint", "waypoint") == 0 and seen["kl_weight"] == 1.0 and lrs() == (1e-2,) * 3
  assert run("zoo:point/maze", "maze") == 0 and seen["kl_weight"] == 0.01 and lrs() == (1e-3,) * 3
  assert run("zoo:point/maze", "maze", "--kl-weight", "0", "--lr", "5e-3") == 0
  assert (seen["kl_weight"], seen["lr"]) == (0.0, 5e-3)
  assert run("zoo:point/maze", "maze", "--kl", "0.5") == 0 and seen["kl_weight"] == 0.5  # --kl: the same option
  assert run("zoo:point/maze", "maze", "--actor-lr", "2e-3") == 0 and seen["lr"] is None
  assert lrs() == (2e-3, 1e-3, 1e-3)  # the other two: the task's
  # `hdt sweep finetune` takes the same defaults; a gridded learning rate is the grid's.
  from hdt.transfer import sweep as sweep_mod
  monkeypatch.setattr(sweep_mod, "sweep", lambda level, runs, *a, **k: seen.update(runs=runs) or 1 / 0)
  sweep = lambda *grid: main(["sweep", "finetune", "--high", "zoo:point/maze", "--low", "zoo:point/low", "--task",
                              "maze", "--preset", "smoke", "--quiet", "--out", str(tmp_path / "sw"), *grid])
  sweep("--grid", "kl_weight=0,1")
  assert [(c.actor_lr, c.critic_lr) for c, _, _ in seen["runs"]] == [(1e-3, 1e-3)] * 2
  sweep("--grid", "actor_lr=1e-4,1e-2", "--overwrite")
  assert [(c.actor_lr, c.critic_lr) for c, _, _ in seen["runs"]] == [(1e-4, 1e-3), (1e-2, 1e-3)]
