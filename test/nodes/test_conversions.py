"""Where messages meet arrays (apf_swarm_nodes.conversions): round trips and refusals."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip('apf_swarm_msgs.msg', reason='apf_swarm_msgs is not built: make setup')

from apf_swarm_nodes.conversions import stamp_ns, step_stamp, swarm_odom_arrays, swarm_odom_msg


def _odom(**kw):
    rng = np.random.default_rng(0)
    x, v = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
    args = {
        'step': 7,
        'stamp': step_stamp(7, 10_000_000),
        'uav_ids': [1, 2, 3],
        'x': x,
        'v': v,
        'target_x': np.array([1.0, 2.0, 3.0]),
        'target_v': np.array([0.5, 0.0, 0.0]),
    }
    args.update(kw)
    return args, swarm_odom_msg(**args)


def test_swarm_odometry_round_trips_with_and_without_command_latency() -> None:
    args, msg = _odom(command_latency=np.array([0.004, 0.0, 0.011]), active=[True, False, True])
    m = swarm_odom_arrays(msg)
    assert m.step == 7 and m.stamp_ns == stamp_ns(step_stamp(7, 10_000_000)) == 70_000_000
    assert m.uav_ids == [1, 2, 3] and m.active == [True, False, True]
    assert np.array_equal(m.x, args['x']) and np.array_equal(m.v, args['v'])
    assert np.array_equal(m.target_x, args['target_x'])
    assert np.array_equal(m.command_latency, [0.004, 0.0, 0.011])
    _, lockstep = _odom()  # lockstep: no latencies, every tracker active
    m = swarm_odom_arrays(lockstep)
    assert m.command_latency.size == 0 and m.active == [True, True, True]


def test_swarm_odometry_with_the_wrong_number_of_latencies_is_refused_by_name() -> None:
    _, msg = _odom()
    msg.command_latency = [0.001, 0.002]
    with pytest.raises(ValueError, match='2 command latencies; expected none or one per id'):
        swarm_odom_arrays(msg)
