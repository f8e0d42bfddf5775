"""Thread limits of the native libraries (BLAS, OpenCV), scoped to a ``with`` block.

The tracker works on stacks of 9×9 matrices and small patches, where BLAS and
OpenCV threads only add wake-up latency and contend with the tracker's own
observation threads; a tracking run, a bench worker and the recorder therefore
run with one native thread each. :func:`limit_threads` sets the limit for a
block and restores the previous one after it, so nothing stays set for the
rest of the process.
"""

from __future__ import annotations

import contextlib
import functools
import sys

__all__ = ["limit_threads"]


@functools.lru_cache(maxsize=1)
def _controller(n_modules: int):
    """The threadpoolctl controller, or None without it.

    Inspecting the loaded libraries costs ~3 ms, so the controller is kept until
    more modules are imported (``n_modules``: the size of ``sys.modules``; a new
    BLAS comes with a new extension module).
    """
    try:
        from threadpoolctl import ThreadpoolController

        return ThreadpoolController()
    except Exception:  # noqa: BLE001 - threadpoolctl missing or unable to inspect the libraries
        return None


@contextlib.contextmanager
def limit_threads(n: int | None = 1, blas: bool = True, opencv: bool = True):
    """Limit BLAS (threadpoolctl) and OpenCV to ``n`` threads inside the block.

    Parameters
    ----------
    n : int or None
        Threads per library; ``None`` leaves the limits as they are.
    blas : bool
        Limit the BLAS libraries (OpenBLAS, MKL, …) loaded so far.
    opencv : bool
        Limit OpenCV (``cv2.setNumThreads``).

    Notes
    -----
    Both limits are process-wide while they hold (that is how the libraries
    work), so they also apply to other threads of the process.
    """
    with contextlib.ExitStack() as stack:
        if n is not None and blas:
            ctl = _controller(len(sys.modules))
            if ctl is not None:
                stack.enter_context(ctl.limit(limits=int(n), user_api="blas"))
        if n is not None and opencv:
            import cv2

            before = cv2.getNumThreads()
            cv2.setNumThreads(int(n))
            stack.callback(cv2.setNumThreads, before)
        yield
