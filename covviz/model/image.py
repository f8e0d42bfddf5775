"""Frame and box helpers every layer above uses: the grey frame the descriptor reads, the initial box check."""

from __future__ import annotations

import cv2
import numpy as np

from covviz.errors import InputError

__all__ = ["MAX_BOX_FRAMES", "MIN_FRAME_SIDE", "check_init_box", "to_gray"]


def to_gray(frame: np.ndarray) -> np.ndarray:
    """``uint8`` RGB or gray frame -> float32 gray in ``[0, 1]``, shape ``(H, W)``."""
    frame = np.asarray(frame)
    if frame.ndim == 3:
        if frame.shape[2] != 3:
            raise ValueError(f"colour frames must have 3 channels, got shape {frame.shape}")
        # ITU-R BT.601 luma; cv2.cvtColor is ~3x faster than the same sum in numpy.
        g = cv2.cvtColor(frame.astype(np.float32), cv2.COLOR_RGB2GRAY)
    elif frame.ndim == 2:
        g = frame.astype(np.float32)
    else:
        raise ValueError(f"a frame must have shape (H, W) or (H, W, 3), got {frame.shape}")
    if frame.dtype == np.uint8:
        g *= np.float32(1.0 / 255.0)
    return g


def check_init_box(box, frame_shape) -> np.ndarray:
    """Validate an initial box against a frame; return it as float64 ``(4,)``.

    Raises
    ------
    covviz.errors.InputError
        (a ``ValueError``) If the frame is smaller than :data:`MIN_FRAME_SIDE`
        on a side, the box is not 4 finite numbers, has zero or
        negative size, lies entirely outside the frame or is more than
        :data:`MAX_BOX_FRAMES` times its size.
    """
    b = np.asarray(box, dtype=np.float64).reshape(-1)
    if b.shape != (4,) or not np.all(np.isfinite(b)):
        raise InputError(f"the initial box must be 4 finite numbers x,y,w,h; got {box!r}")
    x, y, w, h = b
    if w <= 0 or h <= 0:
        raise InputError(f"the initial box has zero or negative size (w={w:g}, h={h:g})")
    H, W = frame_shape[:2]
    if H < MIN_FRAME_SIDE or W < MIN_FRAME_SIDE:
        raise InputError(
            f"the frames are {W}x{H} pixels; tracking needs frames of at least {MIN_FRAME_SIDE}x{MIN_FRAME_SIDE} "
            "(the region warp interpolates between pixels): check that these are the sequence's frames"
        )
    if x >= W or y >= H or x + w <= 0 or y + h <= 0:
        raise InputError(
            f"the initial box {x:g},{y:g},{w:g},{h:g} lies outside the {W}x{H} frame"
        )
    if w > MAX_BOX_FRAMES * W or h > MAX_BOX_FRAMES * H:
        raise InputError(
            f"the initial box {x:g},{y:g},{w:g},{h:g} is more than {MAX_BOX_FRAMES:g} times the size of the "
            f"{W}x{H} frame; give the box around the target"
        )
    return b


#: An initial box may be at most this many times the frame's width and height (a target partly
#: outside the frame is fine; a box of 1e308 pixels overflows the warp).
MAX_BOX_FRAMES = 2.0

#: Frames must be at least this many pixels on each side (the warp's bilinear interpolation needs 2).
MIN_FRAME_SIDE = 2
