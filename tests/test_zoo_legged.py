"""The legged agents' zoo entries re-evaluate to their recorded checks (the others: test_zoo.py; a file
of their own, which pytest-xdist's loadfile runs beside the rest)."""

import pytest

from hdt.transfer import configs, zoo


@pytest.mark.parametrize("name", [n for n in zoo.entry_names() if configs.family_key(n.split("/")[0]) == "legged"])
def test_legged_zoo_entry_reevaluates_to_its_recorded_check(name):
  recorded, fresh = zoo.recheck(name)
  assert not zoo.within_noise(recorded, fresh), f"{name}: {'; '.join(zoo.within_noise(recorded, fresh))}"
