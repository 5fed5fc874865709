import numpy as np
import pytest
from apf_swarm_core.gains import per_run, shaped


def test_shaped_keeps_one_value_0d_and_broadcasts_per_run_values():
    one = shaped(2.5)
    assert one.shape == () and one.dtype == np.float64 and float(one) == 2.5
    runs = shaped([1.0, 2.0, 3.0])
    assert runs.shape == (3, 1, 1)
    assert (runs * np.ones((3, 4, 3))).shape == (3, 4, 3)
    assert shaped([1.0, 2.0], 1).shape == (2, 1) and shaped([1.0, 2.0], 0).shape == (2,)


def test_per_run_is_0d_when_every_run_shares_the_gain():
    assert per_run([0.5, 0.5, 0.5]).shape == ()
    np.testing.assert_array_equal(per_run([0.5, 0.7]), [0.5, 0.7])
    with pytest.raises(ValueError, match='at least one run'):
        per_run([])
