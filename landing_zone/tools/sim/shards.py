"""The synth datasets on disk: shards of scenes written and read back (no pickle).

**Format (version 1).** ``meta.json`` (dataset, seed, sweep, counts, obstacle split, shard
table) and ``shards/shard-NNNNN.npz`` (numpy arrays in a zip, no pickled objects) with, for the
S scenes of the shard and their N returns in total:

==================  ============  ===========================================================
``scene_index``     int64 (S,)    canonical index in the sweep
``label``           uint8 (S,)    1 safe, 0 unsafe
``split``           uint8 (S,)    0 train, 1 test
``point_offsets``   int64 (S+1,)  returns of scene s are ``point_offsets[s]:[s+1]``
``points_delta``    int16 (3, N)  return positions in millimetres relative to the tile centre,
                                  per coordinate the difference to the scene's previous return
                                  (modulo 2^16; the first from 0): consecutive returns are
                                  neighbours along a scan line, so the differences are small
                                  and compress to two thirds of the positions' size
``hit_class``       uint8 (N,)    what each return hit: 0 ground, 1 grass, 2 obstacle
``origin_index``    uint16 (N,)   row of the scene's origin table
``origin_offsets``  int64 (S+1,)  origin table of scene s is ``origins[origin_offsets[s]:...]``
``origins``         float32 (M,3) sensor origin of each scan line [m], tile frame
``origin_times``    float32 (M,)  start time of each scan line [s]
``params_json``     uint8 (B,)    UTF-8 JSON: a list of S parameter dicts
==================  ============  ===========================================================

Zip entries carry a fixed time stamp, so the same scenes give the same bytes; shards are
written to a temporary name and renamed, so an interrupted run leaves only whole shards.
"""
from __future__ import annotations

import io
import json
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np

from landing_zone.errors import DatasetError

__all__ = ['FORMAT_VERSION', 'Scene', 'SceneDataset', 'iter_records', 'prepare_output',
           'shard_arrays', 'shard_complete', 'shard_name', 'write_json', 'write_npz']

FORMAT_VERSION = 1
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)  # fixed zip time stamps: same seed, same bytes


@dataclass
class Scene:
    """One patch as the network's data pipeline sees it (tile centred at (0, 0), ground near 0).

    Attributes:
        points: (N, 3) float32 returns [m].
        origins: (N, 3) float32 sensor origin of each return [m].
        label: 1 safe, 0 unsafe.
        params: the scene's parameters (setting, obstacle, scan figures).
        hit_class: (N,) uint8 what each return hit (0 ground, 1 grass, 2 obstacle).
    """

    points: np.ndarray
    origins: np.ndarray
    label: int
    params: dict
    hit_class: np.ndarray | None = None


def write_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write arrays as an .npz with fixed zip time stamps, atomically (temp file + rename)."""
    tmp = path.with_name(f'{path.name}.tmp-{os.getpid()}')
    with zipfile.ZipFile(tmp, 'w', compression=zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
        for name, arr in arrays.items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.ascontiguousarray(arr), allow_pickle=False)
            info = zipfile.ZipInfo(f'{name}.npy', date_time=_ZIP_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, buf.getvalue(), compress_type=zipfile.ZIP_DEFLATED,
                        compresslevel=1)
    os.replace(tmp, path)


def _delta_encode(mm: np.ndarray) -> np.ndarray:
    """(N, 3) int16 -> (3, N) int16 differences to the previous row (wrapping)."""
    d = np.diff(mm.astype(np.int32), axis=0, prepend=np.zeros((1, 3), np.int32))
    return np.ascontiguousarray(d.T).astype(np.int16)  # wraps modulo 2^16, undone exactly


def _delta_decode(delta: np.ndarray) -> np.ndarray:
    """Inverse of :func:`_delta_encode`: the int16 running sum wraps back exactly."""
    return np.cumsum(delta, axis=1, dtype=np.int16).T


def shard_arrays(records: list[dict[str, Any]]) -> dict[str, np.ndarray]:
    def offsets(key: str) -> np.ndarray:
        return np.concatenate([[0], np.cumsum([len(r[key]) for r in records])]).astype(np.int64)
    params = json.dumps([r['params'] for r in records], sort_keys=True,
                        separators=(',', ':')).encode()
    return {
        'scene_index': np.array([r['params']['index'] for r in records], dtype=np.int64),
        'label': np.array([r['label'] for r in records], dtype=np.uint8),
        'split': np.array([r['split'] == 'test' for r in records], dtype=np.uint8),
        'point_offsets': offsets('points_mm'),
        'points_delta': np.concatenate([_delta_encode(r['points_mm']) for r in records], axis=1),
        'hit_class': np.concatenate([r['hit_class'] for r in records]),
        'origin_index': np.concatenate([r['origin_index'] for r in records]),
        'origin_offsets': offsets('origins'),
        'origins': np.concatenate([r['origins'] for r in records]),
        'origin_times': np.concatenate([r['origin_times'] for r in records]),
        'params_json': np.frombuffer(params, dtype=np.uint8),
    }


def shard_name(k: int) -> str:
    return f'shards/shard-{k:05d}.npz'


def shard_complete(path: Path, indices: list[int]) -> bool:
    """A finished shard: a readable zip whose scene_index matches the plan."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return np.array_equal(z['scene_index'], np.asarray(indices, dtype=np.int64))
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError):
        return False


