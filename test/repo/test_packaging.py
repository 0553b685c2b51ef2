"""Packaging: what colcon's ament_python install and pip's wheel install put where.

colcon builds an ament_python package with ``setup.py install --prefix ...
--single-version-externally-managed --record ...``; setup.cfg's ``[install]`` section then puts
the console scripts in ``lib/landing_zone`` where ``ros2 run`` looks. pip builds a wheel, which
ignores that section, so ``pip install`` still puts them on PATH in ``bin``. Both are checked on
a copy of the source tree (no dependency resolution, no build isolation: seconds, not minutes).
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
from test_layout import modules  # the package's modules, named as imports name them

ROOT = Path(__file__).resolve().parents[2]
SOURCES = ('setup.py', 'setup.cfg', 'package.xml', 'resource', 'config', 'launch', 'models',
           'landing_zone', 'msg_adapters')


@pytest.fixture(scope='module')
def source(tmp_path_factory):
    """A clean copy of the package sources, with a model in models/ if none is shipped yet."""
    dst = tmp_path_factory.mktemp('src')
    for name in SOURCES:
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, dst / name, ignore=shutil.ignore_patterns(
                '__pycache__', '*.pyc', '*.nbi', '*.nbc'))
        elif src.exists():
            shutil.copy2(src, dst / name)
    models = dst / 'models'
    models.mkdir(exist_ok=True)
    if not list(models.glob('*.safetensors')):
        from test_assessor import make_model
        make_model(models / 'landing_zone.safetensors')
    return dst


def site_packages(prefix: Path) -> Path:
    return Path(sysconfig.get_path('purelib', vars={'base': str(prefix),
                                                    'platbase': str(prefix)}))


def test_colcon_style_install_layout(source, tmp_path):
    prefix = tmp_path / 'install'
    record = tmp_path / 'record.txt'
    build = tmp_path / 'build'
    out = subprocess.run([sys.executable, 'setup.py', 'build', '--build-base', str(build),
                          'install', '--prefix', str(prefix),
                          '--single-version-externally-managed', '--record', str(record)],
                         cwd=source, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert 'Unknown distribution option' not in out.stderr  # no warning of the project's own
    share = prefix / 'share'
    assert (share / 'ament_index' / 'resource_index' / 'packages' / 'landing_zone').is_file()
    assert (share / 'landing_zone' / 'package.xml').read_text() == \
        (source / 'package.xml').read_text()
    assert (share / 'landing_zone' / 'config' / 'assessor.yaml').is_file()
    assert (share / 'landing_zone' / 'launch' / 'assessor.launch.py').is_file()
    shipped = sorted(p.name for p in (source / 'models').iterdir()
                     if p.suffix in ('.safetensors', '.md'))
    installed = sorted(p.name for p in (share / 'landing_zone' / 'models').iterdir())
    assert shipped and installed == shipped
    for script in ('assessor', 'landing-zone'):
        path = prefix / 'lib' / 'landing_zone' / script
        assert path.is_file() and os.access(path, os.X_OK), script
        assert not (prefix / 'bin' / script).exists()
    recorded = set(record.read_text().split())
    assert str(prefix / 'lib' / 'landing_zone' / 'assessor') in recorded
    # the installed package finds its installed model through the ament index
    env = dict(os.environ, PYTHONPATH=str(site_packages(prefix)),
               AMENT_PREFIX_PATH=str(prefix), PYTHONDONTWRITEBYTECODE='1')
    probe = subprocess.run(
        [sys.executable, '-c', 'import landing_zone, landing_zone.assessor as a; '
         'print(landing_zone.__file__); print(a.default_model_path())'],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60)
    assert probe.returncode == 0, probe.stderr
    module, model = probe.stdout.split()
    assert module.startswith(str(prefix))
    assert Path(model) == share / 'landing_zone' / 'models' / 'landing_zone.safetensors'
    helped = subprocess.run([str(prefix / 'lib' / 'landing_zone' / 'landing-zone'), '--help'],
                            cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60)
    assert helped.returncode == 0 and 'replay' in helped.stdout


def test_pip_wheel_install_puts_scripts_on_path(source, tmp_path):
    prefix = tmp_path / 'venvlike'
    work = tmp_path / 'src'
    shutil.copytree(source, work)  # pip builds in place: keep the shared copy clean
    out = subprocess.run([sys.executable, '-m', 'pip', 'install', '-q', '--no-deps',
                          '--no-build-isolation', '--no-compile', '--ignore-installed',
                          '--prefix', str(prefix),
                          str(work)], capture_output=True, text=True, timeout=180)
    assert out.returncode == 0, out.stderr[-2000:]
    for script in ('assessor', 'landing-zone'):
        path = prefix / 'bin' / script
        assert path.is_file() and os.access(path, os.X_OK), script
        module = 'landing_zone.ros.node' if script == 'assessor' else 'landing_zone.tools.cli'
        assert f'from {module} import main' in path.read_text()
    assert (prefix / 'share' / 'landing_zone' / 'config' / 'assessor.yaml').is_file()
    assert (prefix / 'share' / 'landing_zone' / 'models' / 'landing_zone.safetensors').is_file()


def _requirement_names(lines) -> dict[str, str]:
    """name -> the whole requirement line, for requirement lines (comments and blanks skipped)."""
    import re
    out = {}
    for line in lines:
        line = line.split('#', 1)[0].strip()
        if line:
            out[re.split(r'[<>=!~;\[ ]', line, maxsplit=1)[0].lower()] = line
    return out


def _setup_kwargs() -> dict:
    import ast
    tree = ast.parse((ROOT / 'setup.py').read_text())
    call = next(n for n in ast.walk(tree) if isinstance(n, ast.Call)
                and getattr(n.func, 'id', '') == 'setup')
    return {k.arg: k.value for k in call.keywords}


def test_robot_install_is_setup_py_minus_rosdep_keys():
    """The robot's pip line installs exactly the dependencies package.xml's rosdep keys leave
    out, in setup.py's own ranges: no ROS wheels, no torch pin, nothing forgotten."""
    import ast
    import xml.etree.ElementTree as ET
    kw = _setup_kwargs()
    install = _requirement_names(ast.literal_eval(kw['install_requires']))
    robot = _requirement_names((ROOT / 'requirements-robot.txt').read_text().splitlines())
    keys = {d.text for d in ET.parse(ROOT / 'package.xml').getroot().iter('exec_depend')}
    # rosdep key -> the pip name it provides
    by_rosdep = {'python3-numpy': 'numpy', 'python3-scipy': 'scipy', 'python3-yaml': 'pyyaml',
                 'python3-tqdm': 'tqdm'}
    python_keys = {k for k in keys if k.startswith('python3-')}
    assert python_keys == set(by_rosdep), 'a python3-* key of package.xml without its pip name'
    assert set(by_rosdep.values()) <= set(install)
    assert set(robot) == set(install) - set(by_rosdep.values())
    for name, line in robot.items():
        assert line == install[name], f'{name}: robot and setup.py ranges differ'
    assert not any(n.startswith('ros-') for n in robot) and '==' not in ''.join(robot.values())
    assert _requirement_names((ROOT / 'requirements.txt').read_text().splitlines())['torch'] \
        == 'torch==2.13.0', 'the development pins keep the local CPU wheel'


