"""The ``hdt`` command. For now: ``hdt quickstart``; the full CLI is issue 7."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def quickstart(out: Path, quiet: bool) -> None:
  """Train a point-mass LL and an HL on Waypoint, then evaluate the composed policy."""
  from hdt.transfer import configs
  from hdt.transfer.evaluate import compose, evaluate
  from hdt.transfer.pipeline import train_high, train_low

  low = train_low("point", configs.low_config("point", total_env_steps=8000, num_envs=8,
                                               updates_per_step=8, steps_per_chunk=125),
                  seeds=2, out=out / "pm_low", quiet=quiet)
  high = train_high("waypoint", low.run_dir,
                    configs.high_config("waypoint", 32, total_env_steps=8000, num_envs=8,
                                        updates_per_step=8, steps_per_chunk=125),
                    seeds=2, out=out / "pm_high", quiet=quiet)
  ev = evaluate(compose(high.run_dir, low.run_dir), "waypoint", episodes=20)
  print(f"\nWaypoint return, PM HL on PM LL, 2 seeds x 20 episodes: "
        f"{ev['return_mean']:.0f} ± {ev['return_std']:.0f} (paper, full budget: 1021 ± 43)")
  print(f"run directories: {low.run_dir}  {high.run_dir}")


def main(argv=None) -> int:
  p = argparse.ArgumentParser(prog="hdt", description=__doc__)
  sub = p.add_subparsers(dest="cmd", required=True)
  q = sub.add_parser("quickstart", help="train a PM LL + HL on Waypoint and evaluate (minutes on a CPU)")
  q.add_argument("--out", type=Path, default=Path("runs/quickstart"), help="run directory root (default: %(default)s)")
  q.add_argument("--quiet", action="store_true", help="no progress output")
  a = p.parse_args(argv)
  if a.cmd == "quickstart":
    quickstart(a.out, a.quiet)
  return 0


if __name__ == "__main__":
  sys.exit(main())
