"""The one base class for bad user input: the CLI prints its message and exits with status 2."""


class InputError(ValueError):
    """Bad input (scene key, value, file, setup); the message names it and what is allowed."""
