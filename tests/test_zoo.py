"""Every zoo entry loads and re-evaluates to its recorded numbers (a change that breaks a checkpoint,
an env or the evaluation fails here), and zoo:NAME works wherever a run directory does."""

import json

import jax
import numpy as np
import pytest
import zoo_entries

from hdt.transfer import configs
from hdt.transfer import evaluate as ev
from hdt.transfer import names, zoo


@pytest.mark.parametrize("name", zoo_entries.entries(legged=False))  # the legged ones: test_zoo_legged.py
def test_zoo_entry_reevaluates_to_its_recorded_check(name):
  recorded, fresh = zoo.recheck(name)
  assert not zoo.within_noise(recorded, fresh), f"{name}: {'; '.join(zoo.within_noise(recorded, fresh))}"


def _check_result(episode_returns, success=None):
  """A check's result as evaluate.evaluate records it, from per-seed lists of episode returns."""
  r = np.asarray(episode_returns, float)
  out = dict(seeds=list(range(len(r))), episodes=r.shape[1], return_mean=float(r.mean()),
             episode_return_std=r.std(axis=1).tolist(), episode_return_min=r.min(axis=1).tolist(),
             episode_return_max=r.max(axis=1).tolist())
  if success is not None:
    out["success_mean"] = float(np.mean(success))
  return out


def test_within_noise_allows_one_episode_that_ends_otherwise_but_not_two():
  # the sparse maze: two seeds reach the goal (+1000) in all 4 check episodes, one never does
  rec = [[999.6] * 4, [-0.6] * 4, [999.7] * 4]
  succ = lambda r: [[x > 500 for x in s] for s in r]
  recorded = _check_result(rec, succ(rec))
  assert not zoo.within_noise(recorded, _check_result(rec, succ(rec)))
  for flips in ([(0, 0)], [(1, 2)]):  # one goal missed, or one reached, on another CPU
    r = [list(s) for s in rec]
    for i, j in flips:
      r[i][j] = -0.7 if r[i][j] > 500 else 999.5
    assert not zoo.within_noise(recorded, _check_result(r, succ(r))), flips
  r = [list(s) for s in rec]
  r[0][0] = r[2][1] = -0.7
  assert zoo.within_noise(recorded, _check_result(r, succ(r)))[0].startswith("return")
  # every recorded episode succeeded (spread ~0), and the check predates the recorded extremes:
  # the fresh replay's range is the episode's worth
  rec = [[198.8] * 12, [198.9] * 12]
  recorded = _check_result(rec, succ(rec))
  for k in ("episode_return_min", "episode_return_max"):
    del recorded[k]
  r = [list(s) for s in rec]
  r[1][5] = -3.0
  assert not zoo.within_noise(recorded, _check_result(r, succ(r)))
  r[0][7] = -3.0
  assert zoo.within_noise(recorded, _check_result(r, succ(r)))
  # a dense return that drifts in every episode is not one episode's worth
  rec = [[100.0 + i for i in range(12)]]
  assert zoo.within_noise(_check_result(rec), _check_result([[x - 10.0 for x in rec[0]]]))


def test_zoo_names_resolve_and_an_hl_uses_the_ll_seed_it_was_trained_over():
  p = ev.compose("zoo:arm_point/push1", "zoo:arm_point/low")
  k = p.low_params["params"]["mlp"]["hidden_0"]["kernel"]
  assert k.shape[0] == 2 and np.array_equal(k[0], k[1])  # both HL seeds over LL seed 0
  # over another LL run (a transfer) HL seed i drives LL seed i
  assert ev.trained_over(p.card, "zoo:arm_point/low") == 0 and ev.trained_over(p.card, "zoo:arm3/low") is None


def test_unknown_zoo_name_is_one_clear_error():
  with pytest.raises(zoo.ZooError, match="no zoo entry 'nope'.*hdt zoo"):
    ev.compose("zoo:nope", "zoo:arm_point/low")


