"""Build script: the same file serves `colcon build` (ament_python) and `pip install`."""
from glob import glob

from setuptools import find_packages, setup

package_name = 'landing_zone'

setup(
    name=package_name,
    version='0.3.0',
    packages=find_packages(include=['landing_zone', 'landing_zone.*',
                                    'msg_adapters', 'msg_adapters.*']),
    package_data={'landing_zone': ['py.typed']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml') + glob('config/*.xml')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
        ('share/' + package_name + '/models', glob('models/*.safetensors') + glob('models/*.md')),
    ],
    python_requires='>=3.10',
    # The robot's install: what the node (landing_zone.ros.node) and `landing-zone replay`
    # import, and the command line's typer and rich; test/repo/test_packaging.py checks it against
    # their imports. Loose ranges for users; this machine's exact pins live in requirements.txt.
    install_requires=[
        'numpy>=1.24',
        'scipy>=1.10',
        'numba>=0.59',
        'torch>=2.2',
        'safetensors>=0.4',
        'rosbags>=0.10',
        'tqdm>=4.60',
        'pyyaml>=6',
        'typer>=0.12',
        'rich>=13',
    ],
    extras_require={
        # The offline tooling, by stage (landing_zone.tools); requirements.txt installs them all.
        # simulate, simulate-flight, insert-obstacles, render, demo (its map PNG and AUC)
        'sim': ['trimesh>=4.0',
                'embreex>=2.17; platform_machine in "x86_64 AMD64 aarch64 arm64"',
                'matplotlib>=3.7', 'scikit-learn>=1.3'],
        # train, tune, calibrate, fit-ood, evaluate, site-check (they read the simulator's scenes)
        'learn': ['trimesh>=4.0',
                  'embreex>=2.17; platform_machine in "x86_64 AMD64 aarch64 arm64"',
                  'matplotlib>=3.7', 'scikit-learn>=1.3', 'optuna>=3.5'],
        # --engine ray (simulate, evaluate-flights, train-fleet, tune): Ray's core only
        'ray': ['ray>=2.9'],
        # landing-zone replay FILE.las / FILE.laz (LAZ through the lazrs backend); pyproj
        # reads the file's CRS (its unit) and projects SBET trajectories
        'survey': ['laspy[lazrs]>=2.4', 'pyproj>=3.4'],
        # landing-zone bench integrate: OctoMap beside the density map
        'bench': ['octomap-python>=1.9'],
        # For machines without a system ROS 2 Jazzy (the wheels from PyPI).
        'ros': ['ros-jazzy-rclpy[fastrtps]', 'ros-jazzy-common-interfaces'],
        'dev': ['pytest>=7', 'hypothesis>=6', 'pytest-timeout>=2', 'flake8>=6', 'mypy>=1.8',
                'mcap>=1.1'],  # mcap: the tests write an unindexed file with it
    },
    zip_safe=True,
    maintainer='landing_zone developers',
    maintainer_email='dev@landing-zone.example',
    description='Landing zone detection from LiDAR with a 3D CNN (ROS 2 Jazzy).',
    license='BSD-3-Clause',
    entry_points={
        'console_scripts': [
            'assessor = landing_zone.ros.node:main',
            'landing-zone = landing_zone.tools.cli:main',
        ],
    },
)
