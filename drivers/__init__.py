"""Serial device drivers and their simulated twins (no imports from ``survey``)."""
