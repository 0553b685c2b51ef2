"""Map snapshots: the density map and the tiles' results on disk, so a restart loses nothing.

The node saves its map every ``snapshot.period`` seconds and when it shuts down, and loads it at
start when the file matches what it is about to build. A snapshot is a safetensors file (tensors
plus a string-to-string header; loading it runs no code from the file, unlike pickle) holding:

* the map's window and counts exactly as stored (hot bytes, cold blocks; see
  :meth:`DensityMap.export_state`), the tiles the map has marked changed since the last pass,
* the tiles' results (P(safe), confidence, ground height, ...) and the newest cloud stamp,
* per tile, the returns from steep rays (``tiles.min_ray_depression_deg``, the angle with them;
  a snapshot without them loads, each tile's return count standing in),
* a JSON header: format version, frame, the map's and tiles' geometry, the mode (follow, or the
  fixed region's centre), the model's weight digest, the OOD reference's digest and when it
  was written.

Loading refuses, with one line naming the first difference, a file that is not such a snapshot or
was made for another frame, voxel size, map extent, tiling or region: its counts would mean
something else here. A snapshot made with another model or OOD reference keeps its counts; its
tiles are judged again by this one at the next pass. Writing goes through a temporary file and
``os.replace``, so a crash mid-write leaves the previous snapshot whole.
"""
from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from landing_zone.errors import ConfigError, LandingZoneError

if TYPE_CHECKING:
    from landing_zone.assessor import Assessor

__all__ = ['SnapshotError', 'save_snapshot', 'load_snapshot', 'snapshot_header', 'FORMAT']

FORMAT = 'landing_zone.snapshot/1'
_HEADER_KEY = 'landing_zone'


class SnapshotError(LandingZoneError):
    """A snapshot file is unreadable, not a snapshot, or made for another map."""


def snapshot_header(assessor: Assessor) -> dict[str, Any]:
    """What a snapshot must agree on with the assessor that loads it (plus the model)."""
    cfg = assessor.config
    return {
        'format': FORMAT,
        'frame_id': cfg.frame_id,
        'voxel_size': float(cfg.map.voxel_size),
        'shape': [int(v) for v in cfg.map.shape],
        'z_below': float(cfg.map.z_below),
        'tile_size': float(cfg.tiles.tile_size),
        'padding': int(cfg.tiles.padding),
        'center': None if cfg.center is None else [float(c) for c in cfg.center],
        'model': str(assessor.model_metadata.get('weights_sha256')
                     or assessor.model.config.spec),
        # the OOD reference the tiles were judged with (None: none)
        'ood': assessor.ood.digest if assessor.ood is not None else None,
    }


def save_snapshot(path: str | os.PathLike[str], assessor: Assessor,
                  stamp_ns: int | None = None) -> int:
    """Write the assessor's map and tiles to ``path`` (atomically).

    Args:
        path: the file.
        assessor: whose map and tiles.
        stamp_ns: the stamp of the newest cloud in the map [ns], kept exactly (the assessor
            keeps it in float seconds), so a restored grid carries the stamp it had.

    Returns:
        Bytes written.

    Raises:
        SnapshotError: the file cannot be written.
    """
    from safetensors.numpy import save

    state = assessor.export_state()
    header = snapshot_header(assessor)
    header['saved_at'] = time.time()
    header['clouds'] = int(assessor.clouds)
    header['stamp_ns'] = None if stamp_ns is None else int(stamp_ns)
    blob = save({k: np.ascontiguousarray(v) for k, v in state.items()},
                metadata={_HEADER_KEY: json.dumps(header)})
    p = Path(path)
    tmp = p.with_name(p.name + '.tmp')
    try:
        if p.parent != Path(''):
            p.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, 'wb') as f:
            f.write(blob)
        os.replace(tmp, p)
    except OSError as err:
        raise SnapshotError(f'cannot write snapshot {p}: {err.strerror or err}') from err
    return len(blob)


def _read(p: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    from safetensors import SafetensorError
    from safetensors.numpy import load

    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise SnapshotError(f'snapshot {p} not found') from None
    except OSError as err:
        raise SnapshotError(f'cannot read snapshot {p}: {err.strerror or err}') from err
    if len(data) < 8:
        raise SnapshotError(f'{p} is not a snapshot (only {len(data)} bytes)')
    n = int.from_bytes(data[:8], 'little')
    try:
        if n > len(data) - 8:
            raise ValueError('header length beyond the end of the file')
        meta = json.loads(data[8:8 + n].decode('utf-8')).get('__metadata__') or {}
        header = json.loads(meta[_HEADER_KEY])
        arrays = load(data)
    except (ValueError, KeyError, TypeError, AttributeError, SafetensorError) as err:
        text = ' '.join(str(err).split()) or type(err).__name__
        raise SnapshotError(f'{p} is not a snapshot ({text[:120]})') from None
    if not isinstance(header, dict) or header.get('format') != FORMAT:
        got = header.get('format') if isinstance(header, dict) else None
        raise SnapshotError(f'{p} is not a snapshot of format {FORMAT} (format {got!r})')
    return header, arrays


def load_snapshot(path: str | os.PathLike[str], assessor: Assessor) -> dict[str, Any]:
    """Restore a snapshot into a fresh assessor of the same map, tiles and region.

    Returns:
        The snapshot's header, with ``'tiles_restored'``: False when another model made it
        (the counts are restored, every tile is judged again at the next pass).

    Raises:
        SnapshotError: unreadable, not a snapshot, or made for another frame, map, tiling or
            region (one line naming the first difference); the assessor is left as it was.
    """
    p = Path(path)
    header, arrays = _read(p)
    want = snapshot_header(assessor)
    for key in ('frame_id', 'voxel_size', 'shape', 'z_below', 'tile_size', 'padding',
                'center'):
        got, mine = header.get(key), want[key]
        same = got == mine
        if isinstance(mine, float) and isinstance(got, (int, float)):
            same = math.isclose(float(got), mine, rel_tol=1e-9, abs_tol=1e-12)
        if not same:
            what = 'region_center' if key == 'center' else key
            raise SnapshotError(f'snapshot {p} was made for {what} {_show(got)}, this node has '
                                f'{_show(mine)}')
    # tiles judged by another model or OOD reference are judged again; a snapshot without an
    # 'ood' entry predates the signal (and its tiles lack the OOD distances)
    tiles = header.get('model') == want['model'] and 'ood' in header and \
        header['ood'] == want['ood']
    try:
        assessor.import_state(arrays, tiles=tiles)
    except ConfigError as err:
        raise SnapshotError(f'snapshot {p} does not fit this map: {err}') from None
    out = dict(header)
    out['tiles_restored'] = tiles
    return out


def _show(value: Any) -> str:
    if value is None:
        return 'unset (follow mode)'
    return repr(value)
