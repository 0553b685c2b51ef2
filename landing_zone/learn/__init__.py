"""Offline learning: training, evaluation, architecture search, calibration, baselines."""