def _as_exported_before_slimming(run, zoo_dir):
  """Makes zoo entry t/low look as exported before LLs dropped their final parameters; returns its hash."""
  import json
  from pathlib import Path

  from hdt.transfer import checkpoint as ckpt
  final = ckpt.restore_params(Path(run) / "seed_0/params")
  ckpt.orbax_save((zoo_dir / "t/low/seed_0/params").resolve(), {k: v for k, v in final.items() if k in zoo.POLICY_KEYS})
  old_hash = ckpt.content_hash("zoo:t/low", 0)
  info = json.loads((zoo_dir / "t/low/zoo.json").read_text())
  info["slim"][0]["sha256"] = old_hash
  (zoo_dir / "t/low/zoo.json").write_text(json.dumps(info))
  return old_hash, info


def _break_first_layer(zoo_dir, shuffle: bool):
  """Changes the first layer of zoo entry t/low's LL policy (a retrained or broken checkpoint)."""
  from hdt.transfer import checkpoint as ckpt
  d = zoo_dir / "t/low/seed_0/best/params"
  params = ckpt.restore_params(d)
  k = params["policy"]["params"]["mlp"]["hidden_0"]["kernel"]
  params["policy"]["params"]["mlp"]["hidden_0"]["kernel"] = (k[:, ::-1] if shuffle else k) * 3.0
  ckpt.pack(d, params)


