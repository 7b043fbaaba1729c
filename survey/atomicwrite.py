"""Writing output files so that nothing is ever half written, lost or hidden from colleagues.

One place for the idea every writer of the application shares (no paper section: this is file
handling, DESIGN.md "bad input: never a partial output file, never a change to raw data"):

- :func:`atomic_path` / :func:`write_text_atomic` / :func:`write_bytes_atomic` /
  :func:`write_csv_frame`: the content goes
  to a temporary file in the target's folder, is flushed to disk (``fsync``), gets the mode a
  plain ``open()`` would have given it (``0o666 & ~umask``, typically 0644, not ``mkstemp``'s
  0600) and is ``os.replace``-d onto the target, so the target is always either the old file or
  the complete new one.
- :func:`check_suffix`: an output file's name ends in its format's suffix (``.xlsx``, ``.pdf``,
  ``.csv``, ``.png``), since other programs know a file by its name.
- :func:`check_outputs`: every output of a command checked (folder exists, target not a folder,
  not one of the command's inputs, not a raw session file, writable) *before* the first is
  written, so a command with several outputs writes all of them or none.
- :func:`guard_overwrite` / :func:`write_marker` / :func:`remove_own_folder`: ``--force`` style
  options delete or replace only what the same command made before (a marker file inside the
  folder), never someone's raw session or an arbitrary folder.

Errors are :class:`OutputError` (a ``ValueError``): one line naming the user's path, never the
temporary file.
"""
from __future__ import annotations

import contextlib
import contextvars
import os
import shutil
import tempfile
import threading
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

# Files a raw session folder holds (FORMATS.md sections 1 and 3): never an output target.
# The in-service recordings' (docs/inservice.md) too.
RAW_FILES = frozenset({"imu.csv", "odometer.csv", "gauge.csv", "fixes.csv", "session.toml", "stats.json",
                       "tgms.toml", "encoder.csv", "lasers.csv", "track.csv", "inservice.toml", "sensors.csv"})

#: Files that make a folder a raw session or a recording: no output folder may be one.
RAW_FOLDER_MARKS = ("session.toml", "tgms.toml", "inservice.toml")

_UMASK_LOCK = threading.Lock()
# (temporary, target) pairs whose os.replace waits for the enclosing all_or_nothing() block
_PENDING: contextvars.ContextVar[list[tuple[Path, Path]] | None] = contextvars.ContextVar("_PENDING", default=None)


class OutputError(ValueError):
    """An output that must not or cannot be written (message: the user's path and why)."""


def umask() -> int:
    """The process's current umask (read by setting it and putting it back)."""
    with _UMASK_LOCK:
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def file_mode() -> int:
    """The mode ``open(path, "w")`` gives a new file: ``0o666 & ~umask`` (``mkstemp`` gives 0600)."""
    return 0o666 & ~umask()


