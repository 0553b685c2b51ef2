"""Counts -> judgements: tiles and their ground, the safety CNN, landing sites (onboard)."""
