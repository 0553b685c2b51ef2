"""Evaluation: ROC tables, leave-one-family-out, flights scored against their labels, baselines."""