def test_one_version():
    """setup.py, package.xml and `landing-zone --version` (landing_zone.__version__) agree."""
    import ast
    import xml.etree.ElementTree as ET

    import landing_zone
    version = ast.literal_eval(_setup_kwargs()['version'])
    assert ET.parse(ROOT / 'package.xml').getroot().findtext('version') == version
    assert landing_zone.__version__ == version


# --- the robot's install, by import inspection --------------------------------------------------

# import name -> the distribution that provides it
DISTRIBUTIONS = {'yaml': 'pyyaml', 'sklearn': 'scikit-learn', 'octomap': 'octomap-python',
                 'mpl_toolkits': 'matplotlib'}
# imported only for an optional input, from the extra that provides it
OPTIONAL = {'laspy': 'survey', 'pyproj': 'survey'}
# from the system ROS (package.xml) or the [ros] extra; rclpy brings the last four with it
ROS = {'rclpy', 'std_msgs', 'sensor_msgs', 'nav_msgs', 'geometry_msgs', 'visualization_msgs',
       'diagnostic_msgs', 'rcl_interfaces', 'builtin_interfaces', 'ament_index_python',
       'rosidl_runtime_py'}
# the command line's modules are followed at module level, and into these functions only: the
# way `landing-zone replay` (and the listing of every command) goes
CLI = 'landing_zone.tools.cli'
CLI_PATH = {CLI: ('main', 'command', '_version', '_root'), f'{CLI}.run': ('replay',)}


