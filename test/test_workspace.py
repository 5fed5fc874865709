"""Workspace sanity: what `make setup` built is complete and usable.

Run in the workspace environment (`make test`, or `source scripts/activate.sh` then
`python -m pytest test`). Needs no running ROS graph.

(a) every console_script of apf_swarm_nodes / apf_swarm_core is where `ros2 run <pkg> <exe>`
    looks for it (ament index prefix + lib/<pkg>/<exe>), executable, and its entry point loads;
(b) apf_swarm_msgs imports, constructs, and survives a CDR serialize -> deserialize round trip;
(c) the installed .msg definitions match the sources, and rosbags reads rclpy's CDR bytes of
    the custom messages when the types are registered from that .msg text (as the recorder does).
"""

import ast
import contextlib
import importlib.metadata
import math
import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PY_PACKAGES = ('apf_swarm_core', 'apf_swarm_nodes')
ALL_PACKAGES = ('apf_swarm_msgs', *PY_PACKAGES)
MSG_NAMES = ('ForceCommand', 'ForceCommands', 'SwarmOdometry', 'SwarmState')


def _installed_console_scripts(pkg):
    """Console scripts of the installed distribution `pkg` (entry point objects)."""
    dist = importlib.metadata.distribution(pkg)
    return sorted(
        (ep for ep in dist.entry_points if ep.group == 'console_scripts'), key=lambda ep: ep.name
    )


def _declared_console_scripts(pkg):
    """Names in the `console_scripts` list of src/<pkg>/setup.py (None if not parseable)."""
    tree = ast.parse((ROOT / 'src' / pkg / 'setup.py').read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Dict):
            for key, value in zip(node.keys, node.values, strict=False):
                if isinstance(key, ast.Constant) and key.value == 'console_scripts':
                    try:
                        entries = ast.literal_eval(value)
                    except ValueError:
                        return None
                    return sorted(e.split('=', 1)[0].strip() for e in entries)
    return None


def _all_console_scripts():
    out = []
    for pkg in PY_PACKAGES:
        # a missing package is reported by test_python_packages_installed
        with contextlib.suppress(importlib.metadata.PackageNotFoundError):
            out.extend((pkg, ep) for ep in _installed_console_scripts(pkg))
    return out


CONSOLE_SCRIPTS = _all_console_scripts()


# --------------------------------------------------------------------------------------------
# (a) ament index and `ros2 run` lookup
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize('pkg', ALL_PACKAGES)
def test_package_registered_in_ament_index(pkg):
    from ament_index_python.packages import get_package_prefix, get_package_share_directory

    prefix = Path(get_package_prefix(pkg))
    assert prefix.resolve() == (ROOT / 'install' / pkg).resolve(), (
        f'{pkg} resolves to {prefix}, not to this workspace: source scripts/activate.sh'
    )
    share = Path(get_package_share_directory(pkg))
    assert share == prefix / 'share' / pkg
    assert (share / 'package.xml').is_file()


def test_wheel_packages_in_ament_index():
    # The venv must be on AMENT_PREFIX_PATH so that the wheels' packages are found.
    from ament_index_python.packages import get_package_share_directory

    for pkg in (
        'rclpy',
        'std_msgs',
        'geometry_msgs',
        'nav_msgs',
        'rosgraph_msgs',
        'visualization_msgs',
    ):
        assert (Path(get_package_share_directory(pkg)) / 'package.xml').is_file(), pkg


@pytest.mark.parametrize('pkg', PY_PACKAGES)
def test_python_packages_installed(pkg):
    importlib.metadata.distribution(pkg)  # raises PackageNotFoundError if not built
    declared = _declared_console_scripts(pkg)
    if declared is not None:
        installed = [ep.name for ep in _installed_console_scripts(pkg)]
        assert installed == declared, (
            f'{pkg}: setup.py declares {declared} but the build has {installed}: run make setup'
        )


def test_console_scripts_found():
    names = [ep.name for _, ep in CONSOLE_SCRIPTS]
    assert names, 'no console_scripts found in apf_swarm_nodes / apf_swarm_core'
    assert 'apf-swarm' in names


@pytest.mark.parametrize('pkg,ep', CONSOLE_SCRIPTS, ids=[ep.name for _, ep in CONSOLE_SCRIPTS])
def test_ros2_run_lookup(pkg, ep):
    # What `ros2 run <pkg> <exe>` does: <ament prefix of pkg>/lib/<pkg>/<exe>.
    from ament_index_python.packages import get_package_prefix

    exe = Path(get_package_prefix(pkg)) / 'lib' / pkg / ep.name
    assert exe.is_file(), f'{exe} missing (setup.cfg install_scripts / script_dir?)'
    assert os.access(exe, os.X_OK), f'{exe} is not executable'
    first = exe.read_text().splitlines()[0]
    assert first.startswith('#!')
    interpreter = first[2:].strip().split()[0]
    assert os.access(interpreter, os.X_OK), f'{exe}: interpreter {interpreter} missing'
    assert callable(ep.load()), f'{ep.value} does not load to a callable'


