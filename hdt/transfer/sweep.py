"""Seeds x a hyper-parameter grid of one stage: every grid point writes its own run directory, as if
trained alone, and the points whose configs differ only in vmappable values train together as one
program (:func:`hdt.transfer.runner.run_points`)."""

from __future__ import annotations

import dataclasses

from hdt.agents.sac import SWEEPABLE
from hdt.transfer import align, finetune, pipeline
from hdt.transfer.runner import Level, RunOptions, RunResult, run_points

# every kind of stage, each declared by its own module with the weights a grid may vary
LEVELS: dict[str, Level] = {lv.name: lv for lv in (pipeline.LOW, pipeline.HIGH, pipeline.FULL, finetune.FINETUNE,
                                                   align.ALIGN)}


def level_of(name: str) -> Level:
  """The :class:`Level` called ``name``, refused in one line if there is none."""
  if name not in LEVELS:
    raise ValueError(f"level={name!r}: sweep trains {', '.join(repr(n) for n in LEVELS)}")
  return LEVELS[name]


def sweep(level: str, runs: list[tuple], *, backend: str = "auto", options: RunOptions = RunOptions(),
          **stage) -> list[RunResult]:
  """Trains each ``(config, out)`` or ``(config, out, weights)`` of ``runs`` at ``level``
  (:data:`LEVELS`: "low" needs agent=...; "high" task=..., low=...; "full" agent=..., task=...;
  "finetune" high=..., low=..., task=...; "align" agent=..., imitate=...; further keywords as its
  stage function). ``weights``: values of the level's plug-in weights (``Level.weights``), the same
  names for every run: ``{"kl_weight": w}`` (finetune) or ``{"disc_weight": w}`` (align: the
  discriminator's initial weight, ``DiscConfig.weight``). ``options``: seeds, quiet and overwrite of
  every run (each writes its own ``out``; a grid does not resume). Configs that differ only in fields
  of :data:`hdt.agents.sac.SWEEPABLE` (learning rates, tau, gamma, reward scale, target entropy),
  whatever their weights, train together, seeds and grid points as one vmapped program; the other
  groups (other network or batch sizes, num_envs, ...) in turn. Every run directory is written as by
  train_* (its meta.json records its weights). Returns the results in the order of ``runs``."""
  lv = level_of(level)
  runs = [(r[0], r[1], dict(r[2]) if len(r) > 2 else {}) for r in runs]
  names = sorted(runs[0][2]) if runs else []
  if any(sorted(w) != names for _, _, w in runs):
    raise ValueError(f"sweep: every run needs values of the same weights, got {[sorted(w) for _, _, w in runs]}")
  check_weights(lv, [w for _, _, w in runs], stage)
  groups: dict[tuple, list[int]] = {}
  for i, (cfg, _, _) in enumerate(runs):
    shape = tuple((k, v) for k, v in dataclasses.asdict(cfg).items() if k not in SWEEPABLE)
    groups.setdefault(shape, []).append(i)
  results: list[RunResult | None] = [None] * len(runs)
  for members in groups.values():
    cfgs = [runs[i][0] for i in members]
    varied = [k for k in SWEEPABLE if len({getattr(c, k) for c in cfgs}) > 1]
    kw = dict(stage)
    for w in lv.weights:
      if w.prepare is not None and w.name in names:
        kw = w.prepare(kw, [runs[i][2][w.name] for i in members])
    st = lv.stage(config=cfgs[0], backend=backend, **kw)
    points = [({k: getattr(runs[i][0], k) for k in varied} | runs[i][2], runs[i][1]) for i in members]
    if len(points) > 1:
      st = dataclasses.replace(st, label=f"{st.label} x{len(points)} points")
    for i, r in zip(members, run_points(st, points, options)):
      results[i] = r
  return results


def check_weights(lv: Level, weights: list[dict], stage: dict) -> None:
  """Refuses (one line) weights the level has no plug-in for, and values its stage would refuse."""
  by_name = {w.name: w for w in lv.weights}
  for values in weights:
    unknown = set(values) - set(by_name)
    if unknown:
      raise ValueError(f"sweep {lv.name}: {sorted(unknown)} cannot be varied; vmappable: "
                       f"{', '.join(SWEEPABLE + lv.weight_names)}")
    for name, value in values.items():
      by_name[name].check(value, stage)
