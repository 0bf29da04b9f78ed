"""Reading the small JSON files users hand over (cameras, transfer functions)."""

from __future__ import annotations

import json
from pathlib import Path

from .errors import ExabricksError

# A camera or colour-map preset is a few kilobytes; anything far larger is not one.
MAX_JSON_BYTES = 16 << 20


def read_json(path, what: str, max_bytes: int = MAX_JSON_BYTES, **loads_options):
    """The parsed JSON of file `path`, or one ExabricksError naming the file and
    `what` it should be ("camera file", "transfer function") for a missing,
    oversized, undecodable, malformed or absurdly nested file."""
    p = Path(path)
    try:
        size = p.stat().st_size
        if size > max_bytes:
            raise ExabricksError(f"{path}: {what} of {size:,} bytes is too large "
                                 f"(at most {max_bytes:,})")
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise ExabricksError(f"{path}: cannot read {what}: {getattr(e, 'strerror', None) or e}") from None
    try:
        return json.loads(text, **loads_options)
    except json.JSONDecodeError as e:
        raise ExabricksError(f"{path}: {what} is not valid JSON: {e.msg} (line {e.lineno})") from None
    except RecursionError:
        raise ExabricksError(f"{path}: {what} is nested too deeply to be one") from None
    except ValueError as e:  # a parse_constant hook refusing NaN/Infinity
        raise ExabricksError(f"{path}: {what} is not valid JSON: {e}") from None
