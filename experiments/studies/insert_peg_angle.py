"""Why the PM's PegInsert HL fails zero-shot on the 3Link insert LL (RESULTS.md, PegInsert): the angle
of the peg from vertical where it comes closest to the slot, per LL seed, over the zoo policies.

The slot is 0.014 m wide (|x| < 0.007 between the capsule ends at y = -0.18) and the peg 0.01 m thick,
so it fits only within about 24 degrees of vertical (0.01 / cos a < 0.014 - clearance).

  python experiments/studies/insert_peg_angle.py [LOW ...]   # default: the PM's and 3Link's zoo insert LLs"""

import sys
from pathlib import Path

import numpy as np

from hdt import envs
from hdt.transfer.evaluate import hl_rollouts
from hdt.transfer.hierarchy import HighLevelEnv

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))
import scripted  # noqa: E402  (the scripted controllers of tests/test_fidelity.py)


def deepest(high: str, low: str, episodes: int = 16):
  record = lambda s, n: (n.obs_hi, n.metrics["success"], n.done)
  rows = []
  for i, (_, (hi, succ, done)) in enumerate(hl_rollouts(high, low, record, episodes)):
    alive = np.cumsum(done, 1) == 0  # before the episode's end (its last state is the next reset's)
    y = np.where(alive, hi[..., 1], np.inf)
    j = np.argmin(y, 1)
    at_min = hi[np.arange(episodes), j]
    d = at_min[:, :2] - at_min[:, 2:4]  # peg tip minus fingertip
    angle = np.degrees(np.abs(np.arctan2(d[:, 0], -d[:, 1])))  # 0 = pointing straight down (-y)
    rows.append((i, float(np.max(succ * (np.cumsum(done, 1) <= 1), 1).mean()), float(np.median(angle)),
                 float(np.median(at_min[:, 0])), float(np.median(at_min[:, 1]))))
  return rows


def scripted_3link(starts: int = 4) -> dict[str, int]:
  """Insertions by a scripted arm LL straight down the slot's axis, with and without driving the peg to
  point down (the fingertip 5 cm above the peg tip)."""
  env = envs.make("arm3", "insert")
  path = [(0.0, -0.10), (0.0, -0.13), (0.0, -0.16), (0.0, -0.2)]
  out = {}
  for label, kw in (("peg tip only", {}), ("peg tip and peg pointing down", {"tool_dir": (0.0, -1.0)})):
    hl = HighLevelEnv(env, scripted.arm_ll(env, tool=0.05, **kw), None)
    out[label] = sum(scripted.run_script(hl, scripted.path_script(path, 0.006), key=k)[0] for k in range(starts))
  return out


if __name__ == "__main__":
  lows = sys.argv[1:]  # insert LLs to measure (zoo names or run dirs); default the PM's and 3Link's, then the scripted arm
  for low in lows or ("zoo:arm_point/low_insert_1p2m", "zoo:arm3/low_insert"):
    for i, succ, ang, x, y in deepest("zoo:arm_point/insert_1p2m", low):
      print(f"PM insert HL over {low} seed {i}: success {succ:.2f}, at the peg's deepest point "
            f"(median over episodes) angle from vertical {ang:.0f} deg, peg tip ({x:+.3f}, {y:+.3f})")
  for label, n in ({} if lows else scripted_3link()).items():
    print(f"scripted 3Link LL ({label}) down the slot's axis: inserted from {n} of 4 starts")