def test_apf_swarm_on_path_but_not_node_executables():
    found = shutil.which('apf-swarm')
    assert found, 'apf-swarm not on PATH: source scripts/activate.sh'
    assert Path(found).resolve() == (ROOT / '.venv' / 'bin' / 'apf-swarm').resolve()
    for entry in os.environ.get('PATH', '').split(os.pathsep):
        assert not entry.rstrip('/').endswith('lib/apf_swarm_nodes'), entry
    res = subprocess.run(
        [found, '--help'],
        capture_output=True,
        text=True,
        timeout=120,
        stdin=subprocess.DEVNULL,
        check=False,
    )
    assert res.returncode == 0, res.stdout + res.stderr
    assert 'usage' in (res.stdout + res.stderr).lower()


# --------------------------------------------------------------------------------------------
# (b) apf_swarm_msgs
# --------------------------------------------------------------------------------------------


def _vec(cls, x, y, z):
    return cls(x=float(x), y=float(y), z=float(z))


def _force_command():
    from geometry_msgs.msg import Vector3

    from apf_swarm_msgs.msg import ForceCommand

    msg = ForceCommand()
    msg.header.stamp.sec = 12
    msg.header.stamp.nanosec = 345_678_901
    msg.header.frame_id = 'world'
    msg.uav_id = 3
    msg.step = 2**40 + 7
    msg.law = ForceCommand.LAW_TRADITIONAL
    msg.force = _vec(Vector3, -125.0, 125.0, 0.125)
    msg.sliding_surface = _vec(Vector3, 1e-9, -2.5, 3.25)
    msg.gradient = _vec(Vector3, 0.1, 0.2, -0.3)
    msg.filter_state = _vec(Vector3, 2.0, -2.0, 1.5)
    msg.saturated = True
    msg.stale = False
    return msg


def _swarm_state():
    from geometry_msgs.msg import Point, Vector3

    from apf_swarm_msgs.msg import SwarmState

    msg = SwarmState()
    msg.header.stamp.sec = 7
    msg.header.stamp.nanosec = 500
    msg.header.frame_id = 'world'
    msg.step = 1234
    msg.sim_time = 12.34
    msg.uav_ids = [1, 2, 3]
    msg.positions = [_vec(Point, i, -i, 0.5 * i) for i in (1, 2, 3)]
    msg.velocities = [_vec(Vector3, 0.1 * i, 0.2, -0.3) for i in (1, 2, 3)]
    msg.forces = [_vec(Vector3, 125.0, -125.0, 9.81) for _ in range(3)]
    msg.sliding_surfaces = [_vec(Vector3, -1.0, 0.0, 1.0) for _ in range(3)]
    msg.target_position = _vec(Point, 0.0, 0.0, 5.0)
    msg.target_velocity = _vec(Vector3, 10.0, 0.0, 0.0)
    msg.potential = 3.5
    msg.centroid_error = 0.01
    msg.formation_error = float('nan')
    msg.missed_deadlines = 2
    msg.stale_inputs = 3
    msg.rejected_inputs = 4
    msg.active = [True, False, True]
    msg.command_latency = [0.001, 0.002, 0.003]  # the plant fills one entry per tracker
    return msg


def _assert_vec(a, b):
    for f in ('x', 'y', 'z'):
        assert getattr(a, f) == pytest.approx(getattr(b, f), rel=1e-12, abs=1e-15), f


def test_msgs_construct_and_constants():
    from apf_swarm_msgs.msg import ForceCommand, SwarmState

    assert ForceCommand.LAW_PROPOSED == 0
    assert ForceCommand.LAW_TRADITIONAL == 1
    fc = ForceCommand()
    assert fc.law == ForceCommand.LAW_PROPOSED and not fc.saturated and not fc.stale
    ss = SwarmState()
    assert len(ss.uav_ids) == 0 and ss.positions == []
    assert ForceCommand.__module__.startswith('apf_swarm_msgs.msg')
    assert SwarmState.__module__.startswith('apf_swarm_msgs.msg')


