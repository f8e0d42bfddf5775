"""The records every sequence yields and the interface they share (no file formats here).

:class:`Frame` is one frame (0-based index, RGB pixels, ground truth, time);
:class:`Sequence` a named, indexable, lazily read list of them;
:class:`SequenceError` the one-line "cannot read this sequence" error. The
sources — OTB/VOT folders, videos (:mod:`covviz.data.sequences`) and the synthetic
generator (:mod:`covviz.data.synthetic`) — build on these.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from covviz.errors import InputError

__all__ = ["Frame", "Sequence", "SequenceError"]


class SequenceError(InputError):
    """A sequence cannot be read; the message says what to fix."""


@dataclass(frozen=True, slots=True)
class Frame:
    """One frame of a sequence.

    Attributes
    ----------
    index : int
        0-based position in the sequence.
    image : ndarray, shape (H, W, 3), uint8
        RGB pixels.
    gt : ndarray, shape (4,), optional
        Ground-truth box ``x, y, w, h`` (0-based pixels), or None if unknown.
    time : float, optional
        Seconds since the first frame, when the sequence has a frame rate.
    """

    index: int
    image: np.ndarray
    gt: np.ndarray | None = None
    time: float | None = None


class Sequence:
    """Base class: a named, indexable, lazily read list of frames.

    Subclasses set ``name``, ``groundtruth`` (``(n, 4)``, ``nan`` rows where
    unknown), ``frame_rate`` (or None) and implement :meth:`_read`.
    """

    name: str = "sequence"
    frame_rate: float | None = None
    groundtruth: np.ndarray

    def __len__(self) -> int:
        return len(self.groundtruth)

    def _read(self, i: int) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def init_box(self) -> np.ndarray:
        """The box to initialise a tracker with (ground truth of frame 0)."""
        b = self.groundtruth[0]
        if not np.all(np.isfinite(b)):
            raise SequenceError(f"{self.name}: the first frame has no ground-truth box; pass --box x,y,w,h")
        return b.copy()

    def check_frames(self, n_frames: int) -> None:
        """Raise :class:`SequenceError` if the first ``n_frames`` frames cannot all be matched to their rows."""

    def frame(self, i: int) -> Frame:
        """Read frame ``i`` (0-based)."""
        if not 0 <= i < len(self):
            raise IndexError(f"frame {i} out of range for {self.name} ({len(self)} frames)")
        gt = self.groundtruth[i]
        return Frame(
            index=i,
            image=self._read(i),
            gt=gt.copy() if np.all(np.isfinite(gt)) else None,
            time=None if not self.frame_rate else i / self.frame_rate,
        )

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self.frame(i)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r}, {len(self)} frames)"
