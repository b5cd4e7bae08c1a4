"""Typed errors of skelfuse. The library raises these; only ``cli.py`` turns them into exit codes and hints.

Every message says what failed, what was expected versus what was found, and what to check next.
"""

from __future__ import annotations


class SkelfuseError(Exception):
    """Base class of every error skelfuse raises on purpose."""


class ConfigError(SkelfuseError):
    """A configuration or profile file is missing, malformed, or holds an unknown key or a wrong type."""


class DataError(SkelfuseError):
    """Input data (a recording, a BVH file, a payload) is missing or malformed."""


class CalibrationError(SkelfuseError):
    """A calibration is missing, malformed, or could not be computed."""


class ServiceError(SkelfuseError):
    """A long-running node cannot do its job: a source that cannot start, a zenoh session that cannot open."""
