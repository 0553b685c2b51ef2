"""launch/assessor.launch.py: its arguments exist and name what the node has. The launch
packages (launch, launch_ros) come with a ROS 2 installation, not with pip: without them the file
is read as source (ast); with them a test starts it."""
from __future__ import annotations

import ast
import re
import time
from pathlib import Path

import pytest

from landing_zone.config import CLOUD_FRAMES, PARAMETERS

ROOT = Path(__file__).resolve().parents[2]
LAUNCH = ROOT / 'launch' / 'assessor.launch.py'


def arguments():
    tree = ast.parse(LAUNCH.read_text(encoding='utf-8'))
    for node in tree.body:
        if isinstance(node, ast.Assign) and getattr(node.targets[0], 'id', '') == 'ARGUMENTS':
            return ast.literal_eval(node.value)
    raise AssertionError('no ARGUMENTS table in the launch file')


def test_the_launch_file_loads_and_its_arguments_exist():
    tree = ast.parse(LAUNCH.read_text(encoding='utf-8'))
    assert 'generate_launch_description' in {f.name for f in tree.body
                                             if isinstance(f, ast.FunctionDef)}
    args = arguments()
    assert {'params_file', 'points', 'sensor_pose', 'odometry', 'cloud_frame',
            'use_sim_time'} <= set(args)
    assert all(text for _, text in args.values())
    # the remapped inputs are the node's subscriptions, by their names
    node_src = (ROOT / 'landing_zone' / 'ros' / 'node.py').read_text(encoding='utf-8')
    subscribed = set(re.findall(r"create_subscription\(\w+, '(\w+)'", node_src))
    assert {'points', 'sensor_pose', 'odometry'} <= subscribed
    src = LAUNCH.read_text(encoding='utf-8')
    for topic in ('points', 'sensor_pose', 'odometry'):
        assert f"('{topic}', arg('{topic}'))" in src
        assert args[topic][0] == topic  # the default leaves the node's own name
    # the parameters it sets are the node's, and the default file is the shipped one
    assert 'cloud_frame' in PARAMETERS and set(CLOUD_FRAMES) >= {'fixed', 'body', 'sensor'}
    assert "'config', 'assessor.yaml'" in src and (ROOT / 'config' / 'assessor.yaml').is_file()
    assert args['use_sim_time'][0] in ('false', 'true')


def test_the_launch_file_starts_the_node():
    pytest.importorskip('launch_ros', reason='launch_ros is not pip-installable: it comes with '
                        'a ROS 2 installation (ros-jazzy-launch-ros)')
    import threading

    import launch
    import rclpy
    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

    try:
        get_package_share_directory('landing_zone')
    except PackageNotFoundError:
        pytest.skip('landing_zone is not installed in an ament prefix (colcon build)')
    ls = launch.LaunchService(argv=[f'params_file:={ROOT / "config" / "assessor.yaml"}'])
    ls.include_launch_description(_load(LAUNCH).generate_launch_description())
    runner = threading.Thread(target=ls.run, daemon=True)
    runner.start()
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    try:
        probe = rclpy.create_node('launch_probe', context=ctx)
        deadline = time.monotonic() + 60
        found = False
        while time.monotonic() < deadline and not found:
            found = 'assessor' in probe.get_node_names()
            time.sleep(0.2)
        assert found, 'the launched assessor never joined the graph'
    finally:
        rclpy.try_shutdown(context=ctx)
        ls.shutdown()
        runner.join(30)


def _load(path):
    import importlib.util

    spec = importlib.util.spec_from_file_location('assessor_launch', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
