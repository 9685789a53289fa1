"""The paper's tables and figures (hdt.paper, ``hdt reproduce``): the cells they describe, the zoo
entries and commands behind them, and one table end to end at the smoke preset: written, then
reused by a second invocation without training or evaluating."""

import functools
import json
import shlex

import pytest

from hdt import cli, paper
from hdt.paper.runs import PRESETS, Finetune, Full, High, Low, Runs
from hdt.transfer import checkpoint as ckpt
from hdt.transfer import names
from hdt.transfer.card import PolicyCard
from hdt.transfer.finetune import start_fields

TABLES = {n: paper.load(n) for n in paper.NAMES}


def recipes(table, pr):
  return [r for part in table.parts(pr) for cell in part.cells for r in cell.runs.values()]


def test_the_tables_hold_the_papers_cells():
  shape = {name: [(p.name, len(p.rows), len(p.cols)) for p in t.parts(PRESETS["paper"])] for name, t in TABLES.items()}
  assert shape["table1"] == [("waypoint", 5, 5), ("maze_end", 5, 2), ("maze_sample", 5, 2), ("push1", 4, 4), ("insert", 3, 3)]
  assert shape["table2"] == [("waypoint", 3, 2), ("maze_end", 2, 2), ("maze_sample", 2, 2), ("push1", 4, 2),
                             ("push2", 4, 2), ("insert", 1, 2)]
  assert shape["table3"] == [("zero_shot", 2, 2), ("finetuning", 4, 1)]
  assert [p for p, *_ in shape["fig6"]] == ["ant_waypoint", "ant_maze_end", "ant_maze_sample", "quadruped_maze_sample"]
  assert all((rows, cols) == (5, 1) for _, rows, cols in shape["fig6"] + shape["fig7"])
  for name in ("table1", "table2", "table3"):  # every number the paper gives is beside hdt's
    assert all(c.paper for p in TABLES[name].parts(PRESETS["paper"]) for c in p.cells), name
  t1 = {TABLES["table1"].parts(PRESETS["paper"])[0].cell_id(c): c for c in TABLES["table1"].parts(PRESETS["paper"])[0].cells}
  assert t1["waypoint/ant/pm"].paper == "483 ± 39" and t1["waypoint/ant/pm"].high.low.agent == "point"


@pytest.mark.parametrize("name", paper.NAMES)
def test_zoo_entries_named_by_the_tables_exist_and_are_what_they_stand_for(name):
  for r in {r for pr in TABLES[name].presets.values() for r in recipes(TABLES[name], pr)}:
    if r.zoo is None:
      continue
    info = names.info_of(names.PREFIX + r.zoo)
    assert info is not None, f"{name}: zoo:{r.zoo} is not in the zoo"
    agent = r.agent if isinstance(r, (Low, Full)) else r.low.agent
    level = "high" if isinstance(r, (High, Finetune)) else "full" if isinstance(r, Full) else "low"
    assert (info["level"], info["agent"]) == (level, agent), r.zoo
    assert info["task"] == (r.task if level != "low" else "reach"), r.zoo
    if isinstance(r, Full):  # a flat policy is of one task variant (e.g. the maze's goal)
      assert info["task_options"] == dict(r.options), r.zoo


@functools.cache
def parser():
  return cli.build_parser()


def _cli_config(argv):
  """The SACConfig and options the CLI builds from a printed command."""
  args = parser().parse_args(argv)
  sets = cli._key_values(args.set, "--set")
  if args.cmd == "finetune":  # A's network and SAC kind, once A exists
    start = (start_fields(PolicyCard.from_json(ckpt.load_meta(args.high), args.high), args.task, args.kl_weight)
             if names.list_seeds(args.high) else {})
    return cli.sac_config(args, "finetune", task=args.task, **start), sets, args
  level = args.level if args.cmd == "train" else "low"
  return cli.sac_config(args, level, getattr(args, "agent", None), getattr(args, "task", None)), sets, args


