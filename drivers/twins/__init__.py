"""Simulated twins: each device's protocol spoken on the master side of a pseudo-terminal."""
from drivers.twins.base import Faults, FaultInjector, PtyTwin

__all__ = ["Faults", "FaultInjector", "PtyTwin"]
