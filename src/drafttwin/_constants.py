"""Constants every layer may use: the package version and the FA320A's roller names."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("drafttwin")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0"

ROLLERS: tuple[str, ...] = ("front", "second", "third", "back")
"""The four bottom rollers of the FA320A's 4-over-4 drafting section, delivery side first
(the default output channels)."""