@pytest.mark.parametrize("preset", ["smoke", "cpu", "paper"])
def test_each_runs_command_trains_exactly_its_recipe(preset, tmp_path):
  """What `hdt reproduce` prints for a run it does not train is a CLI command that builds the same
  config, options, seeds and directory as the table would; at the paper preset every run is a zoo
  entry or costs more than the limit (or needs one that does)."""
  checked = 0
  for name, table in TABLES.items():
    pr = table.presets[preset]
    runs = Runs(tmp_path / name, preset, pr)
    for r in recipes(table, pr):
      s = runs.plan(r)
      if s.status == "zoo":
        continue
      if preset == "paper":
        assert s.status == "not run" and ("--max-env-steps" in s.reason or s.reason.startswith("needs")), (r, s)
      argv = shlex.split(s.command)
      assert argv[0] == "hdt"
      cfg, sets, args = _cli_config(argv[1:])
      paths = {k: runs.plan(v).path for k, v in r.inputs.items()}
      assert cfg == r.configs(preset, pr, paths)[0], (name, r.name)
      want = r.options if isinstance(r, Low) else dict(r.options)
      assert sets == want and args.seeds == pr.seeds and str(args.out) == s.path == str(tmp_path / name / r.name)
      checked += 1
  # the paper preset checks only the runs the zoo does not hold yet, fewer as the zoo fills
  assert checked > (0 if preset == "paper" else 20)


def test_smoke_table_is_written_then_reused_without_training_or_evaluating(tmp_path, monkeypatch, capsys):
  out = tmp_path / "t1"
  argv = ["reproduce", "table1", "--preset", "smoke", "--only", "waypoint/pm/pm", "--out", str(out), "--quiet"]
  assert cli.main(argv) == 0
  table = json.loads((out / "table1_smoke.json").read_text())
  cells = {c["id"]: c for p in table["parts"] for c in p["cells"]}
  first = cells["waypoint/pm/pm"]
  assert first["status"] == "done" and first["episodes"] == 2 and first["paper"] == "1021 ± 43"
  assert cells["waypoint/ant/pm"]["status"] == "not selected"
  assert table["runs"]["point_low"]["status"] == "trained" and table["runs"]["point_high_waypoint"]["status"] == "trained"
  md = (out / "table1_smoke.md").read_text()
  assert "## Waypoint (return)" in md and "(1021 ± 43)" in md and "| point_low | point LL | trained:" in md
  assert (out / "table1_smoke.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

  from hdt.paper import table as table_module
  from hdt.transfer import runner

  def refuse(*a, **k):
    raise AssertionError("a second invocation trained or evaluated")

  monkeypatch.setattr(runner, "run_stage", refuse)
  monkeypatch.setattr(table_module, "_evaluate", refuse)
  assert cli.main(argv) == 0
  again = json.loads((out / "table1_smoke.json").read_text())
  assert {c["id"]: c for p in again["parts"] for c in p["cells"]}["waypoint/pm/pm"] == first
  assert {again["runs"][n]["status"] for n in ("point_low", "point_high_waypoint")} == {"reused"}
  # a cell whose run is over the limit: not run, with the command that trains it; the kept cell stays
  capsys.readouterr()
  assert cli.main(["reproduce", "table1", "--preset", "smoke", "--only", "waypoint/ant/pm", "--out", str(out),
                   "--max-env-steps", "0", "--quiet"]) == 0
  printed = capsys.readouterr().out
  third = {c["id"]: c for p in json.loads((out / "table1_smoke.json").read_text())["parts"] for c in p["cells"]}
  assert third["waypoint/pm/pm"] == first and third["waypoint/ant/pm"]["status"] == "not run"
  assert f"`hdt train low --agent ant --preset smoke --seeds 1 --out {out / 'ant_low'}`" in printed
  assert not (out / "ant_low").exists()


@pytest.mark.slow  # 7 trainings (A's LL and HL, B's LL, four methods): compile-bound, minutes here
def test_a_figure_panel_draws_every_methods_curve(tmp_path):
  done = paper.reproduce("fig7", "smoke", tmp_path / "f7", only=["pm_3link"], quiet=True)
  cells = {c["row"]: c for p in done.result["parts"] if p["name"] == "pm_3link" for c in p["cells"]}
  assert set(cells) == {"zero-shot", "finetune KL", "finetune", "HL scratch", "Full"}
  for method in ("finetune KL", "finetune", "HL scratch", "Full"):
    curve = cells[method]["curve"]
    assert curve["x"][0] == 0 and curve["x"][-1] == 96 * 35  # B's env steps: HL decisions x k, or Full's
    assert len(curve["y"]) == 1 and len(curve["y"][0]) == len(curve["x"])
  assert "curve" not in cells["zero-shot"] and done.files[-1].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
