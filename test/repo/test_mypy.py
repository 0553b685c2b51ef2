"""Type gate: mypy, strict on the core (configuration in setup.cfg), as `make lint` runs it."""
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_mypy_strict_on_the_core():
    out = subprocess.run([sys.executable, '-m', 'mypy'], cwd=ROOT, capture_output=True,
                         text=True, timeout=900)
    assert out.returncode == 0, f'mypy found problems:\n{out.stdout}{out.stderr}'
