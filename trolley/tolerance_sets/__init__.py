"""Built-in tolerance sets (TOML data, format ``trolley-tolerances/1``; see docs/track_geometry.md).

Read them with ``survey.tolerance_files.load_tolerances(NAME)``; the name is the file stem.
"""
