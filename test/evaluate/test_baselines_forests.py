"""The learned baselines (Raw RF, BoW RF) and the factory evaluation uses."""
from __future__ import annotations

import numpy as np
import pytest
from sklearn.metrics import roc_auc_score

from landing_zone.tools.evaluate.baselines import (BowForest, PlaneResiduals, RawForest,
                                                   make_baselines)
from landing_zone.tools.evaluate.baselines.toy import boxes_and_flats
from landing_zone.errors import DatasetError, ModelError


@pytest.fixture(scope='module')
def boxes():
    train = boxes_and_flats(120, seed=1)
    test = boxes_and_flats(60, seed=2)
    return train, test


def test_factory_names_and_interface():
    methods = make_baselines(seed=3)
    assert [m.name for m in methods] == ['Plane residuals', 'Raw RF', 'BoW RF']
    assert not hasattr(methods[0], 'fit')
    assert all(callable(m.fit) for m in methods[1:])
    assert all(m.seed == 3 for m in methods)
    # evaluate.py reports an ECE only for methods whose scores are P(safe).
    assert [m.probabilistic for m in methods] == [False, True, True]


def test_raw_forest_separates_boxes_from_flat(boxes):
    (x, y), (xt, yt) = boxes
    score = RawForest(seed=0).fit(x, y).score(xt)
    assert score.shape == (60,) and np.all((score >= 0) & (score <= 1))
    assert roc_auc_score(yt, score) > 0.9


def test_bow_forest_separates_boxes_from_flat(boxes):
    (x, y), (xt, yt) = boxes
    model = BowForest(seed=0).fit(x, y)
    assert model.words.shape == (512, 16)
    hist = model.histograms(xt)
    assert hist.shape == (60, 512)
    np.testing.assert_allclose(hist.sum(axis=1), 1.0, atol=1e-5)
    assert roc_auc_score(yt, model.score(xt)) > 0.9


def test_learned_baselines_are_deterministic(boxes):
    (x, y), (xt, _) = boxes
    x, y = x[:40], y[:40]
    for make in (lambda s: RawForest(seed=s), lambda s: BowForest(seed=s, words=32)):
        a = make(7).fit(x, y).score(xt)
        b = make(7).fit(x, y).score(xt)
        assert a.tobytes() == b.tobytes()
    a = BowForest(seed=7, words=32).fit_codebook(x)
    c = BowForest(seed=8, words=32).fit_codebook(x)
    assert not np.array_equal(a, c)


def test_codebook_learned_on_a_quarter():
    x, _ = boxes_and_flats(8, seed=4)
    model = BowForest(seed=0, words=4000)
    words = model.fit_codebook(x)
    # Two of the eight volumes feed k-means; with more words asked than voxels, each voxel of
    # that sample becomes a word.
    from landing_zone.tools.evaluate.baselines import voxel_features
    per_volume = np.bincount(voxel_features(x).volume, minlength=8)
    assert words.shape[0] in {int(per_volume[i] + per_volume[j])
                              for i in range(8) for j in range(i + 1, 8)}


def test_errors():
    x, y = boxes_and_flats(6, seed=5)
    for method in (RawForest(), BowForest(words=8)):
        with pytest.raises(ModelError, match='fitted'):
            method.score(x)
        with pytest.raises(DatasetError, match='both safe'):
            method.fit(x, np.ones(6))
        with pytest.raises(DatasetError, match='labels'):
            method.fit(x, y[:5])
        with pytest.raises(DatasetError, match='1 \\(safe\\) or 0'):
            method.fit(x, np.full(6, 2))
    raw = RawForest().fit(x, y)
    with pytest.raises(DatasetError, match='trained on volumes'):
        raw.score(np.zeros((1, 1, 24, 24, 24), np.float32))
    with pytest.raises(DatasetError, match='no occupied voxel'):
        BowForest(words=8).fit(np.zeros_like(x), y)
    # Non-finite voxels are read as unobserved, never a crash.
    bad = x.copy()
    bad[:, :, 3:5] = np.nan
    assert np.all(np.isfinite(raw.score(bad)))
    assert np.all(np.isfinite(PlaneResiduals().score(bad)))
