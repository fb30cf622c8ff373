"""One progress reporter for every long job: a line in the log at every tenth of the work."""

from __future__ import annotations

import logging
from collections.abc import Callable


def progress_logger(label: str, logger: logging.Logger | None = None, every: float = 0.1) -> Callable[[float], None]:
    """progress(fraction done, 0..1) that logs "<label>: NN%" each time another `every` is done,
    so a long job shows in its log that it is alive."""
    logger = logger or logging.getLogger("progress")
    state = {"next": every}

    def report(fraction: float) -> None:
        if fraction >= state["next"] - 1e-9:
            logger.info("%s: %3.0f%%", label, 100 * fraction)
            state["next"] = (int(fraction / every + 1e-9) + 1) * every

    return report
