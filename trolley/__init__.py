"""Science of the track-survey trolley: pure numpy/scipy, no I/O.

Submodules hold one idea each (see ``docs/glossary.md``); nothing here imports from
``drivers`` or ``survey``.
"""
