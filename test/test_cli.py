import subprocess
import sys


def run_cli(*args):
    return subprocess.run([sys.executable, '-m', 'landing_zone', *args],
                          capture_output=True, text=True, timeout=120)


def test_help_lists_commands():
    out = run_cli('--help')
    assert out.returncode == 0
    for command in ('bench', 'evaluate-flights', 'train-fleet'):
        assert command in out.stdout


def test_unknown_benchmark_is_one_clear_line():
    out = run_cli('bench', 'nonsense')
    assert out.returncode == 2
    assert 'Traceback' not in out.stderr
    assert out.stderr.strip().splitlines() == [
        "landing-zone: error: unknown benchmark 'nonsense'; choose from "
        'integrate, simulate, assess, replay, insert, live, soak, engines']
