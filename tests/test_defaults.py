"""The one table of defaults (hdt.transfer.configs): budgets refused rather than rounded, unknown tasks
refused, the CLI, the Python API and hdt reproduce build the same configs (tests/test_paper.py), tasks own
their metrics. No training: every test takes seconds."""

import dataclasses

import jax
import pytest

from hdt import cli
from hdt.envs.agents import AGENTS
from hdt.envs.tasks import TASKS, get_task
from hdt.transfer import configs





# -- budgets --------------------------------------------------------------------------------------
def test_budget_that_does_not_divide_is_refused_not_rounded():
  with pytest.raises(ValueError, match="set total_env_steps to 704000 or 696000"):
    configs.low_config("point", num_envs=8, total_env_steps=700_000)
  with pytest.raises(ValueError, match="multiple of num_envs=8"):
    configs.high_config("waypoint", num_envs=8, total_env_steps=6001, steps_per_chunk=75)
  # what divides is kept exactly
  assert configs.low_config("point", num_envs=8, total_env_steps=704_000).total_env_steps == 704_000
  assert configs.replace(configs.high_config("maze"), total_env_steps=3000).total_env_steps == 3000


def test_cli_refuses_a_budget_in_one_line(tmp_path, capsys):
  out = tmp_path / "low"
  assert cli.main(["train", "low", "--agent", "point", "--preset", "paper", "--num-envs", "8",
                   "--total-env-steps", "700000", "--out", str(out), "--quiet"]) == 1
  err = capsys.readouterr().err.strip()
  assert len(err.splitlines()) == 1 and "704000 or 696000" in err and "--total-env-steps" in err, err
  assert not out.exists()


def test_chunk_for_refuses_uneven_evaluations():
  assert configs.chunk_for(1480, 8, 5) == 37
  with pytest.raises(ValueError, match="e.g. 1480 or 1520"):
    configs.chunk_for(1500, 8, 5)


def test_unknown_task_is_refused_everywhere():
  for build in (lambda: configs.high_config("nope"), lambda: configs.full_config("point", "nope"),
                lambda: configs.config("high", "cpu", task="nope"), lambda: configs.finetune_params("nope"),
                lambda: get_task("nope")):
    with pytest.raises(ValueError, match="unknown task 'nope'; choose one of reach, waypoint"):
      build()
  with pytest.raises(ValueError, match="'reach' has no HL budget"):
    configs.high_config("reach")


def test_budgets_are_not_env_options():
  from hdt.envs import make
  with pytest.raises(ValueError, match="ll_budget is the LL's training budget.*--total-env-steps"):
    make("point", "reach", ll_budget=10)
  with pytest.raises(ValueError, match="unknown override"):
    make("point", "waypoint", hl_budget=10)  # class data of the task, not a field


def test_defaults_are_data_on_agents_and_tasks():
  assert configs.low_config("ant").total_env_steps == AGENTS["ant"].ll_budget == 2_500_000
  assert configs.low_config("arm3").total_env_steps == AGENTS["arm3"].ll_budget == 1_200_000
  assert configs.low_config("point").total_env_steps == AGENTS["point"].ll_budget == 200_000
  for name in TASKS:
    task = get_task(name)
    if task.hl_budget:
      assert configs.high_config(name).total_env_steps == task.hl_budget
      assert configs.full_config("point" if task.family == "nav" else "arm3", name).total_env_steps == task.hl_budget
      assert configs.finetune_params(name) == dict(kl_weight=task.finetune_kl_weight, lr=task.finetune_lr)
  assert configs.finetune_params("maze") == dict(kl_weight=0.01, lr=1e-3)
  assert configs.finetune_params("push1") == dict(kl_weight=1.0, lr=1e-2)


# -- one table for the CLI, the Python API and hdt reproduce (tests/test_paper.py) -------------------
def _cli_config(level, preset, agent=None, task=None):
  argv = {"low": ["train", "low", "--agent", agent], "full": ["train", "full", "--agent", agent, "--task", task],
          "high": ["train", "high", "--task", task, "--low", "unused"]}[level]
  args = cli.build_parser().parse_args(argv + ["--preset", preset])
  return cli.sac_config(args, level, agent, task)


def test_paper_preset_runs_the_authors_sb2_sac_and_the_others_twin_q():
  for level, kw in (("low", dict(agent="arm3")), ("high", dict(task="push1")), ("full", dict(agent="ant", task="maze"))):
    assert configs.config(level, "paper", **kw).value_net, level
    assert not configs.config(level, "cpu", **kw).value_net, level
    assert _cli_config(level, "paper", **kw).value_net
  args = cli.build_parser().parse_args(["train", "low", "--agent", "point", "--preset", "paper", "--value-net", "false"])
  assert not cli.sac_config(args, "low", agent="point").value_net
  # booleans are parsed once, by the CLI; the configs refuse anything else
  from hdt.agents.discriminator import DiscConfig
  args = cli.build_parser().parse_args(["align", "--agent", "arm3", "--imitate", "x", "--disc-include-z", "false"])
  assert cli._overrides(args, DiscConfig, "disc_") == {"include_z": False}
  with pytest.raises(ValueError, match="include_z='false' must be True or False"):
    DiscConfig(include_z="false")