def test_export_keeps_only_the_ll_policies_and_the_hl_still_composes_over_them(point_low, point_high,
                                                                                tmp_path, monkeypatch):
  import json

  from hdt.transfer import checkpoint as ckpt
  from hdt.transfer import finetune
  monkeypatch.setattr(names, "ZOO_DIR", tmp_path / "zoo")
  run = point_low.run_dir if hasattr(point_low, "run_dir") else point_low
  high = point_high.run_dir if hasattr(point_high, "run_dir") else point_high
  zoo.export(run, "t/low", "test", episodes=4)
  zoo.export(high, "t/high", "test", low="zoo:t/low", episodes=4)
  zoo.export(high, "t/high_sac", "test", low="zoo:t/low", episodes=4, keep_sac=True)
  keys = lambda sub: set(ckpt.restore_params(tmp_path / "zoo" / sub))
  # one file per parameter set: the LL keeps its best policy only, the HL its final policy (what its
  # numbers are of), or with keep_sac its whole final SAC and its best policy (the KL reference)
  files = lambda entry: sorted(str(p.relative_to(tmp_path / "zoo" / entry)) for p in (tmp_path / "zoo" / entry).rglob("*")
                               if p.is_file() and not p.name.startswith("."))
  assert files("t/low") == ["config.json", "curves.csv", "meta.json", "seed_0/best/params.msgpack",
                            "seed_0/meta.json", "zoo.json"]
  assert keys("t/low/seed_0/best/params") <= set(zoo.POLICY_KEYS)
  assert "seed_0/params.msgpack" in files("t/high") and not any("best/" in f for f in files("t/high"))
  assert keys("t/high/seed_0/params") <= set(zoo.POLICY_KEYS)
  assert {"policy", "q", "target_q"} <= keys("t/high_sac/seed_0/params")
  assert keys("t/high_sac/seed_0/best/params") <= set(zoo.POLICY_KEYS)
  with pytest.raises(ValueError, match="low level: keep_sac"):
    zoo.export(run, "t/low_sac", "test", episodes=4, keep_sac=True)
  # both HL entries evaluate as the run's final parameters did; finetuning starts only from the whole SAC
  ref = ev.evaluate(ev.compose(high, "zoo:t/low"), episodes=4, key=3)["per_seed"]["return"].tolist()
  for entry in ("zoo:t/high", "zoo:t/high_sac"):
    assert ev.evaluate(ev.compose(entry, "zoo:t/low"), episodes=4, key=3)["per_seed"]["return"].tolist() == ref
  finetune.start_plugin(finetune.load_high_sac("zoo:t/high_sac")[0], None, "zoo:t/high_sac")
  with pytest.raises(ValueError, match="keeps only its policy .*--keep-sac"):
    finetune.start_plugin(finetune.load_high_sac("zoo:t/high")[0], None, "zoo:t/high")
  # the slim LL evaluates as the full one's best parameters did, whichever set is asked for, and says
  # so; the HL trained over the full LL composes with it
  full = ev.evaluate(ev.load_policy(run, "best"), episodes=4, key=3)
  for which in ("final", "best"):
    pol = ev.load_policy("zoo:t/low", which)
    assert pol.card.loaded == "best"
    assert full["per_seed"]["return"].tolist() == ev.evaluate(pol, episodes=4, key=3)["per_seed"]["return"].tolist()
  ev.compose("zoo:t/high", "zoo:t/low")
  # each entry keeps its run's learning curves (what `hdt reproduce` draws from the zoo), nothing else of metrics.csv
  from hdt.report import read_eval_curves
  for entry, source in (("t/low", run), ("t/high", high)):
    kept, orig = read_eval_curves(names.resolve(f"zoo:{entry}")), read_eval_curves(source)
    assert kept.keys() == orig.keys() and kept
    for col, (x, y) in orig.items():
      np.testing.assert_array_equal(kept[col][0], x)
      np.testing.assert_array_equal(kept[col][1], y)
    assert not (tmp_path / "zoo" / entry / "metrics.csv").exists()
  # an entry exported before the LL's final parameters were dropped is slimmed in place, remembers the
  # hash it had, and still composes
  old_hash, info = _as_exported_before_slimming(run, tmp_path / "zoo")
  slim = zoo.reslim("t/low")["slim"][0]
  assert not (tmp_path / "zoo/t/low/seed_0/params").exists()
  assert slim["sha256"] == ckpt.content_hash("zoo:t/low", 0) and slim["earlier_sha256"] == [old_hash]
  assert slim["source_sha256"] == info["slim"][0]["source_sha256"]
  ev.compose("zoo:t/high", "zoo:t/low")
  for name in ("t/low", "t/high"):
    assert not zoo.within_noise(*zoo.recheck(name))
  # a re-evaluation (after a deliberate env change) keeps the numbers it replaces
  before = json.loads((tmp_path / "zoo/t/high/zoo.json").read_text())
  after = zoo.reevaluate("t/high", "test", episodes=4)
  assert after["reevaluated"][0]["previous"]["evaluation"] == before["evaluation"] and after["command"] == "test"
  assert not zoo.within_noise(*zoo.recheck("t/high"))
  # the HL entry records the LL it composes with; the export of an entry onto itself is refused
  high_info = json.loads((tmp_path / "zoo/t/high/zoo.json").read_text())
  assert high_info["low_sha256"] and len(high_info["seed_sha256"]) == 1
  assert json.loads((tmp_path / "zoo/t/high/seed_0/meta.json").read_text())["low"]["sha256"]
  with pytest.raises(ValueError, match="is the exported run"):
    zoo.export("zoo:t/low", "t/low", "test", episodes=4, overwrite=True)
  # a broken LL checkpoint (its first layer shuffled) is refused on load: its files are not zoo.json's
  _break_first_layer(tmp_path / "zoo", shuffle=True)
  info = json.loads((tmp_path / "zoo/t/low/zoo.json").read_text())
  assert info["slim"][0]["sha256"] != ckpt.content_hash("zoo:t/low", 0)
  for load in (lambda: zoo.recheck("t/low"), lambda: ev.compose("zoo:t/high", "zoo:t/low")):
    with pytest.raises(ckpt.CheckpointError, match="not the one .*zoo.json records \\(its content hash differs"):
      load()


