"""Offline learning: training, calibration, architecture search, ensembles."""
