"""Errors raised by the landing_zone core.

Every error the core raises on bad input derives from :class:`LandingZoneError`, so front ends
(the CLI, the node) can catch one type, report its message in one line and carry on.
"""
from __future__ import annotations

__all__ = [
    'LandingZoneError',
    'ConfigError',
    'InvalidCloudError',
    'InvalidPoseError',
    'ModelError',
    'BagError',
    'DatasetError',
    'SimulationError',
    'EngineError',
]


class LandingZoneError(Exception):
    """Base class of every error the landing_zone core raises on bad input."""


class ConfigError(LandingZoneError, ValueError):
    """A configuration value or parameter is out of range or inconsistent."""


class InvalidCloudError(LandingZoneError, ValueError):
    """A point cloud (message or array) is malformed: the message names what is wrong."""


class InvalidPoseError(LandingZoneError, ValueError):
    """A pose is malformed (non-finite, non-unit quaternion) or unavailable at a stamp."""


class ModelError(LandingZoneError):
    """A model file is missing, corrupt, or of another architecture than it claims."""


class BagError(LandingZoneError):
    """A bag cannot be read or written, or lacks the topics asked for."""


class DatasetError(LandingZoneError):
    """A dataset directory is missing, incomplete or inconsistent."""


class SimulationError(LandingZoneError, ValueError):
    """Simulation parameters are nonsensical (checked before any work starts)."""


class EngineError(LandingZoneError):
    """Fan-out work cannot run: an unknown engine, Ray missing or unreachable, a dead worker."""
