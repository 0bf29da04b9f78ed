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


# The most characters of a user's value that a message quotes: a 10 MB key of a
# scene file was once echoed whole in a 10 MB error line.
QUOTED_MOST = 80


def shortened(text: str, most: int = QUOTED_MOST) -> str:
    """`text` cut to at most `most` characters, ending in '...' where it was cut."""
    return text if len(text) <= most else text[: max(most - 3, 0)] + "..."


def quoted(value, most: int = QUOTED_MOST) -> str:
    """A user's `value` as a message quotes it: its repr (a string in quotes), a
    long string cut after `most` characters (`'aaa...'...`), anything else's repr
    shortened; the one helper for quoting user input in messages."""
    if isinstance(value, str):
        return repr(value) if len(value) <= most else repr(value[:most]) + "..."
    return shortened(repr(value), most)
