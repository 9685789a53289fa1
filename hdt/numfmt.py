"""How hdt writes a number for people: a few significant digits, and whole numbers once the digits run out
(a Waypoint return of 1004.9 reads 1005, not 1e+03)."""

from __future__ import annotations


def number(x: float, digits: int = 3) -> str:
  """``x`` to ``digits`` significant digits; where that would need an exponent of ``digits`` or more
  (1004.9, or 999.7 rounding up), a whole number instead."""
  short = f"{x:.{digits}g}"
  return f"{x:.0f}" if "e+" in short else short


def mean_std(mean: float, std: float) -> str:
  """``mean ± std`` as hdt's tables show it."""
  return f"{number(mean)} ± {number(std, 2)}"
