"""Reading tolerance sets: the built-in ones (package data trolley/tolerance_sets/*.toml) or a
user's TOML file (format ``trolley-tolerances/1``, docs/track_geometry.md)."""
from __future__ import annotations

from importlib import resources
from pathlib import Path

from trolley.tolerances import ToleranceError, ToleranceSet, parse_tolerances

_PACKAGE = "trolley.tolerance_sets"


def builtin_tolerance_names() -> list[str]:
    """Names of the built-in tolerance sets (file stems)."""
    return sorted(p.name[:-5] for p in resources.files(_PACKAGE).iterdir() if p.name.endswith(".toml"))


def load_tolerances(name_or_path: str | Path) -> ToleranceSet:
    """A built-in tolerance set by name, or a TOML file by path.

    Raises
    ------
    ToleranceError
        Unknown name, unreadable file, or invalid content (message names the file and key).
    """
    text_name = str(name_or_path)
    if text_name in builtin_tolerance_names():
        res = resources.files(_PACKAGE) / f"{text_name}.toml"
        return parse_tolerances(res.read_text(encoding="utf-8"), origin=f"built-in:{text_name}")
    path = Path(name_or_path)
    if not path.is_file():
        raise ToleranceError(f"{text_name}: neither a built-in tolerance set "
                             f"({', '.join(builtin_tolerance_names())}) nor a file")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise ToleranceError(f"{path}: cannot read ({e})") from None
    return parse_tolerances(text, origin=str(path))
