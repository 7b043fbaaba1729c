"""One module per top-level command group of the ``trolley`` CLI.

Each module exposes ``register(app: typer.Typer) -> None``; heavy imports (control, filterpy,
scipy.signal, matplotlib) happen inside the command functions, not at module import, so that
``trolley --help`` stays fast.
"""
