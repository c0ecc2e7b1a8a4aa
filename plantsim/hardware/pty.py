"""What the emulators' pseudo-terminals share."""

from __future__ import annotations

import os


def close_fds(*fds: int | None) -> None:
    """Closes file descriptors, skipping None and any the other side already closed."""
    for fd in fds:
        if fd is not None:
            try:
                os.close(fd)
            except OSError:
                pass
