"""The errors of reading and writing bags; each message says what was wrong and what to do."""


class BagError(Exception):
    """A bag that cannot be written or read; the message says what was wrong and what to do."""


class BagWriteError(BagError):
    """Writing a bag failed (disk full, I/O error) and the writer stopped. The bag holds what
    was written before; the message says what happened, what the bag holds and what to do."""
