"""Rays -> counts: the compiled ray traversal and the scrolling density map (onboard)."""
