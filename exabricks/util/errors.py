"""The one exception type that stages raise; the CLI maps it to `error: ...` and exit 1."""


class ExabricksError(Exception):
    """Bad input data or a failed run; the message names the file and the problem."""


class UsageError(ExabricksError):
    """Options that contradict each other: the CLI reports it as click reports its
    own usage errors, with exit status 2."""


def one_line(message: str) -> str:
    """`message` with control characters (a newline in a file name) escaped, so that
    an error stays one line."""
    return "".join(c if c.isprintable() or c == " " else repr(c)[1:-1] for c in message)
