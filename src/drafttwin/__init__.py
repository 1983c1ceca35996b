"""drafttwin: mechanism-data hybrid models of a drawing frame's drafting section (FA320A)."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("drafttwin")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0"

ROLLERS: tuple[str, ...] = ("front", "second", "third", "back")
"""The four bottom rollers of the 4-over-4 drafting section, delivery side first."""

__all__ = ["ROLLERS", "__version__"]
