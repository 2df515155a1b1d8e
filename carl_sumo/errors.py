"""Errors that the command line reports as one clear line with exit status 2."""


class InputError(Exception):
    """Bad user input: a missing or malformed file, a wrong option, an impossible scenario.

    The message says what is wrong and what to do; the CLI prints it on one line and exits 2.
    """


class OutputError(InputError):
    """An output could not be written whole (a full disk, a read-only or failing file system, a
    SUMO output that is incomplete): nothing was moved into place, no temporary file is left, and
    the CLI prints one line and exits 2, as for bad input."""
