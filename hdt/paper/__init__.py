"""The paper's tables and figures over hdt's Python API (``hdt reproduce NAME``): one module each
(:mod:`hdt.paper.table1`, ``table2``, ``table3``, ``fig6``, ``fig7``) describing its cells as data,
:mod:`hdt.paper.runs` for the runs behind them and :mod:`hdt.paper.table` for reproducing a table.

``reproduce("table1", "paper", out="runs/table1-paper")`` uses the zoo's policies, reuses the runs in
``out``, trains what is missing there (within the preset's ``max_env_steps``), and writes
``table1_paper.md``, ``.json`` and ``.png`` into ``out``.
"""

from __future__ import annotations

import importlib

NAMES = ("table1", "table2", "table3", "fig6", "fig7")


def load(name: str):
  """The :class:`hdt.paper.table.Table` named ``name`` (one of NAMES)."""
  if name not in NAMES:
    raise ValueError(f"unknown table {name!r}; choose one of {', '.join(NAMES)}")
  return importlib.import_module(f"hdt.paper.{name}").TABLE


def reproduce(name: str, preset: str = "cpu", out=None, **kw):
  """:func:`hdt.paper.table.reproduce` of the table ``name`` (keyword options as there)."""
  from hdt.paper.table import reproduce as run
  return run(load(name), preset, out, **kw)
