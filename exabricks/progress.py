"""Progress bars that show on a terminal and stay quiet in batch logs and with -q."""

from __future__ import annotations

import os
import sys

from tqdm import tqdm


def enabled() -> bool:
    return sys.stderr.isatty() and os.environ.get("EXABRICKS_QUIET", "") in ("", "0")


def bar(total=None, desc: str = "", unit: str = "it", disable: bool = False, **kw) -> tqdm:
    """A tqdm bar on stderr, disabled off a terminal, under -q, or by `disable`."""
    return tqdm(total=total, desc=desc, unit=unit, disable=disable or not enabled(),
                file=sys.stderr, leave=False, dynamic_ncols=True, **kw)
