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


def test_simulate_families_are_checked_in_one_line(tmp_path):
    """--families names obstacle families of synth3 only; a wrong one is one line, no file."""
    two = ('--scenes', '2')
    for args, words in ((('--dataset', 'synth2', '--families', 'frame', *two), 'synth3 option'),
                        (('--dataset', 'hybrid', '--from', str(tmp_path / 'f.mcap'),
                          '--families', 'frame'), 'synth3 option'),
                        (('--dataset', 'synth3', '--families', 'spaceship', *two),
                         'unknown obstacle family'),
                        (('--dataset', 'synth3', '--families', 'coil', *two),
                         'none is a train family')):
        out = run_cli('simulate', '--out', str(tmp_path / 'd'), *args)
        assert out.returncode == 2 and 'Traceback' not in out.stderr, out.stderr
        assert len(out.stderr.strip().splitlines()) == 1 and words in out.stderr, out.stderr
    assert not (tmp_path / 'd').exists()