def test_an_ll_exported_with_its_final_parameters_keeps_and_loads_those(point_low, point_high, tmp_path,
                                                                         monkeypatch):
  import shutil

  from hdt.transfer import checkpoint as ckpt
  monkeypatch.setattr(names, "ZOO_DIR", tmp_path / "zoo")
  run = tmp_path / "run"  # a copy whose final policy is not its best one (here the last evaluation's)
  shutil.copytree(point_low.run_dir if hasattr(point_low, "run_dir") else point_low, run)
  params = ckpt.restore_params(run / "seed_0/params")
  params["policy"]["params"]["mlp"]["hidden_0"]["kernel"] *= 0.5
  ckpt.pack(run / "seed_0/params", params)
  ckpt.record_seed_hashes(run)
  final, best = (ckpt.load(run, 0, which)[0]["policy"] for which in ("final", "best"))
  assert not all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(final), jax.tree.leaves(best)))
  zoo.export(run, "t/low_final", "test", episodes=2, low_params="final")
  entry = tmp_path / "zoo/t/low_final"
  assert (entry / "seed_0/params.msgpack").is_file() and not (entry / "seed_0/best").exists()
  assert json.loads((entry / "zoo.json").read_text())["params"] == "final"
  ref = ev.evaluate(ev.load_policy(run, "final"), episodes=4, key=3)["per_seed"]["return"].tolist()
  for which in ("final", "best"):  # what HLs compose with (--low-params best) is the final policy too
    pol = ev.load_policy("zoo:t/low_final", which)
    assert pol.card.loaded == "final"
    assert ev.evaluate(pol, episodes=4, key=3)["per_seed"]["return"].tolist() == ref
  assert not zoo.within_noise(*zoo.recheck("t/low_final"))
  assert zoo.reslim("t/low_final")["params"] == "final" and (entry / "seed_0/params.msgpack").is_file()
  with pytest.raises(ValueError, match="low_params='last': load the 'final' parameters or the 'best'"):
    zoo.export(run, "t/low_last", "test", episodes=2, low_params="last")
  with pytest.raises(ValueError, match="is not a low level: low_params"):
    high = point_high.run_dir if hasattr(point_high, "run_dir") else point_high
    zoo.export(high, "t/high_best", "test", low="zoo:t/low_final", episodes=2, low_params="final")


@pytest.fixture()
def zoo_copy(tmp_path, monkeypatch):
  """point/low and point/waypoint copied into a zoo of their own (names.ZOO_DIR points there)."""
  import shutil
  for name in ("point/low", "point/waypoint"):
    shutil.copytree(names.ZOO_DIR / name, tmp_path / "zoo" / name)
  monkeypatch.setattr(names, "ZOO_DIR", tmp_path / "zoo")
  return tmp_path / "zoo"


