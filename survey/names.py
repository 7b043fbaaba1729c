"""Names and paths that come from users and input files: checked before they touch the disk.

A project or session name becomes a folder name (``<root>/<project>/sessions/<session>``), and
files name other files (the design in ``session.toml``, ``tgms.toml`` and ``project.toml``). A
name such as ``..``, ``a/b`` or ``/etc`` would put the folder elsewhere, and a file naming
``../../x`` would make a command read outside the folder it was given (issue 12, "Security").
No paper section: input handling at the application's edge.
"""
from __future__ import annotations

import os
import unicodedata
from pathlib import Path, PurePath

#: Longest project or session name, characters (a file name may have 255 bytes; the session
#: folder adds a suffix or two).
MAX_NAME_CHARS = 100


class UnsafeNameError(ValueError):
    """A name or a path from an input file that is not allowed (the message says which and why)."""


def check_name(kind: str, name: str) -> str:
    """Return ``name`` if it can be a project or session folder name, else raise.

    Parameters
    ----------
    kind : what is named, for the message (``"project name"``, ``"--session"``).
    name : the name as given.

    Raises
    ------
    UnsafeNameError
        empty, ``.`` or ``..``, a path separator, a leading dot or blank, a control character,
        or longer than :data:`MAX_NAME_CHARS`.
    """
    text = "" if name is None else str(name)
    why = None
    if text.strip() == "":
        why = "is empty"
    elif text in (".", "..") or text.startswith("."):
        why = "must not start with a dot"
    elif "/" in text or "\\" in text or (os.sep in text) or (os.altsep and os.altsep in text):
        why = "must not contain a path separator (a name, not a path)"
    elif any(unicodedata.category(c).startswith("C") for c in text):
        why = "must not contain control characters"
    elif text != text.strip():
        why = "must not start or end with a blank"
    elif len(text) > MAX_NAME_CHARS:
        why = f"is {len(text)} characters long, at most {MAX_NAME_CHARS} are allowed"
    if why:
        shown = text if len(text) <= 40 else text[:37] + "..."
        raise UnsafeNameError(f"{kind} {shown!r} {why}")
    return text


def is_relative_inside(name: str) -> bool:
    """True for a non-empty relative path without ``..`` parts (so it stays inside its folder)."""
    if not isinstance(name, str) or name.strip() == "":
        return False
    p = PurePath(name)
    return not p.is_absolute() and ".." not in p.parts and not name.startswith(("/", "\\"))


def inside(folder: Path, name: str, where: str) -> Path:
    """``folder / name`` if it stays inside ``folder`` (symbolic links resolved), else raise.

    Parameters
    ----------
    folder : the folder the input file lies in.
    name : the path the file names.
    where : the file and key, for the message (``"project.toml: key design.alignment"``).

    Raises
    ------
    UnsafeNameError
    """
    if not is_relative_inside(name):
        raise UnsafeNameError(f"{where}: must be a relative path inside {folder}, got {name!r}")
    path = Path(folder) / name
    try:
        ok = path.resolve().is_relative_to(Path(folder).resolve())
    except (OSError, RuntimeError):
        ok = False
    if not ok:
        raise UnsafeNameError(f"{where}: {name!r} leads outside {folder} (a symbolic link)")
    return path
