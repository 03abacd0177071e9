"""The one exception a user of the simulator can cause: a scenario that cannot be simulated."""


class SimulationError(ValueError):
    """A bad scenario (unknown track, malformed fault, negative duration, ...); the message says what to do."""
