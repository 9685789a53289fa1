"""benchmarks/results.json: the headline numbers of the benchmarks, one key each, merged in place.

Each benchmark calls ``update({...})`` with the keys it measured; keys of other benchmarks stay.
``python benchmarks/results.py`` (re)derives ``update_matmul_peak_fraction`` from
``benchmarks/sac_throughput.json`` (paper sizes [400,300] batch 100, one seed) and prints the file.
"""

from __future__ import annotations

import json
import os
import time

HERE = os.path.dirname(os.path.abspath(__file__))
PATH = os.path.join(HERE, "results.json")


def update(values: dict, source: str, path: str = PATH, load: float | None = None) -> dict:
  """Merge ``values`` (plain numbers) into results.json; records where and when each key came from.
  Under ``XLA_FLAGS`` (an experiment, not the default setup) nothing is merged."""
  if os.environ.get("XLA_FLAGS"):
    print(f"results.json not updated: XLA_FLAGS={os.environ['XLA_FLAGS']!r} is set (headline numbers use the "
          f"default XLA setup); unset it to record {sorted(values)}")
    return {}
  data = {}
  if os.path.exists(path):
    with open(path) as f:
      data = json.load(f)
  meta = data.setdefault("_sources", {})
  stamp = time.strftime("%Y-%m-%d %H:%M:%S")
  load = os.getloadavg()[0] if load is None else load
  for k, v in values.items():
    data[k] = None if v is None else float(v)
    meta[k] = f"{source} ({stamp}, load avg {load:.1f})"
  with open(path, "w") as f:
    json.dump(dict(sorted(data.items())), f, indent=2)
  return data


def from_sac_throughput(path: str = os.path.join(HERE, "sac_throughput.json")) -> dict:
  with open(path) as f:
    d = json.load(f)
  row = next(r for r in d["updates"] if list(r["hidden"]) == [400, 300] and r["batch"] == 100)
  return ({"update_matmul_peak_fraction": row["pct_of_matmul_1seed"] / 100.0},
          d["machine"]["loadavg_at_end"][0])


if __name__ == "__main__":
  vals, load = from_sac_throughput()
  update(vals, "benchmarks/sac_throughput.json, ant LL [400,300] b100, 1 seed", load=load)
  with open(PATH) as f:
    print(f.read())
