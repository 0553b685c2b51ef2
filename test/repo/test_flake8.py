"""Style gate, as ament_flake8 does for ROS 2 packages (configuration in setup.cfg)."""
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_flake8():
    out = subprocess.run([sys.executable, '-m', 'flake8', 'landing_zone', 'msg_adapters', 'test',
                          'launch'], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, f'flake8 found problems:\n{out.stdout}{out.stderr}'
