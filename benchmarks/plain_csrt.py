"""The baseline a user writes without covviz: OpenCV's CSRT over an OTB folder, frames read with cv2.imread.

Nothing else: no covviz import, OpenCV's own thread settings, no results
written. Reads ``img/*.jpg`` (and the other image files) in name order and the
first box of ``groundtruth_rect.txt`` (1-based ``x,y,w,h``, separated by commas,
tabs or spaces), tracks the first ``--max-frames`` frames (the first one is
where the box is given, as with ``covviz track --max-frames``) and prints one
line: the frames and the seconds of the loop (reading, decoding and tracking).
``benchmarks/speed.py --plain-csrt`` times this script's whole process against
``covviz track``'s.

Usage::

    python benchmarks/plain_csrt.py ../shared/sequences/Car4 --max-frames 200
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from pathlib import Path

import cv2

IMAGES = (".jpg", ".jpeg", ".png", ".bmp")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sequence", help="OTB folder: img/0001.jpg ... and groundtruth_rect.txt")
    ap.add_argument("--max-frames", type=int, default=None, help="stop after this many frames (with the first)")
    args = ap.parse_args(argv)
    folder = Path(args.sequence)
    files = sorted(p for p in (folder / "img").iterdir() if p.suffix.lower() in IMAGES)[: args.max_frames]
    first_line = next(iter((folder / "groundtruth_rect.txt").read_text().splitlines()), "")
    x, y, w, h = (float(v) for v in re.split(r"[,\s]+", first_line.strip())[:4])
    if len(files) < 2:
        print(f"{folder}: fewer than 2 frames", file=sys.stderr)
        return 2

    t0 = time.perf_counter()
    tracker = cv2.TrackerCSRT.create()
    tracker.init(cv2.imread(str(files[0])), (round(x - 1), round(y - 1), round(w), round(h)))
    boxes = []
    for p in files[1:]:
        _ok, box = tracker.update(cv2.imread(str(p)))
        boxes.append(box)
    loop = time.perf_counter() - t0
    print(f"plain CSRT: {len(files)} frames, loop {loop:.3f} s ({len(boxes) / loop:.1f} updates/s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