def folder_mode() -> int:
    """The mode ``os.mkdir`` gives a new folder: ``0o777 & ~umask`` (``mkdtemp`` gives 0700)."""
    return 0o777 & ~umask()


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on normal exit it becomes ``path`` atomically.

    The caller writes the temporary file (by name: pandas, matplotlib, openpyxl, zipfile, sqlite
    all accept one). On exit the file is fsynced, given the umask's mode and renamed onto
    ``path``; on any exception it is removed and ``path`` is untouched.

    Parameters
    ----------
    path : the file to produce.
    suffix : suffix of the temporary name (default: ``path``'s own, so writers that choose the
        format from the extension, like matplotlib, see the right one).

    Yields
    ------
    Path of the temporary file (hidden: its name starts with a dot).
    """
    path = Path(path)
    try:
        fd, tmp_name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.",
                                        suffix=path.suffix if suffix is None else suffix)
    except OSError as exc:
        # name the user's file, not the hidden temporary one that could not be made
        raise OSError(exc.errno, exc.strerror, str(path)) from None
    # (in the try at once: a SIGTERM, raised as an exception, between two statements here would
    # leave the temporary; survey.errors.sigterm_as_interrupt)
    tmp = Path(tmp_name)
    try:
        os.close(fd)
        pending = _PENDING.get()
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, file_mode())
        if pending is None:
            os.replace(tmp, path)
        else:
            pending.append((tmp, path))
    except BaseException as exc:
        tmp.unlink(missing_ok=True)
        if isinstance(exc, OSError) and exc.filename is not None and \
                Path(os.fsdecode(exc.filename)).name == tmp.name:
            # name the user's file, not the hidden temporary one
            raise OSError(exc.errno, exc.strerror, str(path)) from None
        raise
    if pending is None:
        _fsync_dir(path.parent)


@contextlib.contextmanager
def all_or_nothing() -> Iterator[None]:
    """Defer every :func:`atomic_path` replace inside the block to its successful end.

    Each file is written completely to its temporary first; only when the block ends without an
    exception are they all renamed onto their targets (in the order they were written), so a
    command with several outputs (export: xlsx, CSV, plots) leaves either all of them new or
    none; on an exception every temporary is removed and no target is touched.
    """
    outer = _PENDING.get()
    pending: list[tuple[Path, Path]] = []
    token = _PENDING.set(pending)
    try:
        yield
    except BaseException:
        for tmp, _ in pending:
            tmp.unlink(missing_ok=True)
        raise
    finally:
        _PENDING.reset(token)
    if outer is not None:
        outer.extend(pending)
        return
    try:
        for i, (tmp, path) in enumerate(pending):
            os.replace(tmp, path)
    except BaseException:
        for tmp, _ in pending[i:]:
            tmp.unlink(missing_ok=True)
        raise
    for folder in {path.parent for _, path in pending}:
        _fsync_dir(folder)


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_path`). Returns ``path``."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8, newlines as given) to ``path`` atomically. Returns ``path``."""
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
    return Path(path)


def write_csv_frame(path: str | os.PathLike, frame, float_format: str | None = None) -> Path:
    """Write a pandas DataFrame as CSV (no index, ``\\n`` line ends) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        frame.to_csv(tmp, index=False, float_format=float_format, lineterminator="\n")
    return Path(path)


def write_with(path: str | os.PathLike, writer: Callable[[Path], object]) -> Path:
    """Call ``writer(tmp)`` to write a temporary file, then put it in place atomically."""
    with atomic_path(path) as tmp:
        writer(tmp)
    return Path(path)


def remove_stale_temporaries(folder: str | os.PathLike, names: Iterable[str] | None) -> list[Path]:
    """Delete the hidden temporaries :func:`atomic_path` left in ``folder`` when a process was
    killed while writing (``.NAME.xxxxxxxx.ext``, and ``..NAME...`` of a writer that wrote through
    a temporary of its own). ``names``: the outputs whose temporaries may go; None: any output's.
    Call it only on a folder the caller owns, right before writing those outputs again. Returns
    the files deleted."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    import re

    # mkstemp's names: the prefix, 8 characters of [a-z0-9_], the suffix
    temporary = re.compile(r"^\.{1,2}(?P<name>.+)\.[a-z0-9_]{8}(\.[A-Za-z0-9]+)?$")
    gone = []
    for p in folder.iterdir():
        m = temporary.match(p.name)
        if not p.is_file() or m is None or p.name == MARKER_NAME:
            continue
        if names is None or any(m["name"] == n or m["name"].startswith(n + ".") for n in names):
            p.unlink(missing_ok=True)
            gone.append(p)
    return gone


# ------------------------------------------------------------------------------------------
# checks before writing
# ------------------------------------------------------------------------------------------
def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve() or (a.exists() and b.exists() and os.path.samefile(a, b))
    except OSError:
        return False


