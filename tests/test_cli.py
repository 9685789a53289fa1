"""The hdt command line end to end at a tiny budget: train -> checkpoint -> eval -> report."""

import csv
import json
import subprocess
import sys

import pytest

from hdt.cli import COMMANDS, main

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


def test_eval_matrix_writes_heatmap(runs):
  out = runs / "matrix"
  assert main(["eval", "--high", f"pm={runs / 'high'}", "--high", f"pm2={runs / 'high'}", "--low", f"pm={runs / 'low'}",
               "--episodes", "2", "--out", str(out)]) == 0
  m = json.loads((out / "matrix_waypoint.json").read_text())
  assert set(m["cells"]) == {"pm|pm", "pm|pm2"}
  assert m["cells"]["pm|pm"][0] == m["cells"]["pm|pm2"][0]  # same runs, same episodes
  assert (out / "matrix_waypoint.png").stat().st_size > 5000


def test_existing_run_is_not_overwritten(runs, capsys):
  before = (runs / "low" / "metrics.csv").read_text()
  assert main(["train", "low", "--agent", "point", "--out", str(runs / "low"), *TINY_LOW]) == 2
  err = capsys.readouterr().err
  assert "already holds a run" in err and "--resume" in err and len(err.strip().splitlines()) == 1
  assert (runs / "low" / "metrics.csv").read_text() == before


def test_help_of_every_command():
  out = subprocess.run([sys.executable, "-m", "hdt.cli", "--help"], capture_output=True, text=True)
  assert out.returncode == 0 and all(c in out.stdout for c in COMMANDS)
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