def test_force_command_roundtrip():
    from rclpy.serialization import deserialize_message, serialize_message

    from apf_swarm_msgs.msg import ForceCommand

    src = _force_command()
    data = serialize_message(src)
    assert isinstance(data, bytes) and len(data) > 0
    out = deserialize_message(data, ForceCommand)
    assert out.header.stamp.sec == 12 and out.header.stamp.nanosec == 345_678_901
    assert out.header.frame_id == 'world'
    assert (out.uav_id, out.step, out.law) == (3, 2**40 + 7, ForceCommand.LAW_TRADITIONAL)
    for f in ('force', 'sliding_surface', 'gradient', 'filter_state'):
        _assert_vec(getattr(out, f), getattr(src, f))
    assert out.saturated is True and out.stale is False
    assert out == src


def test_swarm_state_roundtrip():
    from rclpy.serialization import deserialize_message, serialize_message

    from apf_swarm_msgs.msg import SwarmState

    src = _swarm_state()
    out = deserialize_message(serialize_message(src), SwarmState)
    assert out.header.stamp.sec == 7 and out.header.stamp.nanosec == 500
    assert out.header.frame_id == 'world'
    assert out.step == 1234 and out.sim_time == pytest.approx(12.34)
    assert list(out.uav_ids) == [1, 2, 3]
    for name in ('positions', 'velocities', 'forces', 'sliding_surfaces'):
        got, want = getattr(out, name), getattr(src, name)
        assert len(got) == len(want) == 3, name
        for a, b in zip(got, want, strict=False):
            _assert_vec(a, b)
    _assert_vec(out.target_position, src.target_position)
    _assert_vec(out.target_velocity, src.target_velocity)
    assert out.potential == pytest.approx(3.5)
    assert out.centroid_error == pytest.approx(0.01)
    assert math.isnan(out.formation_error)
    assert (out.missed_deadlines, out.stale_inputs, out.rejected_inputs) == (2, 3, 4)


def test_numpy_arrays_in_wheel_messages():
    # The wheels' own generated code (compiled against NumPy 2 headers) with the pinned NumPy.
    import numpy as np
    from nav_msgs.msg import Odometry
    from rclpy.serialization import deserialize_message, serialize_message

    odom = Odometry()
    odom.pose.covariance = np.arange(36, dtype=np.float64)
    out = deserialize_message(serialize_message(odom), Odometry)
    assert isinstance(out.pose.covariance, np.ndarray)
    assert np.array_equal(out.pose.covariance, np.arange(36, dtype=np.float64))


# --------------------------------------------------------------------------------------------
# (c) message definitions
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize('name', MSG_NAMES)
def test_installed_definition_matches_source(name):
    from ament_index_python.packages import get_package_share_directory

    installed = Path(get_package_share_directory('apf_swarm_msgs')) / 'msg' / f'{name}.msg'
    source = ROOT / 'src' / 'apf_swarm_msgs' / 'msg' / f'{name}.msg'
    assert installed.read_text() == source.read_text(), 'stale build: run make setup'


def test_every_source_msg_is_generated():
    import apf_swarm_msgs.msg as msgs

    names = sorted(p.stem for p in (ROOT / 'src' / 'apf_swarm_msgs' / 'msg').glob('*.msg'))
    assert names == sorted(MSG_NAMES)
    for name in names:
        assert hasattr(msgs, name), name


def test_rosbags_reads_rclpy_cdr():
    """rosbags (the recorder's writer) and rclpy agree on the CDR of the custom types."""
    from ament_index_python.packages import get_package_share_directory
    from rclpy.serialization import serialize_message
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    share = Path(get_package_share_directory('apf_swarm_msgs')) / 'msg'
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for name in MSG_NAMES:
        types.update(
            get_types_from_msg((share / f'{name}.msg').read_text(), f'apf_swarm_msgs/msg/{name}')
        )
    store.register(types)

    fc = store.deserialize_cdr(
        serialize_message(_force_command()), 'apf_swarm_msgs/msg/ForceCommand'
    )
    assert (fc.uav_id, fc.step, fc.law, fc.saturated) == (3, 2**40 + 7, 1, True)
    assert fc.force.x == pytest.approx(-125.0) and fc.header.frame_id == 'world'

    src = _swarm_state()
    ss = store.deserialize_cdr(serialize_message(src), 'apf_swarm_msgs/msg/SwarmState')
    assert list(ss.uav_ids) == [1, 2, 3]
    assert [(p.x, p.y, p.z) for p in ss.positions] == [(p.x, p.y, p.z) for p in src.positions]
    assert math.isnan(ss.formation_error) and ss.rejected_inputs == 4

    # and back: rosbags' CDR deserializes in rclpy
    from rclpy.serialization import deserialize_message

    from apf_swarm_msgs.msg import SwarmState

    again = deserialize_message(
        bytes(store.serialize_cdr(ss, 'apf_swarm_msgs/msg/SwarmState')), SwarmState
    )
    assert list(again.uav_ids) == [1, 2, 3] and again.step == 1234
