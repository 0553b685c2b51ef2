"""Write a development flight set whose vegetation is the randomised priors.

    python priors_set.py OUT_DIR [--seed S] [--repeats K]

The training obstacle families (``development``) crossed with ``meadow``, ``forb`` and
``canopy``, the simulator's randomised vegetation priors, under the held-out set's spread of
ground, scanners and heights. Those priors are held-out vegetation, so a judge trained on this
set is scored only on the held-out flights of the other four (clumped, tall, bushy, mixed).
"""
import argparse

from landing_zone.tools.sim import flight_sets

PRIORS = ('meadow', 'forb', 'canopy')


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('out')
    ap.add_argument('--seed', type=int, default=3)
    ap.add_argument('--repeats', type=int, default=2)
    a = ap.parse_args()
    flight_sets.SETS['development'] = (flight_sets.DEVELOPMENT_OBSTACLES, PRIORS)
    flight_sets.simulate_set('development', a.seed, a.out, repeats=a.repeats, workers=2)


if __name__ == '__main__':
    main()
