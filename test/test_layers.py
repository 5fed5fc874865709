"""The layers of src/ as the imports draw them: the core never imports the nodes, no module
outside the bring-up (and the command lines above it) imports the bring-up, and no two
modules import each other, directly or around a loop (imports under ``TYPE_CHECKING`` are
for the type checker only and do not count). Each module says its public names in
``__all__``, and another module imports only those."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / 'src'
PACKAGES = (SRC / 'apf_swarm_core', SRC / 'apf_swarm_nodes')


def _modules() -> dict[str, Path]:
    out = {}
    for root in PACKAGES:
        for path in root.rglob('*.py'):
            if path.name == 'setup.py':
                continue
            parts = list(path.relative_to(root).with_suffix('').parts)
            if parts[-1] == '__init__':
                parts = parts[:-1]
            out['.'.join(parts)] = path
    return out


def _runtime_imports(tree: ast.Module) -> list[ast.Import | ast.ImportFrom]:
    """Every import statement but those under ``if TYPE_CHECKING:``."""
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and 'TYPE_CHECKING' in ast.unparse(node.test):
            skip.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    return [
        n
        for n in ast.walk(tree)
        if isinstance(n, (ast.Import, ast.ImportFrom)) and id(n) not in skip
    ]


def _source(node: ast.ImportFrom, mod: str, path: Path) -> str:
    """The module that ``node`` (in module ``mod``, file ``path``) imports from."""
    if not node.level:
        return node.module or ''
    package = (mod if path.name == '__init__.py' else mod.rsplit('.', 1)[0]).split('.')
    base = package[: len(package) - (node.level - 1)]
    return '.'.join(base + ([node.module] if node.module else []))


def import_graph(modules: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the modules of src/ it imports at run time (a package's own ``__init__``
    counts only where a name is imported from it that is not a module)."""
    graph: dict[str, set[str]] = {}
    for mod, path in modules.items():
        deps: set[str] = set()
        for node in _runtime_imports(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                target = _source(node, mod, path)
                names = [f'{target}.{a.name}' for a in node.names]
                found = [t for t in names if t in modules]
                targets = found if len(found) == len(names) else [target, *found]
            else:
                targets = [a.name for a in node.names]
            for target in targets:
                t = target
                while t and t not in modules:
                    t = t.rsplit('.', 1)[0] if '.' in t else ''
                if t and t != mod:
                    deps.add(t)
        graph[mod] = deps
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


@pytest.fixture(scope='module')
def graph() -> dict[str, set[str]]:
    return import_graph(_modules())


def test_no_import_cycle(graph) -> None:
    assert cycles(graph) == []


def test_no_upward_import(graph) -> None:
    up = []
    for mod, deps in graph.items():
        for d in deps:
            if mod.startswith('apf_swarm_core') and d.startswith('apf_swarm_nodes'):
                up.append(f'{mod} -> {d} (the core imports the nodes)')
            below = not mod.startswith(('apf_swarm_nodes.bringup', 'apf_swarm_nodes.cli'))
            if (
                mod.startswith('apf_swarm_nodes.')
                and below
                and d.startswith('apf_swarm_nodes.bringup')
            ):
                up.append(f'{mod} -> {d} (a module under the bring-up imports it)')
    assert up == []


def test_the_scan_finds_a_planted_cycle_and_an_upward_import() -> None:
    planted = {'a': {'b'}, 'b': {'c'}, 'c': {'a'}, 'd': {'a'}}
    assert cycles(planted) == [['a', 'b', 'c']]
    tree = ast.parse(
        'from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import x\nimport y\n'
    )
    assert [ast.unparse(n) for n in _runtime_imports(tree)] == [
        'from typing import TYPE_CHECKING',
        'import y',
    ]


def public_names(tree: ast.Module) -> set[str] | None:
    """The names in the module's ``__all__``, or None if it has none."""
    for node in tree.body:
        targets = node.targets if isinstance(node, ast.Assign) else []
        if any(isinstance(t, ast.Name) and t.id == '__all__' for t in targets):
            assert isinstance(node, ast.Assign)
            return set(ast.literal_eval(node.value))
    return None


def private_imports(modules: dict[str, Path]) -> list[str]:
    """Every ``from M import n`` between modules of src/ where n is not in M's ``__all__``
    (nor a submodule of M)."""
    public = {m: public_names(ast.parse(p.read_text())) for m, p in modules.items()}
    found = []
    for mod, path in modules.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.ImportFrom):
                continue
            source = _source(node, mod, path)
            names = public.get(source)
            for alias in node.names if names is not None else ():
                if alias.name not in names and f'{source}.{alias.name}' not in modules:
                    found.append(f'{mod} imports {alias.name} from {source}')
    return found


def _bound(tree: ast.Module) -> set[str]:
    """The names bound anywhere in a module: a superset of its top-level names, enough to
    catch a name in ``__all__`` that nothing defines."""
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            out.add(node.name)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            out.update((a.asname or a.name).split('.')[0] for a in node.names)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            out.update(n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name))
    return out


def test_each_module_says_its_public_names() -> None:
    missing, unbound = [], []
    for mod, path in _modules().items():
        if path.name in ('__init__.py', '__main__.py'):
            continue
        tree = ast.parse(path.read_text())
        names = public_names(tree)
        if names is None:
            missing.append(mod)
            continue
        unbound += [f'{mod}.{n}' for n in sorted(names - _bound(tree))]
    assert missing == [], f'modules without __all__: {missing}'
    assert unbound == [], f'names in __all__ the module does not bind: {unbound}'


def test_no_module_imports_a_private_name() -> None:
    assert private_imports(_modules()) == []


def test_the_scan_finds_a_planted_private_import(tmp_path: Path) -> None:
    (tmp_path / 'a.py').write_text("__all__ = ['f']\ndef f(): ...\ndef _g(): ...\n")
    (tmp_path / 'b.py').write_text('from .a import f, _g\n')
    planted = {'pkg.a': tmp_path / 'a.py', 'pkg.b': tmp_path / 'b.py'}
    assert private_imports(planted) == ['pkg.b imports _g from pkg.a']
