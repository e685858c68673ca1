"""Process-wide settings for a fedtrack process, applied by the CLI before numpy is imported.

* One BLAS thread (``OPENBLAS_NUM_THREADS``, ``OMP_NUM_THREADS``; an explicit setting in the
  environment wins). fedtrack runs one process per role and its matrices are small: BLAS threads
  only contend with the other processes for the cores (a 10,000-target batched Kalman step
  took 1.8 ms in a 40,000 x 4 product with two threads, 0.4 ms with one).
* glibc's malloc keeps freed memory instead of returning it to the system after every large
  array (``mallopt`` ``M_TRIM_THRESHOLD`` and ``M_MMAP_THRESHOLD``): a batched step allocates and
  frees arrays of about a megabyte, and faulting their pages in again cost more than the
  arithmetic (10,000-target Kalman steps: 0.99 M -> 1.24 M target-steps/s). The process keeps
  its peak heap, which the services' RSS figures already bound.
"""

from __future__ import annotations

import ctypes
import os

BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
TRIM_THRESHOLD_BYTES = 128 * 1024 * 1024
MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024  # glibc's largest dynamic threshold; larger arrays are mapped


def tune_process() -> None:
    """Set one BLAS thread (unless the environment says otherwise) and glibc's malloc thresholds."""
    for name in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(name, "1")
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the C library already loaded (no ldconfig lookup)
    except (OSError, AttributeError):  # not glibc: nothing to tune
        return
    mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)
    mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
