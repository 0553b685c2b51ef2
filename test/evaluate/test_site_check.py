"""`landing-zone site-check` on a small real run: two models judge a simulated test split, two
replay reports are scored against their labels, the test families come from a by-family file."""
import json

import pytest

from landing_zone.tools.cli import main
from landing_zone.tools.evaluate.site_check import family_passes, hybrid_counts
from landing_zone.tools.sim.dataset import simulate_dataset
from landing_zone.tools.sim.families import TEST_FAMILIES
from landing_zone.tools.sim.shards import SceneDataset
from test_assessor import make_model

# four tiles in a row, the last under an obstacle; P(safe) of the flight under each model
SAFE = [True, True, True, False]
INITIAL = [0.2, 0.3, 0.9, 0.6]  # 2 of 3 safe tiles flagged, the obstacle tile passed
ADAPTED = [0.7, 0.3, 0.9, 0.4]  # 1 flagged, the obstacle tile caught


def _report(p_safe):
    return {'frame_id': 'map', 'tile_size': 1.0, 'landing_sites': [], 'stats': {},
            'tiles': [{'x': i + 0.5, 'y': 0.5, 'ground_z': 0.0, 'p_safe': p, 'confidence': 1.0}
                      for i, p in enumerate(p_safe)]}


def _families(*passes):
    fam = TEST_FAMILIES[0]
    return {'families': {'methods': {
        name: {'obstacle': {fam: {'n': 10, 'n_unsafe': 5, 'unsafe_ge_0.5': p5,
                                  'unsafe_ge_0.9': p9, 'safe_lt_0.5': flagged}}}
        for name, (p5, p9, flagged) in zip(('initial', 'adapted', 'third'), passes)}}}


@pytest.fixture(scope='module')
def run(tmp_path_factory):
    d = tmp_path_factory.mktemp('site')
    simulate_dataset('synth1', d / 'hybrid', scenes=24, workers=1, seed=0, progress=False)
    make_model(d / 'm0.safetensors', seed=0)
    make_model(d / 'm1.safetensors', seed=1)
    (d / 'site.labels.json').write_text(json.dumps({
        'frame_id': 'map', 'tile_size': 1.0, 'obstacles': [],
        'tiles': [{'x': i + 0.5, 'y': 0.5, 'safe': s} for i, s in enumerate(SAFE)]}))
    (d / 'r0.json').write_text(json.dumps(_report(INITIAL)))
    (d / 'r1.json').write_text(json.dumps(_report(ADAPTED)))
    (d / 'fam.json').write_text(json.dumps(_families((0.4, 0.2, 0.2), (0.2, 0.0, 0.4))))
    (d / 'fam_worse.json').write_text(json.dumps(_families((0.4, 0.2, 0.2), (0.6, 0.2, 0.2))))
    (d / 'fam3.json').write_text(json.dumps(_families((0.4, 0.2, 0.2), (0.2, 0, 0), (0, 0, 0))))
    return d


def _check(capsys, d, initial, adapted, r0, r1, families=None):
    args = ['site-check', '--initial-model', d / initial, '--adapted-model', d / adapted,
            '--hybrid', d / 'hybrid', '--labels', d / 'site.labels.json',
            '--initial-report', d / r0, '--adapted-report', d / r1]
    if families is not None:
        args += ['--families', d / families]
    with pytest.raises(SystemExit) as exc:
        main([str(a) for a in args])
    out = capsys.readouterr()
    return exc.value.code, out.out.splitlines(), out.err


def test_the_check_holds_when_false_alarms_fall_and_no_more_obstacles_pass(run, capsys):
    code, lines, _ = _check(capsys, run, 'm0.safetensors', 'm0.safetensors', 'r0.json',
                            'r1.json', 'fam.json')
    assert code == 0, lines
    scenes = len(SceneDataset(run / 'hybrid', 'test'))
    [h] = hybrid_counts([run / 'm0.safetensors'], run / 'hybrid')
    assert h['safe'] + h['unsafe'] == scenes and h['safe'] and h['unsafe']
    assert lines == [
        f'held-out vegetation, hybrid test split: safe tiles flagged {h["false_alarms"]} -> '
        f'{h["false_alarms"]} of {h["safe"]}; obstacle tiles passed {h["passed"]} -> '
        f'{h["passed"]} of {h["unsafe"]}',
        'held-out vegetation, flight site.labels.json: safe tiles flagged 2 -> 1 of 3; '
        'obstacle tiles passed 1 -> 0 of 1; AUC 0.333 -> 0.667',
        'test obstacle families (5 obstacle tiles): passed at P(safe) >= 0.5 2 -> 1, at >= 0.9 '
        '1 -> 0; their safe tiles flagged 1 -> 2',
        'site-adaptation check: holds']


def test_the_check_fails_with_exit_1_and_says_why(run, capsys):
    # more false alarms on the flight, and two other models on the hybrid split
    code, lines, _ = _check(capsys, run, 'm0.safetensors', 'm1.safetensors', 'r1.json',
                            'r0.json', 'fam_worse.json')
    assert code == 1
    h0, h1 = hybrid_counts([run / 'm0.safetensors', run / 'm1.safetensors'], run / 'hybrid')
    assert lines[0].startswith(f'held-out vegetation, hybrid test split: safe tiles flagged '
                               f'{h0["false_alarms"]} -> {h1["false_alarms"]} of {h0["safe"]}')
    assert '  false alarms on the held-out vegetation not cut' in lines
    assert '  more test-family obstacle tiles passed' in lines
    assert lines[-1] == 'site-adaptation check: FAILS'
    # without the families the check cannot hold
    code, lines, _ = _check(capsys, run, 'm0.safetensors', 'm0.safetensors', 'r0.json',
                            'r1.json')
    assert code == 1
    assert lines[-2:] == ['test obstacle families: not scored (no --families)',
                          'site-adaptation check: FAILS']


def test_a_families_file_of_other_than_two_models_is_one_line(run, capsys):
    assert [f['name'] for f in family_passes(run / 'fam3.json')] == ['initial', 'adapted',
                                                                     'third']
    code, lines, err = _check(capsys, run, 'm0.safetensors', 'm0.safetensors', 'r0.json',
                              'r1.json', 'fam3.json')
    assert code == 2 and lines == []
    assert err.strip().splitlines() == [
        f'landing-zone: error: {run / "fam3.json"}: 3 models, want the initial and the '
        'adapted one']
