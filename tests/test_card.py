"""The hand-off card: JSON round trip (meta.json, including committed zoo entries), refusal of another
card format, and the one-line messages of its hand-off checks. No training: cards come from envs, files
and edited copies."""

import json

import numpy as np
import pytest

from hdt.envs import make
from hdt.transfer import checkpoint as ckpt
from hdt.transfer import configs, names, zoo
from hdt.transfer.card import CARD_FORMAT, FORMAT_KEY, ObsLayout, PolicyCard, load_low
from hdt.transfer.hierarchy import HighLevelEnv

CFG = configs.low_config("point", total_env_steps=400, num_envs=4, steps_per_chunk=25, batch_size=16,
                         buffer_size=1000, hidden_sizes=(16, 16), num_eval_episodes=2)


def low_card(agent="point", **extra):
  return PolicyCard.from_env(make(agent, "reach"), "low", CFG, env_overrides={}, **extra)


def high_card(task="waypoint", low=None):
  low = low or low_card()
  env = low.high_env({}, task)
  return PolicyCard.from_env(env, "high", CFG, low={"path": "x"}, task_overrides={})


def test_card_from_env_round_trips_through_json():
  card = low_card()
  d = card.to_json()
  assert d[FORMAT_KEY] == CARD_FORMAT and d["level"] == "low" and d["hidden_sizes"] == [16, 16]
  assert d["sac"]["total_env_steps"] == 400 and d["env_overrides"] == {}
  on_disk = json.loads(json.dumps(d))  # tuples become lists
  back = PolicyCard.from_json(on_disk)
  assert back.to_json() == on_disk and PolicyCard.from_json(back.to_json()) == back
  assert back.replace(extra=card.extra) == card  # the typed fields survive exactly
  assert card.goal_dim == 2 and card.obs_size == card.obs_lo_size + card.goal_dim
  assert card.hl_obs is None and card.obs_layout == ObsLayout()
  with pytest.raises(Exception):  # frozen
    card.k = 3


def test_high_card_carries_the_hl_observation_layout():
  card = high_card("maze")
  env = low_card().high_env({}, "maze")
  assert isinstance(env, HighLevelEnv)
  assert card.hl_obs == ObsLayout(tuple(env.env.task.hl_relative), env.env.task.hl_absolute)
  assert card.k == env.k and card.hl_horizon == env.horizon and card.delta_max == env.delta_max
  again = PolicyCard.from_json(json.loads(json.dumps(card.to_json())))
  assert again.obs_layout.task_options() == card.obs_layout.task_options()
  # the card rebuilds the env its policy was trained on: same observation size
  rebuilt = low_card().high_env({}, "maze", **again.obs_layout.task_options())
  assert rebuilt.observation_size == card.obs_size


@pytest.mark.parametrize("name", zoo.entry_names())
def test_committed_zoo_cards_load_and_round_trip(name):
  """Every zoo card loads and writes the same content; one written before the card format was
  recorded loads as format 1."""
  meta = json.loads((names.ZOO_DIR / name / "meta.json").read_text())
  assert meta.get(FORMAT_KEY, CARD_FORMAT) == CARD_FORMAT
  card = PolicyCard.from_json(meta, name)
  assert card.to_json() == dict(meta, **{FORMAT_KEY: CARD_FORMAT})
  assert card.policy_fn() is not None and card.level in ("low", "high", "full")


@pytest.mark.parametrize("fmt,fix", [(CARD_FORMAT + 1, "upgrade hdt"), (0, "re-train it"), ("1", "re-train it")])
def test_unknown_card_format_is_refused_in_one_line(fmt, fix):
  meta = dict(low_card().to_json(), **{FORMAT_KEY: fmt})
  with pytest.raises(ckpt.CheckpointError, match=f"card format {fmt!r} but this hdt reads card format "
                                                 f"{CARD_FORMAT}: {fix}") as e:
    PolicyCard.from_json(meta, "somewhere")
  assert "somewhere" in str(e.value) and len(str(e.value).splitlines()) == 1


