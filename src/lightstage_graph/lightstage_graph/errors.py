"""What can go wrong between a node and the stage (driver + camera)."""


class StageError(RuntimeError):
    """The stage did not deliver (driver or camera missing, refusing, silent); the message says
    why and what to do."""


class MissingImagesError(StageError):
    """Some images of a trigger sequence did not arrive in time (or arrived unusable)."""

    def __init__(self, message: str, missing: list[int]):
        super().__init__(message)
        self.missing = missing
