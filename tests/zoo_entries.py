"""The zoo's entries as the suite splits them: the legged agents' (long episodes, test_zoo_legged.py,
which pytest-xdist's loadfile runs beside the rest) and the others (test_zoo.py). One rule, so no entry
is left out or checked twice."""

from hdt.transfer import configs, zoo


def entries(legged: bool) -> list[str]:
  return [n for n in zoo.entry_names() if (configs.family_key(n.split("/")[0]) == "legged") == legged]