def test_a_run_directory_of_another_card_format_is_refused(tmp_path):
  w = {"w": np.zeros((2,), np.float32)}
  meta = dict(low_card().to_json(), **{FORMAT_KEY: CARD_FORMAT + 1})
  ckpt.save(tmp_path / "run", 0, {"policy": w, "q": w}, dict(meta, seed=0))
  with pytest.raises(ckpt.CheckpointError, match=f"has card format {CARD_FORMAT + 1}"):
    load_low(tmp_path / "run")


def test_missing_fields_are_named():
  meta = {k: v for k, v in low_card().to_json().items() if k != "hidden_sizes"}
  with pytest.raises(ckpt.CheckpointError, match="has no 'hidden_sizes': the file was edited or damaged"):
    PolicyCard.from_json(meta, "m.json")


def _src(card, source):
  return card.replace(source=source)


def test_each_hand_off_check_words_its_errors():
  pm, arm = _src(low_card(), "PM_LOW"), _src(low_card("arm3"), "ARM_LOW")
  hl = _src(high_card(), "PM_HIGH")
  # compose: levels, goal spaces, goal boxes
  assert hl.compose_box(pm) == hl.delta_max
  with pytest.raises(ckpt.CheckpointError, match="PM_LOW holds a 'low'-level policy; compose needs an HL"):
    pm.compose_box(pm)
  with pytest.raises(ckpt.CheckpointError, match="PM_HIGH holds a 'high'-level policy; compose needs an LL"):
    hl.compose_box(hl)
  with pytest.raises(ValueError, match="goal spaces do not match: the HL in PM_HIGH emits navigation"):
    hl.compose_box(arm)
  small_box = pm.replace(delta_max=2.0)
  with pytest.raises(ValueError, match=r"goal boxes differ: .* pass box='scale'"):
    hl.compose_box(small_box)
  assert hl.compose_box(small_box, box="scale") == 2.0
  assert hl.compose_box(small_box, box="keep") == hl.delta_max
  # an LL for an HL
  assert pm.low_box() == pm.delta_max
  with pytest.raises(ckpt.CheckpointError, match="PM_HIGH holds a 'high'-level policy where a low level was expected"):
    hl.low_box()
  with pytest.raises(ckpt.CheckpointError, match="trained with k=0, delta_max=4.0; an HL needs both positive"):
    pm.replace(k=0).low_box()
  # finetuning A's HL into B's run
  hl.check_finetunes_to(hl)
  with pytest.raises(ckpt.CheckpointError, match="finetune_high needs an HL"):
    pm.check_finetunes_to(hl)
  with pytest.raises(ValueError, match="goal spaces do not match: the HL in PM_HIGH was trained for the 'nav'"):
    hl.check_finetunes_to(hl.replace(family="manip"))
  with pytest.raises(ckpt.CheckpointError, match=f"maps {hl.obs_size} observations to 2 actions"):
    hl.check_finetunes_to(hl.replace(obs_size=hl.obs_size + 3))
  with pytest.raises(ValueError, match=r"has hidden sizes \(16, 16\)"):
    hl.check_finetunes_to(hl.replace(hidden_sizes=(8, 8)))
  normed = hl.replace(extra=dict(hl.extra, sac=dict(hl.sac, normalize_observations=True)))
  with pytest.raises(ValueError, match="was trained without an observation normaliser"):
    hl.check_finetunes_to(normed)
  # aligning B's LL to A's
  pm.check_imitated_by(pm)
  with pytest.raises(ValueError, match="cannot align 'arm3' to the LL in PM_LOW .*goal spaces differ"):
    pm.check_imitated_by(arm)


def test_card_checks_the_env_it_is_run_on():
  hl = _src(high_card(), "PM_HIGH")
  maze = low_card().high_env({}, "maze", **hl.obs_layout.task_options())
  if maze.observation_size != hl.obs_size:
    with pytest.raises(ValueError, match="was the HL trained on another task"):
      hl.check_env(maze, "maze")
  hl.check_env(low_card().high_env({}, "waypoint"), "waypoint")
  with pytest.raises(ValueError, match="the policy observes"):
    low_card().check_env(make("arm3", "reach"), "reach")
