"""The layout holds: no import cycle between packages nor between modules, the core imports
nothing from outside it, what flies imports nothing from the simulator, the learning code or the
benchmarks, rclpy only in the node, play, the node's rcl take and the live benchmarks' own ROS 2
processes, no module over 500 lines and no function over 100.

Imports are read from the source (ast), those inside functions and under TYPE_CHECKING too, so
an import moved into a function to dodge a cycle is still seen."""
from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ('landing_zone', 'msg_adapters')
# the core: the onboard pipeline's own modules, importable without ROS or the tooling
CORE = ('landing_zone.config', 'landing_zone.errors', 'landing_zone.poses',
        'landing_zone.assessor', 'landing_zone.mapping', 'landing_zone.judging')
OFFLINE = ('landing_zone.tools',)
MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 100


def modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob('*.py')):
            parts = list(path.relative_to(ROOT).with_suffix('').parts)
            if parts[-1] == '__init__':
                parts = parts[:-1]
            out['.'.join(parts)] = path
    return out


MODULES = modules()


def imports(name: str) -> set[str]:
    """Project modules ``name`` imports (``from pkg import sub`` counts as ``pkg.sub``; a
    relative import is resolved against ``name``'s package)."""
    path = MODULES[name]
    package = name if path.name == '__init__.py' else name.rpartition('.')[0]
    tree = ast.parse(path.read_text(encoding='utf-8'))
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            module = node.module
            if node.level:
                base = package.split('.')[:len(package.split('.')) - node.level + 1]
                module = '.'.join(base + ([node.module] if node.module else []))
            if module:
                found.add(module)
                found.update(f'{module}.{a.name}' for a in node.names
                             if f'{module}.{a.name}' in MODULES)
    return {m for m in found if m.split('.')[0] in PACKAGES and m in MODULES and m != name}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` (its nodes in order, the first repeated last), or None."""
    state: dict[str, int] = {}
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            if not state.get(nxt):
                found = visit(nxt)
                if found:
                    return found
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if not state.get(node):
            found = visit(node)
            if found:
                return found
    return None


def package_of(name: str) -> str:
    """The node of the package graph: a subpackage of landing_zone, msg_adapters, or a module
    of landing_zone's own (config, errors, assessor, cli, ...)."""
    parts = name.split('.')
    if parts[0] == 'msg_adapters':
        return 'msg_adapters'
    if len(parts) >= 2 and (ROOT / 'landing_zone' / parts[1]).is_dir():
        return '.'.join(parts[:2])
    return name


def in_any(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + '.') for p in prefixes)


def test_no_import_cycle_between_packages():
    graph: dict[str, set[str]] = {}
    for name in MODULES:
        src = package_of(name)
        graph.setdefault(src, set()).update(
            package_of(m) for m in imports(name) if package_of(m) != src)
    graph.pop('landing_zone', None)  # the lazy facade of the public API, imported by no one
    cycle = find_cycle(graph)
    assert cycle is None, 'import cycle between packages: ' + ' -> '.join(cycle or [])
    # the two the issue named: msg_adapters depends on the core, never the reverse
    assert 'msg_adapters' not in set().union(*(graph.get(p, set()) for p in CORE))


def test_no_import_cycle_between_modules():
    # function-level imports count: one that only hides a cycle is a cycle
    graph = {name: imports(name) for name in MODULES}
    graph.pop('landing_zone', None)  # the lazy facade of the public API, imported by no one
    cycle = find_cycle(graph)
    assert cycle is None, 'import cycle between modules: ' + ' -> '.join(cycle or [])


def test_find_cycle_sees_a_cycle():
    assert find_cycle({'a': {'b'}, 'b': {'c'}, 'c': {'a'}}) == ['a', 'b', 'c', 'a']
    assert find_cycle({'a': {'b'}, 'b': {'c'}, 'c': set()}) is None


def test_the_core_imports_only_the_core():
    for name in MODULES:
        if in_any(name, CORE):
            outside = {m for m in imports(name) if not in_any(m, CORE)}
            assert not outside, f'{name} imports {sorted(outside)} from outside the core'


def test_what_flies_imports_nothing_offline():
    # everything the node imports, transitively, is what runs on the robot
    seen, todo = set(), ['landing_zone.ros.node']
    while todo:
        name = todo.pop()
        if name not in seen:
            seen.add(name)
            todo.extend(imports(name))
    assert 'landing_zone.assessor' in seen and 'landing_zone.mapping.raytrace' in seen
    offline = sorted(m for m in seen if in_any(m, OFFLINE))
    assert not offline, f'the node reaches offline code: {offline}'


# rclpy's users: the node and play; rcl_take (the node's take with the publisher's GID, through
# rcl's C API in the libraries rclpy loads); the live benchmarks' publisher and observer, which
# are ROS 2 participants of their own beside the node (offline: never imported by it)
RCLPY_USERS = {'landing_zone.ros.node', 'landing_zone.ros.play',
               'landing_zone.ros.rcl_take', 'landing_zone.tools.bench.live_publisher',
               'landing_zone.tools.bench.livenode'}


def test_rclpy_only_in_the_node_and_play():
    users = set()
    for name, path in MODULES.items():
        tree = ast.parse(path.read_text(encoding='utf-8'))
        for node in ast.walk(tree):
            mods = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                    [node.module or ''] if isinstance(node, ast.ImportFrom) else [])
            if any(m.split('.')[0] == 'rclpy' for m in mods):
                users.add(name)
    assert users == RCLPY_USERS


def test_modules_are_short():
    lines = {name: len(path.read_text(encoding='utf-8').splitlines())
             for name, path in MODULES.items()}
    over = {n: k for n, k in lines.items() if k > MAX_MODULE_LINES}
    assert not over, f'modules over {MAX_MODULE_LINES} lines: {over}'


def test_functions_are_short():
    over = {}
    for name, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                length = (node.end_lineno or node.lineno) - node.lineno + 1
                if length > MAX_FUNCTION_LINES:
                    over[f'{name}.{node.name}'] = length
    assert not over, f'functions over {MAX_FUNCTION_LINES} lines: {over}'


def test_old_flat_modules_are_gone():
    # no compatibility shims: the pre-0.3.0 paths do not import
    for old in ('model', 'tiles', 'raytrace', 'density_map', 'sites', 'stream', 'node', 'play',
                'bagio', 'insert', 'train', 'evaluate', 'tune', 'calibration',
                'baselines', 'benchmarks'):
        assert f'landing_zone.{old}' not in MODULES, old


# a citation of a document in the code: docs/NAME.md or models/NAME.md, then a section as
# "§N" or as its quoted title
CITATION = re.compile(r'((?:docs|models)/[A-Za-z_]+\.md)(?:[,)]?\s*(?:§\s*(\d+)|"([^"]+)"))?')


def headings(path: Path) -> list[str]:
    return [line.lstrip('#').strip() for line in path.read_text(encoding='utf-8').splitlines()
            if line.startswith('#')]


def test_the_documents_and_sections_code_cites_exist():
    missing = []
    for name, path in MODULES.items():
        text = ' '.join(path.read_text(encoding='utf-8').split())  # citations may wrap
        for doc, number, title in CITATION.findall(text):
            target = ROOT / doc
            if not target.is_file():
                missing.append(f'{name}: {doc}')
                continue
            heads = headings(target)
            if number and not any(h.startswith(f'{number}.') for h in heads):
                missing.append(f'{name}: {doc} §{number}')
            if title and not any(title.lower() in h.lower() for h in heads):
                missing.append(f'{name}: {doc}, "{title}"')
    assert not missing, f'citations of documents or sections that do not exist: {missing}'
