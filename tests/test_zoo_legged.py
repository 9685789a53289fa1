"""The legged agents' zoo entries re-evaluate to their recorded checks (the others: test_zoo.py)."""

import pytest

from hdt.transfer import zoo
from tests.test_zoo import legged


@pytest.mark.parametrize("name", [n for n in zoo.entry_names() if legged(n)])
def test_legged_zoo_entry_reevaluates_to_its_recorded_check(name):
  recorded, fresh = zoo.recheck(name)
  assert not zoo.within_noise(recorded, fresh), f"{name}: {'; '.join(zoo.within_noise(recorded, fresh))}"
