"""The legged agents' zoo entries re-evaluate to their recorded checks (the others: test_zoo.py)."""

import pytest
import zoo_entries

from hdt.transfer import zoo


@pytest.mark.parametrize("name", zoo_entries.entries(legged=True))
def test_legged_zoo_entry_reevaluates_to_its_recorded_check(name):
  recorded, fresh = zoo.recheck(name)
  assert not zoo.within_noise(recorded, fresh), f"{name}: {'; '.join(zoo.within_noise(recorded, fresh))}"