def check_suffix(option: str, path: str | os.PathLike | None, suffix: str, what: str) -> None:
    """Refuse an output file whose name does not end in ``suffix`` (any case): the format is the
    option's, and other programs (Excel, a PDF viewer, a file manager) know a file by its name
    (``export --xlsx x.csv`` wrote an Excel workbook named x.csv).

    Parameters
    ----------
    option : the option's name (``--xlsx``).
    path : its value (None: not given).
    suffix : the suffix the file must have (``.xlsx``).
    what : the file the option writes, for the message (``an Excel workbook``).

    Raises
    ------
    OutputError
        ``--xlsx x.csv: the file name must end in .xlsx (an Excel workbook; did you mean x.xlsx?)``.
    """
    if path is None or Path(path).suffix.lower() == suffix:
        return
    path = Path(path)
    # x.txt -> x.xlsx, x -> x.xlsx, x.xlsx.bak -> x.xlsx
    stem = path.stem if path.stem.lower().endswith(suffix) else path.stem + suffix
    hint = f"; did you mean {path.with_name(stem)}?" if path.name not in ("", ".", "..") else ""
    raise OutputError(f"{option} {path}: the file name must end in {suffix} ({what}{hint})")


def check_outputs(outputs: Iterable[tuple[str, Path | None]], inputs: Iterable[Path | None] = (),
                  folders: Iterable[tuple[str, Path | None]] = (),
                  made_before: Callable[[Path], bool] = lambda p: False) -> None:
    """Check every output of a command before the first one is written.

    Parameters
    ----------
    outputs : (option name, file) pairs; None entries are skipped.
    inputs : files the command reads: no output may be one of them.
    folders : (option name, folder) pairs of output folders (made if missing, so only an
        existing non-folder or an unwritable folder is refused).
    made_before : True for an existing file that this command wrote earlier (it may be replaced
        even when it carries a raw file's name).

    Raises
    ------
    OutputError
        naming the option and the path: folder missing, target a folder, target one of the
        inputs or a raw session file, not writable, two options naming the same file.
    """
    inputs = [Path(p) for p in inputs if p is not None]
    seen: dict[Path, str] = {}
    for option, out in outputs:
        if out is None:
            continue
        out = Path(out)
        if out.name in ("", ".", ".."):
            raise OutputError(f"{option} {out}: not a file name")
        if not out.parent.is_dir():
            raise OutputError(f"{option} {out}: folder {out.parent} does not exist")
        if out.is_dir():
            raise OutputError(f"{option} {out}: is a folder, give a file name")
        for src in inputs:
            if _same_file(out, src):
                raise OutputError(f"{option} {out}: is one of this command's inputs; "
                                  "choose another file name (the input is left unchanged)")
        if out.name in RAW_FILES and out.exists() and not made_before(out):
            raise OutputError(f"{option} {out}: would overwrite the data file {out.name} of "
                              f"{out.parent}; choose another file name")
        key = out.resolve()
        if key in seen:
            raise OutputError(f"{option} {out}: also given to {seen[key]}")
        seen[key] = option
        if not os.access(out.parent, os.W_OK | os.X_OK) or (out.exists() and not os.access(out, os.W_OK)):
            raise OutputError(f"{option} {out}: not writable (permission denied)")
    for option, folder in folders:
        if folder is None:
            continue
        folder = Path(folder)
        if folder.exists() and not folder.is_dir():
            raise OutputError(f"{option} {folder}: exists and is not a folder")
        for src in inputs:
            if _same_file(folder, src):
                raise OutputError(f"{option} {folder}: is this command's input folder; choose another folder")
        raw = [m for m in RAW_FOLDER_MARKS if (folder / m).exists()]
        if raw:
            raise OutputError(f"{option} {folder}: holds {raw[0]} (a recording or raw session, never written "
                              "into); choose another folder")
        inside = enclosing_raw_folder(folder)
        if inside is not None:
            raise OutputError(f"{option} {folder}: is inside {inside} (a recording or raw session, never written "
                              "into); choose a folder outside it")
        parent = folder if folder.is_dir() else folder.parent
        if not parent.is_dir():
            raise OutputError(f"{option} {folder}: folder {parent} does not exist")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise OutputError(f"{option} {folder}: not writable (permission denied)")


