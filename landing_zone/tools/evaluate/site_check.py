"""The site-adaptation check: did adapting a model to a site's vegetation cut its false alarms
without passing more obstacles of shapes no model trained on?

It compares an initial and an adapted model on
- the held-out vegetation: safe tiles given P(safe) < 0.5 on a hybrid set's test split (a clear
  flight neither trained on, obstacles inserted) and on a replayed flight with obstacles
  (``landing-zone replay`` reports scored against the flight's labels);
- the obstacle families no model ever trained on: obstacle tiles of synth3's test families given
  P(safe) >= 0.5 and >= 0.9 (from ``landing-zone evaluate --by-family --json``, both models).

The check holds when the false alarms fall, in all and on neither set rise, and the test
families' passes rise at neither threshold. ``landing-zone site-check`` runs it.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from landing_zone.errors import ConfigError
from landing_zone.io.labels import LabelScores, read_labels, score_report

__all__ = ['SiteCheck', 'hybrid_counts', 'family_passes', 'site_check']

PathLike = str | os.PathLike[str]


@dataclass
class SiteCheck:
    """The figures of both models and the verdict.

    Attributes:
        hybrid: per model, on the hybrid test split: ``safe``, ``false_alarms`` (safe tiles
            at P(safe) < 0.5), ``unsafe``, ``passed`` (obstacle tiles at P(safe) >= 0.5).
        flight: per model, the replayed flight's report scored against its labels.
        families: per model, the test families' obstacle tiles passed at 0.5 and 0.9 (None:
            not scored).
        failures: why the check fails, one line each (empty: it holds).
        lines: the report, one line per figure, the verdict last.
    """

    hybrid: list[dict[str, int]]
    flight: list[LabelScores]
    families: list[dict[str, Any]] | None
    failures: list[str] = field(default_factory=list)
    lines: list[str] = field(default_factory=list)

    @property
    def holds(self) -> bool:
        return not self.failures


def hybrid_counts(models: list[PathLike], data: PathLike) -> list[dict[str, int]]:
    """Per model: false alarms and obstacles passed (at 0.5) on the data's test split."""
    from landing_zone.judging.checkpoint import input_configs, load_model
    from landing_zone.judging.inference import Predictor
    from landing_zone.tools.learn.samples import voxelize
    from landing_zone.tools.learn.scenes import ScenePack
    from landing_zone.tools.sim.shards import SceneDataset

    ds = SceneDataset(data, 'test')
    pack = ScenePack.from_scenes(ds, np.arange(len(ds)))
    out, volumes = [], {}
    for path in models:
        net, meta = load_model(path, 'cpu')
        key = json.dumps(input_configs(meta), default=str)
        if key not in volumes:  # models of the same input share the voxels
            volumes[key] = voxelize(pack, *input_configs(meta), 0, False)
        x, y = volumes[key]
        with Predictor(net) as predict:
            p = predict(x)
        y = y.numpy()
        out.append({'safe': int((y == 1).sum()), 'false_alarms': int((p[y == 1] < 0.5).sum()),
                    'unsafe': int((y == 0).sum()), 'passed': int((p[y == 0] >= 0.5).sum())})
    return out


def family_passes(families_json: PathLike) -> list[dict[str, Any]]:
    """Per model in the file (in its order): test-family obstacle tiles passed at 0.5, 0.9."""
    from landing_zone.tools.sim.families import TEST_FAMILIES

    with open(families_json, encoding='utf-8') as f:
        rep = json.load(f)['families']['methods']
    out = []
    for name, per in rep.items():
        obs = [per['obstacle'][f] for f in TEST_FAMILIES if f in per['obstacle']]
        n = sum(f['n_unsafe'] for f in obs)
        out.append({'name': name, 'n': n,
                    '0.5': round(sum(f['unsafe_ge_0.5'] * f['n_unsafe'] for f in obs)),
                    '0.9': round(sum(f['unsafe_ge_0.9'] * f['n_unsafe'] for f in obs)),
                    'safe_flagged': round(sum(f['safe_lt_0.5'] * (f['n'] - f['n_unsafe'])
                                              for f in obs))})
    return out


def _auc(s: LabelScores) -> float | None:
    return None if s.auc is None else round(s.auc, 3)


def site_check(initial_model: PathLike, adapted_model: PathLike, hybrid: PathLike,
               labels: PathLike, initial_report: PathLike, adapted_report: PathLike,
               families: PathLike | None = None) -> SiteCheck:
    """Compare the initial and the adapted model (module docstring).

    Args:
        initial_model, adapted_model: the model files.
        hybrid: the hybrid set (its test split is judged).
        labels: SITE.labels.json of the replayed flight.
        initial_report, adapted_report: REPORT.json of the flight replayed with each model.
        families: ``evaluate --by-family --json`` of both models, initial first; None: the
            test families are not scored, and the check cannot hold.

    Raises:
        ConfigError: the families file holds other than two models.
    """
    h0, h1 = hybrid_counts([initial_model, adapted_model], hybrid)
    truth = read_labels(labels)
    flight = []
    for path in (initial_report, adapted_report):
        with open(path, encoding='utf-8') as f:
            flight.append(score_report(json.load(f), truth, 0.5))
    f0, f1 = flight
    fam = family_passes(families) if families is not None else None
    if fam is not None and len(fam) != 2:
        raise ConfigError(f'{families}: {len(fam)} models, want the initial and the adapted one')
    res = SiteCheck([h0, h1], flight, fam)
    res.lines += [
        f'held-out vegetation, hybrid test split: safe tiles flagged {h0["false_alarms"]} -> '
        f'{h1["false_alarms"]} of {h0["safe"]}; obstacle tiles passed {h0["passed"]} -> '
        f'{h1["passed"]} of {h0["unsafe"]}',
        f'held-out vegetation, flight {Path(labels).name}: safe tiles flagged '
        f'{f0.false_alarms} -> {f1.false_alarms} of {f0.safe}; obstacle tiles passed '
        f'{f0.unsafe_judged_safe} -> {f1.unsafe_judged_safe} of {f0.unsafe}; AUC '
        f'{_auc(f0)} -> {_auc(f1)}']
    alarms0, alarms1 = h0['false_alarms'] + f0.false_alarms, h1['false_alarms'] + f1.false_alarms
    if not (alarms1 < alarms0 and h1['false_alarms'] <= h0['false_alarms']
            and f1.false_alarms <= f0.false_alarms):
        res.failures.append('false alarms on the held-out vegetation not cut')
        res.lines.append('  ' + res.failures[-1])
    if fam is not None:
        a, b = fam
        res.lines.append(
            f'test obstacle families ({a["n"]} obstacle tiles): passed at P(safe) >= 0.5 '
            f'{a["0.5"]} -> {b["0.5"]}, at >= 0.9 {a["0.9"]} -> {b["0.9"]}; their safe tiles '
            f'flagged {a["safe_flagged"]} -> {b["safe_flagged"]}')
        if b['0.5'] > a['0.5'] or b['0.9'] > a['0.9']:
            res.failures.append('more test-family obstacle tiles passed')
            res.lines.append('  ' + res.failures[-1])
    else:
        res.failures.append('test obstacle families not scored (no --families)')
        res.lines.append('test obstacle families: not scored (no --families)')
    res.lines.append('site-adaptation check: ' + ('holds' if res.holds else 'FAILS'))
    return res