def test_an_hl_over_a_zoo_ll_whose_seed_was_replaced_is_refused(zoo_copy, tmp_path, capsys):
  """point/waypoint records no hash of its LL; the LL's own zoo.json tells that its seed_0 is another
  run's: refused in one line (API and command), nothing written."""
  import hashlib
  import shutil

  from hdt.cli import main
  ev.compose("zoo:point/waypoint", "zoo:point/low")  # intact: composes
  # an HL entry's zoo.json may record its LL's hash (exports do): another LL's is refused
  info_path = zoo_copy / "point" / "waypoint" / "zoo.json"
  info_path.write_text(json.dumps(dict(json.loads(info_path.read_text()), low_sha256="0" * 64)))
  with pytest.raises(ValueError, match="changed after the HL"):
    ev.compose("zoo:point/waypoint", "zoo:point/low")
  info_path.write_text(json.dumps({k: v for k, v in json.loads(info_path.read_text()).items() if k != "low_sha256"}))
  low = zoo_copy / "point" / "low"
  shutil.rmtree(low / "seed_0")
  shutil.copytree(low / "seed_1", low / "seed_0")  # another run's checkpoint under seed_0
  with pytest.raises(ValueError, match="seed_0 is not the one .*zoo.json records"):
    ev.compose("zoo:point/waypoint", "zoo:point/low")
  tree = lambda: {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(zoo_copy.rglob("*")) if p.is_file()}
  before = tree()
  for damage in ("replaced", "garbage bytes"):
    if damage == "garbage bytes":  # a damaged data file of the HL itself
      data = zoo_copy / "point" / "waypoint" / "seed_0" / "params.msgpack"
      data.write_bytes(b"\x00garbage" * 8)
      before = tree()
    assert main(["eval", "--high", "zoo:point/waypoint", "--low", "zoo:point/low", "--episodes", "1",
                 "--out", str(tmp_path / "ev")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "content hash differs" in err and "git checkout -- zoo/point/" in err, err
    assert tree() == before and not (tmp_path / "ev").exists()


def _as_exported_by_an_older_hdt(zoo_dir, name: str) -> dict:
  """Makes zoo entry ``name`` look as an older hdt exported it: orbax directories, their commit markers
  naming the exporting machine's path, and the hashes such an export recorded; returns {seed or None: hash}."""
  from hdt.transfer import checkpoint as ckpt
  entry = zoo_dir / name
  for f in list(entry.rglob("*" + ckpt.PACKED)):
    d = f.with_name(f.name[:-len(ckpt.PACKED)])
    ckpt.orbax_save(d.resolve(), ckpt.restore_params(d))
    f.unlink()
    (d / names.ORBAX_MARKER).write_text(f"Checkpoint commit was successful to /home/someone/hdt/zoo/.{name}.tmp/{d.name}")
  seeds = ckpt.list_seeds(entry)
  hashes = {s: ckpt.content_hash(entry, s) for s in seeds}
  info = json.loads((entry / "zoo.json").read_text())
  for s in info.get("slim") or []:  # the names it had before stay its names
    s.update(earlier_sha256=[*s["earlier_sha256"], s["sha256"]], sha256=hashes[s["seed"]])
  info["seed_sha256"] = [hashes[s] for s in seeds]
  info["earlier_entry_sha256"] = [*info["earlier_entry_sha256"], info["entry_sha256"]]
  info["entry_sha256"] = ckpt.content_hash(entry)
  (entry / "zoo.json").write_text(json.dumps(info))
  ckpt.record_seed_hashes(entry)
  return {**hashes, None: ckpt.content_hash(entry)}


def test_repacking_an_entry_an_older_hdt_exported_keeps_what_depends_on_it(zoo_copy, tmp_path):
  from hdt.transfer import checkpoint as ckpt
  # a checkpoint written today names no directory in its commit marker
  ckpt.save(tmp_path / "run", 0, {"w": np.ones(3, np.float32)}, dict(level="low"))
  markers = list((tmp_path / "run").rglob(names.ORBAX_MARKER))
  assert markers and all(m.read_text() == names.MARKER_TEXT for m in markers)
  # entries as an older hdt exported them, an HL over the LL that recorded its hash, and a run that
  # recorded the HL's whole hash (a finetuning run does)
  low = _as_exported_by_an_older_hdt(zoo_copy, "point/low")
  high = _as_exported_by_an_older_hdt(zoo_copy, "point/waypoint")
  info_path = zoo_copy / "point" / "waypoint" / "zoo.json"
  info_path.write_text(json.dumps(dict(json.loads(info_path.read_text()), low_sha256=low[0])))
  recorded = {n: zoo.recheck(n)[1] for n in ("point/low", "point/waypoint")}
  for name in ("point/low", "point/waypoint"):
    zoo.reslim(name)
    left = sorted(p.name for p in (zoo_copy / name).rglob("*") if p.is_file() and p.parent.name != name.split("/")[1])
    assert set(left) == {"meta.json", "params.msgpack"}, left  # one file per parameter set, no orbax marker
  assert ckpt.content_hash("zoo:point/low", 0) != low[0]
  # the files changed, their parameters did not: the HL still composes, evaluates as before, its old hashes name it
  ev.compose("zoo:point/waypoint", "zoo:point/low")
  for name, before in recorded.items():
    assert zoo.recheck(name)[1]["per_seed"] == before["per_seed"]
  assert low[0] in names.hash_aliases("zoo:point/low", 0) and high[None] in names.hash_aliases("zoo:point/waypoint", None)
  assert zoo.keeps(json.loads(info_path.read_text())) == "sac"  # it kept what finetuning starts from
  # a finetuning run that recorded the HL's old whole hash resumes (runner's check of what it depends on)
  from hdt.transfer import runner
  rec = lambda h: {"meta": {"finetuned_from": {"path": "zoo:point/waypoint", "sha256": h}}}
  now = ckpt.content_hash("zoo:point/waypoint")
  assert runner._same_low_as_slim_copy(rec(high[None]), rec(now)) == rec(now)
  assert runner._same_low_as_slim_copy(rec("0" * 64), rec(now)) == rec("0" * 64)  # another HL's: refused later
  # and only while they are unchanged: another edit drops the aliases
  m = zoo_copy / "point/waypoint/seed_0/meta.json"
  m.write_text(json.dumps(dict(json.loads(m.read_text()), edited=True)))
  assert names.hash_aliases("zoo:point/waypoint", None) == {ckpt.content_hash("zoo:point/waypoint")}


def test_a_failed_export_leaves_nothing_in_the_zoo(zoo_copy, monkeypatch):
  def broken(*a, **k):
    raise RuntimeError("evaluation failed")

  monkeypatch.setattr(zoo, "_numbers", broken)
  before = sorted(str(p) for p in zoo_copy.rglob("*"))
  for name in ("t/new", "point/low_again"):
    with pytest.raises(RuntimeError, match="evaluation failed"):
      zoo.export(zoo_copy / "point" / "low", name, "test", episodes=2)
    assert sorted(str(p) for p in zoo_copy.rglob("*")) == before


def test_exporting_a_run_in_which_a_seed_diverged_warns_and_records_it(point_low, tmp_path, monkeypatch, capsys):
  import json
  import shutil

  monkeypatch.setattr(names, "ZOO_DIR", tmp_path / "zoo")
  run = tmp_path / "run"
  shutil.copytree(point_low.run_dir if hasattr(point_low, "run_dir") else point_low, run)
  zoo.export(run, "t/clean", "test", episodes=2)
  assert "diverged" not in json.loads((tmp_path / "zoo/t/clean/zoo.json").read_text())
  assert "diverged" not in capsys.readouterr().err
  m = run / "seed_0" / "meta.json"
  m.write_text(json.dumps(dict(json.loads(m.read_text()), diverged_at_env_step=1200)))
  zoo.export(run, "t/diverged", "test", episodes=2)
  err = capsys.readouterr().err
  assert "seed 0 (from env step 1200) stopped training when its loss went NaN/inf" in err, err
  assert json.loads((tmp_path / "zoo/t/diverged/zoo.json").read_text())["diverged"] == {"0": 1200}


def test_committed_zoo_stays_a_few_megabytes():
  """The zoo is committed: it keeps what is loaded from it (zoo.py) and no more, one file per set."""
  from hdt.transfer import checkpoint as ckpt
  disk = lambda d: sum(p.stat().st_blocks * 512 for p in d.rglob("*") if p.is_file())  # what du counts
  # per entry: an HL's policies ≈ 0.06 MB, an arm LL's ≈ 0.2 MB, a legged LL's ≈ 0.4 MB, a legged Full
  # policy (the paper's [400, 300] over 125-165 observations) ≈ 0.7-0.9 MB; a replay buffer, an Adam state
  # or critics kept by mistake are more. The bound is README's ("The model zoo").
  total = disk(names.ZOO_DIR) / 1e6
  assert total < 20, f"zoo/ takes {total:.1f} MB on disk: too many entries to commit"
  for info in zoo.entries():
    entry = names.ZOO_DIR / info["name"]
    mb, bound = disk(entry) / 1e6, 1.0 if info["level"] == "full" else 0.6
    assert mb < bound, f"zoo entry {info['name']} takes {mb:.2f} MB; export policies only (zoo.export slims them)"
    assert not list(entry.rglob(names.ORBAX_MARKER)), f"{entry} keeps orbax directories: zoo.reslim packs them"
    for seed in entry.glob("seed_*"):
      final, best = ckpt.has_params(seed / "params"), ckpt.has_params(seed / "best/params")
      assert final or best, seed
      assert not (final and best) or zoo.keeps(info) == "sac", f"{seed} keeps both sets"


def test_the_hls_finetuning_starts_from_keep_their_sac_and_no_other_entry_does():
  from hdt import paper
  from hdt.paper.runs import Finetune
  sources = {c.high.high.zoo for name in paper.NAMES for t in [paper.load(name)] for part in t.parts(t.presets["paper"]) for c in part.cells
             if isinstance(c.high, Finetune) and c.high.high.zoo}
  assert "point/maze" in sources and {i["name"] for i in zoo.entries() if zoo.keeps(i) == "sac"} == sources


def test_every_committed_entry_records_the_content_hash_of_each_seed():
  from hdt.transfer import checkpoint as ckpt
  for name in zoo.entry_names():
    info = json.loads((names.ZOO_DIR / name / "zoo.json").read_text())
    seeds = ckpt.list_seeds(names.ZOO_DIR / name)
    assert [names.recorded_hash(info, s) for s in seeds] == [ckpt.content_hash(names.ZOO_DIR / name, s) for s in seeds], name


def test_every_committed_entry_lists_the_seeds_it_holds():
  from hdt.transfer import checkpoint as ckpt
  for name in zoo.entry_names():
    info = json.loads((names.ZOO_DIR / name / "zoo.json").read_text())
    assert info["seeds"] == ckpt.list_seeds(names.ZOO_DIR / name) == info["evaluation"]["seeds"], name


def test_zoo_table_lists_every_entry_with_the_parameters_its_numbers_are_of():
  rows = [r.split(" | ") for r in zoo.table().splitlines()[2:]]
  assert [r[0] for r in rows] == zoo.entry_names()
  assert {r[5] for r in rows if r[1] == "low"} <= {"best", "final"} and {r[5] for r in rows if r[1] == "high"} == {"final"}
  assert {r[9] for r in rows if r[1] == "low"} == {"policy"} and {r[9] for r in rows if r[1] == "high"} == {"policy", "sac"}


def test_an_hl_run_started_over_an_older_zoo_copy_resumes_after_the_entry_is_slimmed(point_low, tmp_path,
                                                                                     monkeypatch):
  from hdt.transfer import checkpoint as ckpt
  from hdt.transfer import configs
  from hdt.transfer.pipeline import train_high
  from hdt.transfer.runner import RunOptions
  monkeypatch.setattr(names, "ZOO_DIR", tmp_path / "zoo")
  run = point_low.run_dir if hasattr(point_low, "run_dir") else point_low
  zoo.export(run, "t/low", "test", episodes=4)
  _as_exported_before_slimming(run, tmp_path / "zoo")
  steps = 256
  cfg = lambda total: configs.high_config("waypoint", total_env_steps=total, num_envs=8, updates_per_step=8,
                                          steps_per_chunk=steps // 8, num_eval_episodes=4)
  high = tmp_path / "high"
  train_high("waypoint", "zoo:t/low", cfg(steps), options=RunOptions(out=high, quiet=True, save_every=steps))
  zoo.reslim("t/low")
  res = train_high("waypoint", "zoo:t/low", cfg(2 * steps), options=RunOptions(out=high, quiet=True, resume=True))
  assert int(np.max(res.history["env_steps"])) == 2 * steps
  # a real change of the LL is still refused
  _break_first_layer(tmp_path / "zoo", shuffle=False)
  with pytest.raises(ckpt.CheckpointError, match="content hash differs"):
    train_high("waypoint", "zoo:t/low", cfg(3 * steps), options=RunOptions(out=high, quiet=True, resume=True))


def test_results_zoo_section_names_every_committed_entry_and_retires_only_absent_ones():
  import re
  text = (names.ZOO_DIR.parent / "RESULTS.md").read_text()
  table = text[text.index("| group | entries | status |"):]
  table = table[:table.index("\n\n")]
  rows = {r.split(" | ")[0].strip("| "): set(re.findall(r"`([a-z0-9_]+/[a-z0-9_]+)`", r)) for r in table.splitlines()[2:]}
  live = set(zoo.entry_names())
  listed = set().union(*(v for k, v in rows.items() if k != "retired"))
  assert live - listed == set(), f"RESULTS.md's Zoo table misses {sorted(live - listed)}"
  assert listed - live == set(), f"RESULTS.md's Zoo table lists absent entries {sorted(listed - live)}"
  assert rows["retired"] & live == set(), f"retired but still in the zoo: {sorted(rows['retired'] & live)}"


def test_every_check_replays_as_many_episodes_as_an_export_would_record():
  from hdt.transfer import checkpoint as ckpt
  for info in zoo.entries():
    want = zoo.check_episodes(ckpt.load_meta(names.ZOO_DIR / info["name"]))
    assert info["check"]["episodes"] == want, f"{info['name']}: re-record with zoo.reevaluate(name, reason, check_only=True)"