def write_json(path: Path, obj: Any) -> None:
    tmp = path.with_name(path.name + '.tmp')
    tmp.write_text(json.dumps(obj, indent=1, sort_keys=True) + '\n', encoding='utf-8')
    os.replace(tmp, path)


def prepare_output(out: Path, meta: dict[str, Any], plan_key: Any) -> None:
    """Start or resume a dataset directory: refuse one that holds another plan (``plan_key``
    of the metadata differs), drop half-written shards, write ``meta`` marked incomplete.

    Raises:
        DatasetError: ``out`` holds another dataset, or its meta.json is unreadable.
    """
    meta_path = out / 'meta.json'
    if meta_path.exists():
        try:
            old = json.loads(meta_path.read_text(encoding='utf-8'))
        except (OSError, ValueError) as err:
            raise DatasetError(f'{meta_path} is unreadable: {err}') from err
        if plan_key(old) != plan_key(meta):
            split = f', split {old["split"]}' if 'split' in old else ''
            raise DatasetError(
                f'{out} already holds another dataset ({old.get("dataset")}, seed '
                f'{old.get("seed")}, {old.get("n_scenes")} scenes{split}); choose another '
                '--out or remove it')
    (out / 'shards').mkdir(parents=True, exist_ok=True)
    for stale in (out / 'shards').glob('*.tmp-*'):
        stale.unlink()  # a shard an interrupted run was writing
    meta['complete'] = False
    write_json(meta_path, meta)


class SceneDataset:
    """The scenes of one split of a dataset directory, loaded lazily shard by shard.

    Args:
        root: directory written by :func:`simulate_dataset`.
        split: ``train``, ``test`` or ``all``.
        cache_shards: decoded shards kept in memory (least recently used dropped).

    Raises:
        DatasetError: the directory is missing, incomplete or of another format.
    """

    def __init__(self, root: str | os.PathLike, split: str = 'train',
                 cache_shards: int = 4) -> None:
        self.root = Path(root)
        if split not in ('train', 'test', 'all'):
            raise DatasetError(f"split must be 'train', 'test' or 'all', got {split!r}")
        meta_path = self.root / 'meta.json'
        if not meta_path.exists():
            raise DatasetError(f'{self.root} is no dataset directory (no meta.json)')
        try:
            self.meta = json.loads(meta_path.read_text(encoding='utf-8'))
        except (OSError, ValueError) as err:
            raise DatasetError(f'{meta_path} is unreadable: {err}') from err
        if self.meta.get('format_version') != FORMAT_VERSION:
            raise DatasetError(f'{self.root}: format version {self.meta.get("format_version")} '
                               f'(this code reads {FORMAT_VERSION})')
        if not self.meta.get('complete'):
            raise DatasetError(f'{self.root} is incomplete: rerun the same simulate command '
                               'to finish it')
        self.split = split
        self._index: list[tuple[int, int]] = []
        labels = []
        for k, shard in enumerate(self.meta['shards']):
            for j, (t, lab) in enumerate(zip(shard['test'], shard['labels'])):
                if split == 'all' or (t == '1') == (split == 'test'):
                    self._index.append((k, j))
                    labels.append(int(lab))
        self.labels = np.array(labels, dtype=np.int64)
        self._cache: dict[int, dict[str, Any]] = {}
        self._cache_size = max(1, cache_shards)

    def __len__(self) -> int:
        return len(self._index)

    def __repr__(self) -> str:
        return (f'SceneDataset({str(self.root)!r}, split={self.split!r}: {len(self)} scenes, '
                f'{int((self.labels == 0).sum())} unsafe)')

    def _shard(self, k: int) -> dict[str, Any]:
        if k in self._cache:
            self._cache[k] = self._cache.pop(k)  # most recently used goes last
            return self._cache[k]
        path = self.root / self.meta['shards'][k]['file']
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {name: z[name] for name in z.files}
        except (OSError, ValueError, KeyError, zipfile.BadZipFile) as err:
            raise DatasetError(f'{path} is missing or corrupt: {err}') from err
        data['params'] = json.loads(data.pop('params_json').tobytes().decode())
        self._cache[k] = data
        while len(self._cache) > self._cache_size:
            self._cache.pop(next(iter(self._cache)))
        return data

    def __getitem__(self, i: int) -> Scene:
        if not -len(self) <= i < len(self):
            raise IndexError(f'scene {i} out of range ({len(self)} scenes)')
        k, j = self._index[i]
        z = self._shard(k)
        p0, p1 = z['point_offsets'][j], z['point_offsets'][j + 1]
        o0, o1 = z['origin_offsets'][j], z['origin_offsets'][j + 1]
        points = _delta_decode(z['points_delta'][:, p0:p1]).astype(np.float32) * np.float32(
            0.001)
        origins = z['origins'][o0:o1][z['origin_index'][p0:p1]]
        return Scene(points, origins, int(z['label'][j]), dict(z['params'][j]),
                     z['hit_class'][p0:p1].copy())

    def __iter__(self) -> Iterator[Scene]:
        for i in range(len(self)):
            yield self[i]

    def params(self, i: int) -> dict:
        """Parameters of scene ``i`` (loads its shard)."""
        return self[i].params


def iter_records(root: str | os.PathLike) -> Iterable[dict]:
    """Parameters of every scene of a dataset directory, in shard order (both splits)."""
    ds = SceneDataset(root, 'all')
    for k in range(len(ds.meta['shards'])):
        yield from ds._shard(k)['params']
