"""The software version, read from the installed package's metadata (``pyproject.toml``).

One place for the version: ``trolley --version`` and the deliverables that print a software
version take it from here, so it never disagrees with what ``pip`` installed.
"""
from __future__ import annotations

from importlib import metadata

#: Distribution name in pyproject.toml ``[project] name``.
DISTRIBUTION = "trolley-survey"


def version() -> str:
    """The installed version of the trolley-survey distribution.

    Returns
    -------
    str
        ``importlib.metadata.version("trolley-survey")``, e.g. ``"0.1.0"``; ``"(version unknown:
        not installed as a package)"`` when the code runs from a source tree never installed.
    """
    try:
        return metadata.version(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        return "(version unknown: not installed as a package)"
