"""Copies of the leave-groups-out models with the final model's out-of-family calibration.

``landing-zone calibrate`` fits ``P(safe) = sigmoid(logit / T + b)`` on the fold models'
logits on the train scenes of the families each held out, and writes it into the final model.
To see what that calibration does on families a model never trained on, the fold models get
the same ``T`` and ``b`` (their weights bit for bit) and are scored on the *test* instances of
the families they held out (``landing-zone evaluate --by-family``). The calibration saw other
instances of those families (the train split's), so these figures are not free of it; the test
families (never in any training or calibration) judged by the final model are.

    python scripts/lofo_calibrated.py CALIBRATED_FINAL FOLD... --suffix _cal
"""
from __future__ import annotations

import argparse
from pathlib import Path

from landing_zone.judging.checkpoint import load_model, read_metadata, save_model


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('calibrated', type=Path, help='the final model after landing-zone calibrate')
    ap.add_argument('folds', type=Path, nargs='+', help='fold models (train --hold-out)')
    ap.add_argument('--suffix', default='_cal', help='appended to each fold file stem')
    args = ap.parse_args()
    cal = read_metadata(args.calibrated)
    if 'calibration' not in cal:
        raise SystemExit(f'{args.calibrated}: not calibrated by landing-zone calibrate')
    t, b = float(cal['temperature']), float(cal.get('calibration_offset', 0.0))
    for path in args.folds:
        net, meta = load_model(path)
        net.temperature, net.offset = t, b
        # save_model writes the format, spec, temperature, offset and digest afresh
        keep = {**meta, 'calibration': {'copied_from': str(args.calibrated), 'temperature': t,
                                        'offset': b}}
        out = path.with_name(path.stem + args.suffix + path.suffix)
        save_model(out, net, keep)
        print(f'wrote {out}: T {t:.3f}, offset {b:+.3f}')


if __name__ == '__main__':
    main()
