"""The one exception type that stages raise; the CLI maps it to `error: ...` and exit 1."""


class ExabricksError(Exception):
    """Bad input data or a failed run; the message names the file and the problem."""


def one_line(message: str) -> str:
    """`message` with control characters (a newline in a file name) escaped, so that
    an error stays one line."""
    return "".join(c if c.isprintable() or c == " " else repr(c)[1:-1] for c in message)
