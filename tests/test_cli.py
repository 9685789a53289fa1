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
