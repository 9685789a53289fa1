"""What the repository records (benchmark and experiment results, documentation) names no machine:
no absolute path of the machine that produced it."""

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MACHINE_PATH = re.compile(r"""(?<![\w.<>])/(?:tmp|work|root|home|Users)/""")


def tracked_records() -> list[Path]:
  try:
    out = subprocess.run(["git", "ls-files", "benchmarks", "experiments", "*.md"], cwd=ROOT, capture_output=True,
                         text=True, check=True).stdout.split()
    files = [ROOT / f for f in out]
  except (OSError, subprocess.CalledProcessError):  # not a git checkout
    files = [*ROOT.glob("benchmarks/**/*"), *ROOT.glob("experiments/**/*"), *ROOT.glob("*.md")]
  return [f for f in files if f.is_file() and f.suffix in (".json", ".md", ".csv")]


def test_recorded_results_and_docs_name_no_machine_path():
  bad = [f"{f.relative_to(ROOT)}:{i}" for f in tracked_records()
         for i, line in enumerate(f.read_text(errors="replace").splitlines(), 1) if MACHINE_PATH.search(line)]
  assert not bad, f"absolute machine paths in {bad[:10]}: record paths relative to the repository"


def test_the_machine_path_check_catches_one():
  assert MACHINE_PATH.search('"compile_cache": "/tmp/hdt-ttq-1"')
  assert not MACHINE_PATH.search('"compile_cache": "<tmp>/hdt-ttq-1"')
