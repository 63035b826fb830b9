"""Exceptions the engine raises."""


class SceneError(ValueError):
    """A scene description is malformed; the message names the item at fault."""


class SimulationError(FloatingPointError):
    """A world's state turned non-finite; the message names world, body and step."""

    def __init__(self, message: str, worlds=(), bodies=(), step=None):
        super().__init__(message)
        self.worlds = tuple(worlds)
        self.bodies = tuple(bodies)
        self.step = step
