"""Keep freed memory in the process's heap, so a GNS step does not fault its activations in anew.

glibc's malloc serves a block over its mmap threshold (128 KB, raised on the fly up to 32 MB) with
fresh pages from the kernel and gives them back when the block is freed, and it trims the top of the
heap past twice that threshold. A GNS step allocates and frees dozens of [E, latent] tensors (~2 MB
each for the model's two 589-grain graphs), so each one was page-faulted in again, zeroed by the
kernel first: ~6,000 faults per forward pass, about 45% of a no-gradient forward's time on this
project's 2-core machines (docs/experiments/gns-training.md). Raising both thresholds keeps the
freed blocks for the next step; the process then holds its peak heap until it ends.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging

log = logging.getLogger(__name__)

# mallopt parameters, glibc's <malloc.h>
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024  # glibc's upper bound for it on 64-bit
TRIM_THRESHOLD_BYTES = 1024 * 1024 * 1024

_done: bool | None = None


def keep_freed_memory() -> bool:
    """Set glibc's mmap and trim thresholds (once per process); True when they are set, False where
    the C library is not glibc (its allocator is left as it is)."""
    global _done
    if _done is None:
        _done = False
        name = ctypes.util.find_library("c")
        try:
            libc = ctypes.CDLL(name) if name else None
            mallopt = libc.mallopt if libc is not None else None
        except (OSError, AttributeError):
            mallopt = None
        if mallopt is not None:
            mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
            _done = bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(
                mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)
            )
        if not _done:
            log.info("malloc thresholds left as they are (no glibc mallopt)")
    return _done
