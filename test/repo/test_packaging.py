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

ROOT = Path(__file__).resolve().parents[2]
SOURCES = ('setup.py', 'setup.cfg', 'package.xml', 'resource', 'config', 'models',
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
    share = prefix / 'share'
    assert (share / 'ament_index' / 'resource_index' / 'packages' / 'landing_zone').is_file()
    assert (share / 'landing_zone' / 'package.xml').read_text() == \
        (source / 'package.xml').read_text()
    assert (share / 'landing_zone' / 'config' / 'assessor.yaml').is_file()
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


def test_robot_install_is_setup_py_minus_rosdep_keys():
    """The robot's pip line installs exactly the dependencies package.xml's rosdep keys leave
    out, in setup.py's own ranges: no ROS wheels, no torch pin, nothing forgotten."""
    import ast
    import xml.etree.ElementTree as ET
    tree = ast.parse((ROOT / 'setup.py').read_text())
    call = next(n for n in ast.walk(tree) if isinstance(n, ast.Call)
                and getattr(n.func, 'id', '') == 'setup')
    kw = {k.arg: k.value for k in call.keywords}
    install = _requirement_names(ast.literal_eval(kw['install_requires']))
    robot = _requirement_names((ROOT / 'requirements-robot.txt').read_text().splitlines())
    keys = {d.text for d in ET.parse(ROOT / 'package.xml').getroot().iter('exec_depend')}
    # rosdep key -> the pip name it provides
    by_rosdep = {'python3-numpy': 'numpy', 'python3-scipy': 'scipy',
                 'python3-sklearn': 'scikit-learn', 'python3-matplotlib': 'matplotlib',
                 'python3-yaml': 'pyyaml', 'python3-tqdm': 'tqdm',
                 'python3-trimesh-pip': 'trimesh'}
    python_keys = {k for k in keys if k.startswith('python3-')}
    assert python_keys == set(by_rosdep), 'a python3-* key of package.xml without its pip name'
    assert set(robot) == set(install) - set(by_rosdep.values())
    for name, line in robot.items():
        assert line == install[name], f'{name}: robot and setup.py ranges differ'
    assert not any(n.startswith('ros-') for n in robot) and '==' not in ''.join(robot.values())
    assert _requirement_names((ROOT / 'requirements.txt').read_text().splitlines())['torch'] \
        == 'torch==2.13.0', 'the development pins keep the local CPU wheel'
