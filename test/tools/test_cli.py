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


def test_a_bad_candidate_model_for_the_assess_benchmark_is_one_clear_line(tmp_path):
    bad = tmp_path / 'candidate.safetensors'
    bad.write_bytes(b'not a model')
    out = run_cli('bench', 'assess', '--model', str(bad))
    assert out.returncode != 0 and 'Traceback' not in out.stderr, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and 'candidate.safetensors' in lines[0], out.stderr
    assert 'full map' not in out.stdout  # it fails before any timing


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


def test_a_flight_set_in_a_directory_of_another_is_one_clear_line(tmp_path):
    (tmp_path / 'flights.json').write_text('{"set": "development", "seed": 1}')
    out = run_cli('simulate-flights', '--set', 'heldout', '--seed', '2', '--out', str(tmp_path))
    assert out.returncode == 2 and 'Traceback' not in out.stderr, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and 'holds another flight set' in lines[0], out.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ['flights.json']


def test_train_anchor_data_is_checked_in_one_line(tmp_path):
    """An anchor set must be held out of the fine-tuning and needs the anchored calibration
    (also under the option's former name, --guard-data)."""
    data, out = tmp_path / 'some', tmp_path / 'm.safetensors'
    for args, words in ((('--init', 'models/landing_zone.safetensors', '--anchor-data', str(data)),
                         'both training data and anchor data'),
                        (('--guard-data', str(tmp_path / 'thin')), 'anchored calibration')):
        res = run_cli('train', '--data', str(data), '--out', str(out), *args)
        assert res.returncode == 2 and 'Traceback' not in res.stderr, res.stderr
        assert len(res.stderr.strip().splitlines()) == 1 and words in res.stderr, res.stderr
    assert not out.exists()


def test_calibrate_wants_fold_models_or_like_in_one_line(tmp_path):
    """calibrate fits on fold models' logits or carries an initial model's correction over:
    exactly one of the two, else one line and exit 2, nothing written."""
    out = tmp_path / 'm.safetensors'
    model = 'models/landing_zone.safetensors'
    for args in ((), ('--like', model, '--fold-model', model)):
        res = run_cli('calibrate', '--model', model, '--data', str(tmp_path), '--out', str(out),
                      *args)
        assert res.returncode == 2 and 'Traceback' not in res.stderr, res.stderr
        assert len(res.stderr.strip().splitlines()) == 1, res.stderr
        assert 'either --fold-model' in res.stderr, res.stderr
    assert not out.exists()


def test_version():
    from landing_zone import __version__
    out = run_cli('--version')
    assert out.returncode == 0 and out.stdout.strip() == f'landing-zone {__version__}'


def test_help_imports_nothing_heavy():
    """The listing of every command, and a command's own module, import no stage's library:
    `landing-zone --help` is instant and runs on the robot's install."""
    code = ('import sys\n'
            'from landing_zone.tools.cli import main\n'
            'try:\n'
            '    main(["--help"])\n'
            'except SystemExit:\n'
            '    pass\n'
            'heavy = ("torch", "numba", "scipy", "matplotlib", "sklearn", "trimesh", "optuna",\n'
            '         "ray", "rosbags", "landing_zone.tools.learn", "landing_zone.tools.sim")\n'
            'print(sorted(m for m in sys.modules if m.split(".")[0] in heavy\n'
            '             or m.startswith(heavy[-2:])))\n')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    assert 'train-fleet' in out.stdout and out.stdout.strip().splitlines()[-1] == '[]'


def test_train_options_are_train_config_fields():
    """train's defaults and help are TrainConfig's, stated there once."""
    import dataclasses

    from landing_zone.tools.cli import command
    from landing_zone.tools.learn.train import TrainConfig

    group = command()
    params = {p.name: p for p in group.commands['train'].command().params}
    for f in dataclasses.fields(TrainConfig):
        if f.name in ('arch', 'z_shift', 'yaw'):
            continue  # arch: the --init model's by default; the augmentation is fixed
        assert params[f.name].help == f.metadata['help'], f.name
        if f.default is dataclasses.MISSING:  # a list: absent is empty
            assert not params[f.name].default, f.name
        else:
            assert params[f.name].default == f.default, f.name
    fleet = {p.name: p for p in group.commands['train-fleet'].command().params}
    assert fleet['epochs'].default == 3 and fleet['lr'].default == TrainConfig.lr
    assert fleet['lr'].help == params['lr'].help


def test_replay_writes_only_what_it_is_asked_for(tmp_path, model_file):
    from test_replay import write_flight

    bag = tmp_path / 'flight.mcap'
    write_flight(bag)
    png = tmp_path / 'map.png'
    out = run_cli('replay', str(bag), '--png', str(png), '--model', str(model_file))
    assert out.returncode == 0, out.stderr
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == ['flight.mcap', 'map.png']
    assert out.stdout.strip().splitlines()[-1] == f'wrote {png}'


def test_replay_runs_without_the_extras(tmp_path, model_file):
    """`landing-zone replay` on the robot's install: the extras' libraries made unimportable."""
    from test_replay import write_flight

    bag = tmp_path / 'flight.mcap'
    write_flight(bag)
    code = ('import sys\n'
            'EXTRAS = {"matplotlib", "sklearn", "trimesh", "embreex", "optuna", "ray", "laspy",\n'
            '          "pyproj", "octomap", "mpl_toolkits"}\n'
            'class Block:\n'
            '    def find_spec(self, name, path=None, target=None):\n'
            '        if name.split(".")[0] in EXTRAS:\n'
            '            raise ModuleNotFoundError(f"No module named {name!r}", name=name)\n'
            'sys.meta_path.insert(0, Block())\n'
            'from landing_zone.tools.cli import main\n'
            'main(sys.argv[1:])\n')
    report = tmp_path / 'r.json'
    out = subprocess.run([sys.executable, '-c', code, 'replay', str(bag), '--report', str(report),
                          '--model', str(model_file)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert report.is_file() and out.stdout.strip().splitlines()[-1] == f'wrote {report}'
    out = subprocess.run([sys.executable, '-c', code, 'replay', str(bag), '--png',
                          str(tmp_path / 'm.png'), '--model', str(model_file)],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2 and out.stderr.strip().splitlines() == [
        "landing-zone: error: --png draws with matplotlib: pip install matplotlib (or "
        "'landing_zone[sim]')"]


def test_each_stage_module_is_short():
    from pathlib import Path

    import landing_zone.tools.cli as cli
    for path in Path(cli.__file__).parent.glob('*.py'):
        assert len(path.read_text().splitlines()) <= 300, path.name
