"""Seeds x a hyper-parameter grid of one stage: every grid point writes its own run directory, as if
trained alone, and the points whose configs differ only in vmappable values train together as one
program (:func:`hdt.transfer.runner.run_points`)."""

from __future__ import annotations

import dataclasses

from hdt.agents import discriminator, kl
from hdt.agents.sac import SWEEPABLE
from hdt.transfer.align import AlignSpec, align_stage
from hdt.transfer.finetune import FinetuneSpec, check_kl_weight, finetune_stage
from hdt.transfer.pipeline import full_stage, high_stage, low_stage
from hdt.transfer.runner import RunOptions, RunResult, run_points


def sweep(level: str, runs: list[tuple], *, backend: str = "auto", options: RunOptions = RunOptions(),
          **stage) -> list[RunResult]:
  """Trains each ``(config, out)`` or ``(config, out, weights)`` of ``runs`` at ``level`` ("low": agent=...,
  "high": task=..., low=..., "full": agent=..., task=..., "finetune": high=..., low=..., task=...,
  "align": agent=..., imitate=...; further keywords as low_stage/high_stage/full_stage/finetune_stage/
  align_stage). ``weights``: the values of the level's plug-in weights, the same names for every run:
  ``{"kl_weight": w}`` (finetune) or ``{"disc_weight": w}`` (align: the discriminator's initial weight,
  ``DiscConfig.weight``). ``options``: seeds, quiet and overwrite of every run (each writes its own
  ``out``; a grid does not resume). Configs that differ only in fields of
  :data:`hdt.agents.sac.SWEEPABLE` (learning rates, tau, gamma, reward scale, target entropy), whatever their weights,
  train together, seeds and grid points as one vmapped program; the other groups (other network or
  batch sizes, num_envs, ...) in turn. Every run directory is written as by train_* (its meta.json
  records its weights). Returns the results in the order of ``runs``."""
  setup = {"low": low_stage, "high": high_stage, "full": full_stage, "align": align_stage,
           "finetune": finetune_stage}.get(level)
  if setup is None:
    raise ValueError(f"level={level!r}: sweep trains 'low', 'high', 'full', 'finetune' or 'align'")
  runs = [(r[0], r[1], dict(r[2]) if len(r) > 2 else {}) for r in runs]
  names = sorted(runs[0][2]) if runs else []
  if any(sorted(w) != names for _, _, w in runs):
    raise ValueError(f"sweep: every run needs values of the same weights, got {[sorted(w) for _, _, w in runs]}")
  check_weights(level, [w for _, _, w in runs], stage)
  groups: dict[tuple, list[int]] = {}
  for i, (cfg, _, _) in enumerate(runs):
    shape = tuple((k, v) for k, v in dataclasses.asdict(cfg).items() if k not in SWEEPABLE)
    groups.setdefault(shape, []).append(i)
  results: list[RunResult | None] = [None] * len(runs)
  for members in groups.values():
    cfgs = [runs[i][0] for i in members]
    varied = [k for k in SWEEPABLE if len({getattr(c, k) for c in cfgs}) > 1]
    kw = dict(stage)
    if level == "finetune" and kl.WEIGHT in names:  # the KL plug-in exists only for a weight > 0
      kw["spec"] = dataclasses.replace(kw.get("spec", FinetuneSpec()),
                                       kl_weight=max(runs[i][2][kl.WEIGHT] for i in members) or 1.0)
    st = setup(config=cfgs[0], backend=backend, **kw)
    points = [({k: getattr(runs[i][0], k) for k in varied} | runs[i][2], runs[i][1]) for i in members]
    if len(points) > 1:
      st = dataclasses.replace(st, label=f"{st.label} x{len(points)} points")
    for i, r in zip(members, run_points(st, points, options)):
      results[i] = r
  return results


WEIGHTS = {"finetune": (kl.WEIGHT,), "align": (discriminator.WEIGHT,)}  # the plug-in weights sweep can vary


def check_weights(level: str, weights: list[dict], stage: dict) -> None:
  """Refuses (one line) weights the level has no plug-in for, and values its stage would refuse."""
  for w in weights:
    unknown = set(w) - set(WEIGHTS.get(level, ()))
    if unknown:
      raise ValueError(f"sweep {level}: {sorted(unknown)} cannot be varied; vmappable: "
                       f"{', '.join(SWEEPABLE + WEIGHTS.get(level, ()))}")
    check_kl_weight(w.get(kl.WEIGHT, 0.0))
    if discriminator.WEIGHT in w:
      disc = AlignSpec.of(stage["imitate"]).disc if stage.get("imitate") is not None else None
      dataclasses.replace(disc or discriminator.DiscConfig(), weight=w[discriminator.WEIGHT])  # checks [0, 1]
