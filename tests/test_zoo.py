"""Every zoo entry loads and re-evaluates to its recorded numbers (a change that breaks a checkpoint,
an env or the evaluation fails here), and zoo:NAME works wherever a run directory does."""

import numpy as np
import pytest

from hdt.transfer import evaluate as ev
from hdt.transfer import zoo


@pytest.mark.parametrize("name", zoo.names())
def test_zoo_entry_reevaluates_to_its_recorded_check(name):
  recorded, fresh = zoo.recheck(name)
  assert not zoo.within_noise(recorded, fresh), f"{name}: {'; '.join(zoo.within_noise(recorded, fresh))}"


def test_zoo_names_resolve_and_an_hl_uses_the_ll_seed_it_was_trained_over():
  p = ev.compose("zoo:arm_point/push1", "zoo:arm_point/low")
  k = p.low_params["params"]["mlp"]["hidden_0"]["kernel"]
  assert k.shape[0] == 2 and np.array_equal(k[0], k[1])  # both HL seeds over LL seed 0
  # over another LL run (a transfer) HL seed i drives LL seed i
  assert ev.trained_over(p.meta, "zoo:arm_point/low") == 0 and ev.trained_over(p.meta, "zoo:arm3/low") is None


def test_unknown_zoo_name_is_one_clear_error():
  with pytest.raises(zoo.ZooError, match="no zoo entry 'nope'.*hdt zoo"):
    ev.compose("zoo:nope", "zoo:arm_point/low")


def test_export_keeps_only_the_ll_policies_and_the_hl_still_composes_over_them(point_low, point_high,
                                                                                tmp_path, monkeypatch):
  import json
  import shutil

  import orbax.checkpoint as ocp

  from hdt.transfer import checkpoint as ckpt
  monkeypatch.setattr(zoo, "ZOO_DIR", tmp_path / "zoo")
  run = point_low.run_dir if hasattr(point_low, "run_dir") else point_low
  high = point_high.run_dir if hasattr(point_high, "run_dir") else point_high
  zoo.export(run, "t/low", "test", episodes=4)
  zoo.export(high, "t/high", "test", low="zoo:t/low", episodes=4)
  for sub in ("params", "best/params"):
    p = tmp_path / "zoo/t/low/seed_0" / sub
    if p.is_dir():
      assert set(ocp.PyTreeCheckpointer().restore(p.resolve())) <= set(zoo.LL_KEEP), sub
  # the slim LL evaluates as the full one did, and the HL trained over the full LL composes with it
  full = ev.evaluate(ev.load_policy(run), episodes=4, key=3)
  slim = ev.evaluate(ev.load_policy("zoo:t/low"), episodes=4, key=3)
  assert full["per_seed"]["return"].tolist() == slim["per_seed"]["return"].tolist()
  ev.compose("zoo:t/high", "zoo:t/low")
  for name in ("t/low", "t/high"):
    assert not zoo.within_noise(*zoo.recheck(name))
  # a re-evaluation (after a deliberate env change) keeps the numbers it replaces
  before = json.loads((tmp_path / "zoo/t/high/zoo.json").read_text())
  after = zoo.reevaluate("t/high", "test", episodes=4)
  assert after["reevaluated"][0]["previous"]["evaluation"] == before["evaluation"] and after["command"] == "test"
  assert not zoo.within_noise(*zoo.recheck("t/high"))
  # a broken LL checkpoint (its first layer shuffled) is outside noise; its changed files are refused
  d = tmp_path / "zoo/t/low/seed_0/params"
  params = ocp.PyTreeCheckpointer().restore(d.resolve())
  k = params["policy"]["params"]["mlp"]["hidden_0"]["kernel"]
  params["policy"]["params"]["mlp"]["hidden_0"]["kernel"] = k[:, ::-1] * 3.0
  shutil.rmtree(d)
  ocp.PyTreeCheckpointer().save(d.resolve(), params)
  info = json.loads((tmp_path / "zoo/t/low/zoo.json").read_text())
  assert info["slim"][0]["sha256"] != ckpt.content_hash("zoo:t/low", 0)
  assert zoo.within_noise(*zoo.recheck("t/low"))
  with pytest.raises(ckpt.CheckpointError, match="changed after the HL"):
    ev.compose("zoo:t/high", "zoo:t/low")
