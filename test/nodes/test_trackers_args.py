"""The ``trackers`` executable's own argument: which tracker ids one process hosts."""

from __future__ import annotations

import pytest
from apf_swarm_nodes.bringup import node_commands
from apf_swarm_nodes.trackers_node import parse_uav_ids


@pytest.mark.parametrize(
    'text, ids',
    [('1', [1]), ('1,2,3', [1, 2, 3]), ('4-6', [4, 5, 6]), ('1-2,5,7-8', [1, 2, 5, 7, 8])],
)
def test_parse_uav_ids(text: str, ids: list[int]) -> None:
    assert parse_uav_ids(text) == ids


@pytest.mark.parametrize(
    'text, needle',
    [
        ('x', 'expected ids'),
        ('0', '1-based'),
        ('3-1', 'ascending'),
        ('1,2,1', 'twice'),
        ('', 'expected ids'),
    ],
)
def test_parse_uav_ids_refuses(text: str, needle: str) -> None:
    with pytest.raises(ValueError, match=needle):
        parse_uav_ids(text)


def test_node_commands_group_the_trackers(tmp_path) -> None:
    cmds = dict(node_commands(tmp_path, tmp_path / 'c.yaml', 7, 'lockstep', per_process=3))
    assert sorted(cmds) == ['plant', 'target', 'trackers_1-3', 'trackers_4-6', 'trackers_7-7']
    argv = cmds['trackers_4-6']
    assert argv[0].endswith('/trackers') and argv[1:3] == ['--uav-ids', '4-6']
    assert '__ns:=' not in ' '.join(argv)  # each node gets its own namespace
    single = dict(node_commands(tmp_path, tmp_path / 'c.yaml', 2, 'lockstep'))
    assert sorted(single) == ['plant', 'target', 'tracker_1', 'tracker_2']


def test_outputs_parameter() -> None:
    from apf_swarm_core.errors import ConfigError
    from apf_swarm_nodes.params import parse_outputs

    assert parse_outputs('force') == {'force'}
    assert parse_outputs('accel, velocity') == {'force', 'accel', 'velocity'}
    with pytest.raises(ConfigError, match="outputs = 'accel,thrust': expected"):
        parse_outputs('accel,thrust')
