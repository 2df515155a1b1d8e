"""Errors that the command line reports as one clear line with exit status 2."""


class InputError(Exception):
    """Bad user input: a missing or malformed file, a wrong option, an impossible scenario.

    The message says what is wrong and what to do; the CLI prints it on one line and exits 2.
    """
