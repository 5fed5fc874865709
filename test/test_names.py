"""The floors of the layout that a grep can hold: every ROS name of the swarm is said in one
module (:mod:`apf_swarm_nodes.topics`, or :mod:`apf_swarm_core.names` for what the core must
know), a node names its topics through it, nothing under src/ imports rclpy's private API
(``rclpy.impl``, ``_rclpy``), and the library layers raise their own errors, not the command
line's."""

from __future__ import annotations

import ast
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / 'src'
#: the two modules allowed to spell a name
NAME_MODULES = {
    SRC / 'apf_swarm_nodes' / 'apf_swarm_nodes' / 'topics.py',
    SRC / 'apf_swarm_core' / 'apf_swarm_core' / 'names.py',
}
#: a string that is a ROS name of the swarm (whole, or as a remapping ``__ns:=/uav_{i}``):
#: ``{}`` stands for a formatted value of an f-string
_NAME = re.compile(r'(^|:=)/(swarm|target|uav_|clock|recorder|plant)[\w/{}~]*$')
#: rclpy calls whose topic argument must be a name from the names module, not a literal
_TOPIC_CALLS = {
    'create_publisher': 1,
    'create_subscription': 1,
    'count_publishers': 0,
    'count_subscribers': 0,
    'get_publishers_info_by_topic': 0,
    'get_subscriptions_info_by_topic': 0,
}


def _modules() -> Iterator[tuple[Path, ast.Module]]:
    for path in sorted(SRC.rglob('*.py')):
        if 'build' in path.parts or '__pycache__' in path.parts:
            continue
        yield path, ast.parse(path.read_text(), str(path))


def _text(node: ast.expr) -> str | None:
    """A string literal's text, an f-string's with ``{}`` for each formatted value."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr):
        return ''.join(v.value if isinstance(v, ast.Constant) else '{}' for v in node.values)
    return None


def _is_literal(node: ast.expr) -> bool:
    return _text(node) is not None


def _where(path: Path, node: ast.AST) -> str:
    return f'{path.relative_to(SRC)}:{getattr(node, "lineno", "?")}'


def test_each_ros_name_is_said_in_one_module() -> None:
    found = []
    for path, tree in _modules():
        if path in NAME_MODULES:
            continue
        inner = {id(v) for n in ast.walk(tree) if isinstance(n, ast.JoinedStr) for v in n.values}
        for node in ast.walk(tree):
            if id(node) in inner or not isinstance(node, (ast.Constant, ast.JoinedStr)):
                continue
            text = _text(node)
            if text is not None and _NAME.search(text):
                found.append(f'{_where(path, node)}: {text!r}')
    assert not found, 'ROS names spelt outside apf_swarm_nodes.topics:\n' + '\n'.join(found)


def test_nodes_name_their_topics_through_the_names_module() -> None:
    found = []
    for path, tree in _modules():
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)):
                continue
            pos = _TOPIC_CALLS.get(node.func.attr)
            if pos is None:
                continue
            args = list(node.args[pos : pos + 1]) + [
                k.value for k in node.keywords if k.arg == 'topic'
            ]
            if any(_is_literal(a) for a in args):
                found.append(f'{_where(path, node)}: {node.func.attr} with a literal topic')
    assert not found, '\n'.join(found)


def test_the_names_are_distinct() -> None:
    from apf_swarm_nodes import topics

    absolute = [
        v for k, v in vars(topics).items() if k.isupper() and isinstance(v, str) and v[:1] == '/'
    ]
    assert len(absolute) == len(set(absolute)), absolute
    assert topics.odom_topic(3) == '/uav_3/odom' and topics.force_topic(3) == '/uav_3/force_cmd'
    assert topics.UAV_TOPIC.match('/uav_12/velocity_cmd') and not topics.UAV_TOPIC.match(
        '/uav_/odom'
    )


def test_no_private_rclpy_api() -> None:
    found = []
    for path, tree in _modules():
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ''] + [f'{node.module}.{a.name}' for a in node.names]
            else:
                continue
            if any(n.startswith('rclpy.impl') or '_rclpy' in n for n in names):
                found.append(f'{_where(path, node)}: {", ".join(names)}')
    assert not found, 'rclpy private API imported:\n' + '\n'.join(found)


def test_library_layers_raise_their_own_errors() -> None:
    # every layer raises its own error (ConfigError, AnalysisError, BagError, BringupError,
    # DdsError, ViewError...); the command lines turn them into messages: no CliError left
    found = [
        _where(path, n)
        for path, tree in _modules()
        for n in ast.walk(tree)
        if (isinstance(n, ast.Name) and n.id == 'CliError')
        or (isinstance(n, ast.alias) and n.name == 'CliError')
        or (isinstance(n, ast.ClassDef) and n.name == 'CliError')
    ]
    assert not found, 'CliError in a library layer:\n' + '\n'.join(found)


@pytest.mark.parametrize('planted', ["x = '/swarm/state'\n", "x = f'/uav_{i}/odom'\n"])
def test_the_scan_finds_a_planted_name(planted: str) -> None:
    tree = ast.parse(planted)
    texts = [_text(n) for n in ast.walk(tree) if isinstance(n, (ast.Constant, ast.JoinedStr))]
    assert any(t is not None and _NAME.search(t) for t in texts)
