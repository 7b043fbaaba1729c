"""The one JSON writer for every command's machine output (``--json``).

The text is always valid JSON (RFC 8259, which has no NaN or Infinity): non-finite floats become
``null``; numpy scalars and arrays become numbers and lists; paths become strings; dataclasses
and enums become their fields and values. Any other object is a programming error and raises
``TypeError`` rather than being printed as something a reader cannot parse.
"""
from __future__ import annotations

import dataclasses
import enum
import json
import math
from pathlib import PurePath
from typing import Any

import typer


def jsonable(x: Any) -> Any:
    """``x`` as plain JSON types, with every non-finite float replaced by None.

    Parameters
    ----------
    x : dicts (keys made strings), lists, tuples, sets, numbers (Python or numpy), strings,
        None, booleans, paths, enums, dataclass instances and numpy arrays, nested freely.

    Returns
    -------
    The same structure made of dict, list, str, int, float (finite), bool and None.

    Raises
    ------
    TypeError for any other type.
    """
    if x is None or isinstance(x, (bool, str)):
        return x
    if isinstance(x, enum.Enum):
        return jsonable(x.value)
    if isinstance(x, int):
        return int(x)
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, set, frozenset)):
        return [jsonable(v) for v in x]
    if isinstance(x, PurePath):
        return str(x)
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return jsonable({f.name: getattr(x, f.name) for f in dataclasses.fields(x)})
    tolist = getattr(x, "tolist", None)  # numpy scalars and arrays, without importing numpy
    if callable(tolist):
        return jsonable(tolist())
    raise TypeError(f"cannot write a {type(x).__name__} as JSON: {x!r}")


def dumps(x: Any, indent: int | None = None) -> str:
    """Valid JSON text of ``x`` (see :func:`jsonable`)."""
    return json.dumps(jsonable(x), indent=indent, allow_nan=False, ensure_ascii=False)


def echo(x: Any, indent: int | None = None) -> None:
    """Print ``x`` as one JSON document on stdout."""
    typer.echo(dumps(x, indent))