def test_align_discriminator_defaults_come_from_a_in_cli_api_and_experiments():
  """One place for the discriminator's defaults: the paper's values by A (configs.disc_config), whether the
  alignment is started from the CLI, the API or hdt reproduce (the CLI once used the class's nav values)."""
  from hdt.transfer.align import align_stage
  parse = lambda *extra: cli.build_parser().parse_args(["align", "--agent", "arm3", "--imitate", "x", *extra])
  for a, want in (("arm_point", (3e-4, 0.4, "online")), ("arm3", (5e-4, 0.4, "online")), ("point", (2e-4, 0.3, "offline"))):
    d = cli._disc(parse(), a)
    assert (d.lr, d.weight, d.data) == want == (lambda c: (c.lr, c.weight, c.data))(configs.disc_config(a)), a
  d = cli._disc(parse("--disc-lr", "1e-3", "--disc-data", "offline"), "arm_point")
  assert (d.lr, d.weight, d.data) == (1e-3, 0.4, "offline")  # options override A's values, field by field
  stage = align_stage("arm3", "zoo:arm_point/low", configs.low_config("arm3", total_env_steps=64, num_envs=4,
                                                                     steps_per_chunk=16))
  assert stage.card.extra["discriminator"] == dataclasses.asdict(configs.disc_config("arm_point"))
  # fields added since older alignments were saved, with the values those ran under (resume back-fill)
  from hdt.agents.discriminator import ADDED_FIELDS
  assert stage.legacy_meta == {"discriminator": ADDED_FIELDS} and set(ADDED_FIELDS) <= set(stage.card.extra["discriminator"])


def test_cli_presets_are_the_configs_table():
  assert cli.PRESETS == tuple(configs.PRESETS)
  assert "2.5M" in configs.describe_paper_budgets() and "500k push1" in configs.describe_paper_budgets()


# -- metrics ----------------------------------------------------------------------------------------
def test_tasks_declare_headline_and_hl_step_reductions():
  assert get_task("waypoint").headline == "return" and get_task("waypoint").headline_column == "eval/return"
  for name in ("maze", "steps", "push1", "push2", "insert", "reach"):
    assert get_task(name).headline_column == "eval/success_max", name
  assert get_task("waypoint").reduction("waypoints") == "sum"
  assert get_task("maze").reduction("success") == "last" and get_task("maze").reduction("fall") == "max"
  assert get_task("push1").reduction("dist") == "mean"


def test_kl_term_is_logged_as_kl():
  """A regularising plug-in's term and weight are logged under its name: the KL plug-in's as kl and
  kl_weight (the name of its weight from the CLI to the metric column); no regulariser, no column."""
  from toy_env import PointGoal
  from hdt.agents import train as sac_train
  from hdt.agents.kl import kl_plugin
  from hdt.agents.sac import SACConfig
  env, cfg = PointGoal(), SACConfig(hidden_sizes=(8,), batch_size=4, buffer_size=64, total_env_steps=20,
                                    steps_per_chunk=10, learning_starts=4)
  networks = sac_train.make_networks(env, cfg)
  metrics = lambda plugins: jax.eval_shape(  # traced, not compiled: fast
      sac_train.make_train(env, cfg, plugins=plugins).run_chunk,
      jax.eval_shape(sac_train.make_train(env, cfg, plugins=plugins).init, jax.random.PRNGKey(0)))[1]
  m = metrics([kl_plugin(networks.policy_apply, networks.policy_init(jax.random.PRNGKey(1)), 1.0, 10)])
  assert {"kl", "kl_weight"} <= set(m) and "regularizer" not in m
  assert not {"kl", "kl_weight", "regularizer"} & set(metrics([]))


def test_fast_is_the_setting_the_zoos_legged_lls_were_trained_with():
  """`--fast` on top of `--preset paper` gives, field for field, the SAC config each zoo LL named
  *_fast_* records (their commands spelled the options out, and any SAC option beyond --fast); options given
  win, HLs refuse it."""
  import json

  from hdt.agents.sac import SACConfig
  from hdt.transfer import names
  entries = sorted(p.parent for p in names.ZOO_DIR.glob("*/*fast*/config.json"))
  sac_options = {f.name: f"--{f.name.replace('_', '-')}" for f in dataclasses.fields(SACConfig)
                 if f.name != "total_env_steps"}
  assert len(entries) >= 6
  for entry in entries:
    recorded = json.loads((entry / "config.json").read_text())
    command = json.loads((entry / "zoo.json").read_text())["command"].split()
    verb = ["align", "--imitate", "x"] if command[1] == "align" else ["train", "low"]
    argv = verb + ["--agent", command[command.index("--agent") + 1], "--preset", "paper", "--fast",
                   "--total-env-steps", str(recorded["total_env_steps"])]
    for field, option in sac_options.items():  # SAC options the command gave beyond --fast, or against it
      if option in command:
        i = command.index(option)
        given = command[i:i + 1 + next((j for j, t in enumerate(command[i + 1:]) if t.startswith("--")),
                                       len(command) - i - 1)]
        value = cli._overrides(cli.build_parser().parse_args(["train", "low", "--agent", "ant"] + given),
                               SACConfig, "")[field]
        if field not in configs.FAST_LOW or value != configs.FAST_LOW[field]:
          argv += given
    got = dataclasses.asdict(cli.sac_config(cli.build_parser().parse_args(argv), "low", entry.parent.name))
    want = dataclasses.asdict(SACConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in recorded.items()
                                           if k != "budget_unit"}))
    assert got == want, entry.name
  args = cli.build_parser().parse_args(["train", "low", "--agent", "ant", "--fast", "--num-envs", "4"])
  assert cli.sac_config(args, "low", "ant").num_envs == 4
  args = cli.build_parser().parse_args(["sweep", "high", "--task", "waypoint", "--low", "x", "--fast"])
  with pytest.raises(cli.CLIError, match="--fast is the setting of a legged LL"):
    cli.sac_config(args, "high", task="waypoint")
