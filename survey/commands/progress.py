"""One progress bar for every step of the CLI that takes longer than about 2 s.

``process``, ``export``, ``tgms process`` and the ``budget`` Monte Carlo report their progress
through a callable ``report(step, fraction)`` (the convention of
:func:`trolley.engine.process_session`): the step under way and the fraction of the whole run
done, 0..1. The bar goes to stderr and disappears when the step ends, so stdout keeps only the
result (a table or ``--json``).
"""
from __future__ import annotations

from contextlib import contextmanager
from typing import Callable, Iterator

Report = Callable[[str, float], None]


@contextmanager
def progress_bar(first_step: str, console=None) -> Iterator[Report]:
    """A transient rich progress bar on stderr.

    Parameters
    ----------
    first_step : description shown until the first report.
    console : rich Console to draw on (default: a new one on stderr).

    Yields
    ------
    report(step, fraction): set the description and the fraction done (clipped to 0..1).
    """
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TaskProgressColumn, TextColumn, TimeElapsedColumn

    con = console if console is not None else Console(stderr=True)
    # no bar where nobody watches (stderr a file or a pipe): rich draws none there anyway, but
    # printed an empty line when it stopped, above the one line of an error
    with Progress(TextColumn("{task.description:<48}"), BarColumn(), TaskProgressColumn(), TimeElapsedColumn(),
                  console=con, transient=True, disable=not con.is_interactive) as prog:
        task = prog.add_task(first_step, total=1.0)

        def report(step: str, fraction: float) -> None:
            prog.update(task, completed=min(max(float(fraction), 0.0), 1.0), description=step)

        yield report


def share(report: Report | None, start: float, end: float) -> Report | None:
    """``report`` for a sub-step that covers the fractions ``start`` .. ``end`` of the whole run.

    Returns None when ``report`` is None, so callers pass it on unchanged.
    """
    if report is None:
        return None

    def sub(step: str, fraction: float) -> None:
        report(step, start + (end - start) * fraction)

    return sub