def enclosing_raw_folder(folder: Path) -> Path | None:
    """The raw session or recording folder that ``folder`` lies inside (an ancestor holding one of
    :data:`RAW_FOLDER_MARKS`), or None. Outputs written there would be mixed with raw data, and a
    later ``simulate --force`` on the session would delete them with it."""
    for up in Path(folder).absolute().parents:
        if any((up / m).is_file() for m in RAW_FOLDER_MARKS):
            return up
    return None


# ------------------------------------------------------------------------------------------
# --force / --overwrite: only what the same command made
# ------------------------------------------------------------------------------------------
MARKER_NAME = ".made-by-trolley"


def write_marker(folder: Path, command: str) -> None:
    """Mark ``folder`` as made by ``command`` (e.g. ``"simulate"``): only then may a later
    ``--force`` of the same command replace it."""
    write_text_atomic(Path(folder) / MARKER_NAME, command + "\n")


def claim_folder(folder: Path, command: str, option: str = "--out") -> None:
    """Mark ``folder`` as ``command``'s at once and exclusively (O_EXCL): of two commands started
    together into one new folder, both passing :func:`guard_overwrite`, only one gets it (bug hunt
    2026-11-26: two sessions wrote over each other's results). A folder already marked by
    ``command`` stays its own.

    Raises
    ------
    OutputError : another command's marker is there.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    try:
        fd = os.open(folder / MARKER_NAME, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    except FileExistsError:
        if made_by(folder, command):
            return
        raise OutputError(f"{option} {folder}: was just taken by another command ({MARKER_NAME}); choose another "
                          "folder") from None
    with os.fdopen(fd, "w", encoding="utf-8") as fh:
        fh.write(command + "\n")


def made_by(folder: Path, command: str) -> bool:
    """True if ``folder`` carries the marker of ``command``."""
    try:
        return (Path(folder) / MARKER_NAME).read_text(encoding="utf-8").strip() == command
    except (OSError, UnicodeDecodeError):
        return False


def guard_overwrite(out: Path, command: str, force: bool, option: str = "--out", *, reuse_own: bool = False,
                    force_option: str = "--force") -> None:
    """Refuse to write the folder ``out`` when something is there that this command did not make.

    Parameters
    ----------
    out : the output folder.
    command : name of the command, as written in the marker (``"simulate"``, ``"tgms simulate"``).
    force : the user's ``--force`` / ``--overwrite``.
    option : option name for the message.
    reuse_own : a folder this command made may be written again without ``force`` (commands
        that have no such option and replace their own files one by one).
    force_option : the command's name for ``force``, as the message names it.

    Raises
    ------
    OutputError
        ``out`` is a file; ``out`` is a non-empty folder and ``force`` is False; ``out`` is a
        non-empty folder without this command's marker (even with ``force``).
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{option} {out}: exists and is not a folder")
    inside = enclosing_raw_folder(out)
    if inside is not None:
        raise OutputError(f"{option} {out}: is inside {inside} (a recording or raw session); choose a folder "
                          "outside it")
    if not out.is_dir() or not any(out.iterdir()):
        return
    if reuse_own and made_by(out, command):
        return
    if not force and not reuse_own:
        raise OutputError(f"{option} {out}: already exists and is not empty (use {force_option} to replace it)")
    if not made_by(out, command):
        try:
            other = (out / MARKER_NAME).read_text(encoding="utf-8").strip()
        except (OSError, UnicodeDecodeError):
            other = ""
        made = f"its {MARKER_NAME} marker says `trolley {other}`" if other else f"no {MARKER_NAME} marker"
        raise OutputError(f"{option} {out}: exists and was not made by `trolley {command}` ({made}); an existing "
                          "session, recording or other folder is never replaced, choose another folder")


def remove_own_folder(out: Path, command: str) -> None:
    """Delete ``out`` if (and only if) it carries ``command``'s marker."""
    if made_by(out, command):
        shutil.rmtree(out)
