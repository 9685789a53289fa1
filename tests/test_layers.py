"""hdt's import graph (DESIGN.md, "Layers"): no import circle, and no import against the layer table.

Every import statement of every module counts, at module level or inside a function, so that a
function-local import cannot hide a circle. Read with ``ast``: nothing is imported.
"""

import ast
from pathlib import Path

HDT = Path(__file__).resolve().parents[1] / "hdt"

# package -> packages it never imports (DESIGN.md's layer table)
NEVER = {
    "hdt.envs": ("hdt.agents", "hdt.transfer", "hdt.cli", "hdt.report", "hdt.render", "hdt.paper"),
    "hdt.agents": ("hdt.transfer", "hdt.cli", "hdt.report", "hdt.render", "hdt.paper"),
    "hdt.transfer": ("hdt.cli", "hdt.report", "hdt.render", "hdt.plots", "hdt.paper"),
    "hdt.paper": ("hdt.cli", "hdt.render"),  # the CLI is a thin layer over it
}
LEAVES = ("hdt.version", "hdt.atomic", "hdt.numfmt", "hdt.interrupt", "hdt.progress", "hdt.cache", "hdt.plots",
          "hdt.transfer.names")  # import no hdt module but hdt.atomic and hdt.numfmt
SHARED = {"hdt.atomic", "hdt.numfmt"}  # how hdt writes a file, and a number


def modules() -> dict[str, Path]:
  out = {}
  for path in HDT.rglob("*.py"):
    parts = path.relative_to(HDT.parent).with_suffix("").parts
    out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
  return out


def imports(path: Path, known: dict) -> set[str]:
  """The hdt modules ``path`` imports anywhere in its code."""
  found = set()
  for node in ast.walk(ast.parse(path.read_text())):
    if isinstance(node, ast.Import):
      found |= {a.name for a in node.names}
    elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
      subs = {f"{node.module}.{a.name}" for a in node.names} & set(known)  # from hdt.transfer import names
      found |= subs or {node.module}
  return {m for m in found if m in known}


def graph() -> dict[str, set[str]]:
  known = modules()
  return {m: imports(p, known) - {m} for m, p in known.items()}


def circles(g: dict[str, set[str]]) -> list[list[str]]:
  """The strongly connected components of more than one module (Tarjan)."""
  index, low, stack, on, out = {}, {}, [], set(), []

  def visit(v):
    index[v] = low[v] = len(index)
    stack.append(v)
    on.add(v)
    for w in sorted(g[v]):
      if w not in index:
        visit(w)
        low[v] = min(low[v], low[w])
      elif w in on:
        low[v] = min(low[v], index[w])
    if low[v] == index[v]:
      comp = []
      while True:
        w = stack.pop()
        on.discard(w)
        comp.append(w)
        if w == v:
          break
      if len(comp) > 1:
        out.append(sorted(comp))

  for v in sorted(g):
    if v not in index:
      visit(v)
  return out


def test_no_import_circles():
  assert circles(graph()) == []


def test_no_import_against_the_layer_table():
  bad = [f"{m} imports {t}" for m, targets in graph().items() for t in targets
         for pkg, never in NEVER.items() if (m == pkg or m.startswith(pkg + "."))
         and any(t == n or t.startswith(n + ".") for n in never)]
  assert bad == []


def test_leaves_import_no_other_hdt_module():
  g = graph()
  assert {m: sorted(g[m] - SHARED) for m in LEAVES if g[m] - SHARED} == {}


def test_the_circle_finder_finds_a_circle():
  assert circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
