"""Every zoo entry loads and re-evaluates to its recorded numbers (a change that breaks a checkpoint,
an env or the evaluation fails here), and zoo:NAME works wherever a run directory does."""

import numpy as np
import pytest

from hdt.transfer import evaluate as ev
from hdt.transfer import zoo


@pytest.mark.parametrize("name", zoo.names())
def test_zoo_entry_reevaluates_to_its_recorded_check(name):
  recorded, fresh = zoo.recheck(name)
  for k, v in recorded["per_seed"].items():
    np.testing.assert_allclose(fresh["per_seed"][k], v, rtol=1e-3, atol=1e-3, err_msg=f"{name}: {k}")


def test_zoo_names_resolve_and_an_hl_uses_the_ll_seed_it_was_trained_over():
  p = ev.compose("zoo:arm_point/push1", "zoo:arm_point/low")
  k = p.low_params["params"]["mlp"]["hidden_0"]["kernel"]
  assert k.shape[0] == 2 and np.array_equal(k[0], k[1])  # both HL seeds over LL seed 0
  # over another LL run (a transfer) HL seed i drives LL seed i
  assert ev.trained_over(p.meta, "zoo:arm_point/low") == 0 and ev.trained_over(p.meta, "zoo:arm3/low") is None


def test_unknown_zoo_name_is_one_clear_error():
  with pytest.raises(zoo.ZooError, match="no zoo entry 'nope'.*hdt zoo"):
    ev.compose("zoo:nope", "zoo:arm_point/low")
