"""Thread control in one place.

On small problems (hundreds of points, 5-d embeddings) one BLAS/OpenMP thread is much faster than
two on the 2-core machines we target: sklearn K-means was measured 30-50x slower with 2 threads.
Nothing here runs at import; callers (the CLI, benchmarks, tests) opt in.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator


def set_threads(num_threads: int = 1) -> None:
    """Set torch, OpenCV and BLAS/OpenMP thread counts for this process.

    Args:
        num_threads: threads for intra-op parallelism; 1 is fastest for per-clip work here.
    """
    import cv2
    import torch
    from threadpoolctl import threadpool_limits

    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, str(num_threads))
    torch.set_num_threads(num_threads)
    cv2.setNumThreads(num_threads)
    threadpool_limits(num_threads)


_active_limit: list[int | None] = [None]  # the limit of the innermost limited_threads block


@contextlib.contextmanager
def limited_threads(num_threads: int = 1) -> Iterator[None]:
    """Context manager limiting the BLAS/OpenMP pools (used around scikit-learn calls).

    Entering threadpoolctl's limit costs ~4-12 ms (it scans the loaded libraries), more than a small
    K-means fit, so a block nested inside one with the same limit enters nothing.

    Args:
        num_threads: threads the pools may use inside the block.
    """
    if _active_limit[0] == num_threads:
        yield
        return
    from threadpoolctl import threadpool_limits

    previous = _active_limit[0]
    with threadpool_limits(num_threads):
        _active_limit[0] = num_threads
        try:
            yield
        finally:
            _active_limit[0] = previous
