"""The one exception type that stages raise; the CLI maps it to `error: ...` and exit 1."""


class ExabricksError(Exception):
    """Bad input data or a failed run; the message names the file and the problem."""