def _imports(name: str, path: Path, functions: tuple[str, ...] | None) -> set[str]:
    """What module ``name`` imports at run time: everywhere (functions None), or at module level
    and inside the top-level ``functions``; imports under TYPE_CHECKING are left out."""
    import ast

    tree = ast.parse(path.read_text(encoding='utf-8'))
    package = name if path.name == '__init__.py' else name.rpartition('.')[0]
    found: set[str] = set()

    def visit(node, top: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and 'TYPE_CHECKING' in ast.unparse(child.test):
                for other in child.orelse:
                    visit(ast.Module(body=[other], type_ignores=[]), top)
                continue
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                if functions is None or (top and child.name in functions):
                    visit(child, False)
                continue
            if isinstance(child, ast.ClassDef):
                if functions is None:
                    visit(child, False)
                continue
            if isinstance(child, ast.Import):
                found.update(a.name for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                module = child.module or ''
                if child.level:
                    base = package.split('.')[:len(package.split('.')) - child.level + 1]
                    module = '.'.join(base + ([module] if module else []))
                found.add(module)
                found.update(f'{module}.{a.name}' for a in child.names)
            visit(child, top)

    visit(tree, True)
    return found


def _closure(roots: list[str]) -> tuple[set[str], dict[str, set[str]]]:
    """The project modules reached from ``roots`` and the third-party top-level modules they
    import (name -> the modules importing it), standard library left out."""
    files = modules()
    seen: set[str] = set()
    third: dict[str, set[str]] = {}
    todo = list(roots)
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        in_cli = name == CLI or name.startswith(CLI + '.')
        for module in _imports(name, files[name], CLI_PATH.get(name, ()) if in_cli else None):
            top = module.split('.')[0]
            if top in ('landing_zone', 'msg_adapters'):
                parts = module.split('.')  # a module and the packages above it
                todo += [m for m in ('.'.join(parts[:i]) for i in range(1, len(parts) + 1))
                         if m in files]
            elif top and top not in sys.stdlib_module_names and top != '__future__':
                third.setdefault(top, set()).add(name)
    return seen, third


def test_the_node_reaches_no_offline_tool():
    seen, _ = _closure(['landing_zone.ros.node'])
    assert 'landing_zone.assessor' in seen and 'msg_adapters.pointcloud' in seen
    assert not sorted(m for m in seen if m.startswith('landing_zone.tools')), \
        'the node imports offline tooling'


def test_base_install_holds_what_the_robot_imports():
    """install_requires is what the node, replay and the command line's way to replay import
    (at module level or inside a function), typer and rich for the command line, and no more;
    what they import for an optional input is in that input's extra."""
    import ast

    kw = _setup_kwargs()
    install = set(_requirement_names(ast.literal_eval(kw['install_requires'])))
    extras = {k.value: set(_requirement_names(ast.literal_eval(v)))
              for k, v in zip(kw['extras_require'].keys, kw['extras_require'].values)}
    node, node_third = _closure(['landing_zone.ros.node'])
    seen, third = _closure(['landing_zone.ros.node', 'landing_zone.replay', CLI])
    assert 'landing_zone.replay' in seen and f'{CLI}.run' in seen
    assert set(node_third) <= set(third)
    # (landing_zone.tools: the package above the command line, its imports followed)
    offline = sorted(m for m in seen if m.startswith('landing_zone.tools.')
                     and not m.startswith(CLI))
    assert not offline, f'replay reaches offline tooling: {offline}'
    needed = set()
    for top, users in sorted(third.items()):
        dist = DISTRIBUTIONS.get(top, top)
        if top in ROS:
            continue
        if top in OPTIONAL:
            assert dist in extras[OPTIONAL[top]], f'{top} ({sorted(users)}) not in its extra'
            assert dist not in install
            continue
        assert dist in install, f'{top}, imported by {sorted(users)}, is not in install_requires'
        needed.add(dist)
    assert install == needed | {'typer', 'rich'}, \
        f'install_requires holds what the robot does not import: {install - needed}'
    assert 'typer' in needed  # the command line's modules import it at module level


def test_every_offline_import_has_an_extra():
    """Every third-party module the package imports anywhere comes from install_requires, an
    extra, or ROS: `pip install 'landing_zone[sim,learn,ray,survey,bench]'` runs everything."""
    import ast

    kw = _setup_kwargs()
    provided = set(_requirement_names(ast.literal_eval(kw['install_requires'])))
    for extra in kw['extras_require'].values:
        provided |= set(_requirement_names(ast.literal_eval(extra)))
    _, third = _closure(sorted(modules()))
    missing = {top: sorted(users)[:3] for top, users in third.items()
               if top not in ROS and DISTRIBUTIONS.get(top, top) not in provided}
    assert not missing, f'imported but in no requirement: {missing}'
