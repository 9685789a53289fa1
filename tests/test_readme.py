"""The README's Python example runs as written (budgets, episode counts and output paths made small),
so it cannot drift from the API."""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def python_example() -> str:
  blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)
  assert len(blocks) == 1, "the README should hold exactly one Python example"
  return blocks[0]


def shrink(code: str, out: Path) -> str:
  """Smaller budgets and episode counts, outputs under ``out``; every substitution must apply."""
  small = code
  for pattern, repl in ((r"total_env_steps=[\d_]+", "total_env_steps=800"), (r"episodes=\d+", "episodes=2"),
                        (r'out="runs/', f'out="{out}/')):
    small, n = re.subn(pattern, repl, small)
    assert n > 0, f"the README example no longer has {pattern!r}; update this test with it"
  return small


def test_readme_python_example_runs(tmp_path, capsys):
  code = shrink(python_example(), tmp_path)
  scope: dict = {}
  exec(compile(code, str(README), "exec"), scope)
  printed = capsys.readouterr().out
  assert printed.count("return_mean") == 3  # three evaluations printed
  for name in ("low", "high", "aligned", "tuned"):
    run = Path(scope[name].run_dir)
    assert run.is_relative_to(tmp_path) and (run / "meta.json").is_file(), name
  assert "uniform random actions" in printed
