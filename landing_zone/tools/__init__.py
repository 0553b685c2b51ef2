"""Offline tooling, never imported by the node: simulation, learning, evaluation, benchmarks,
the CLI."""
