"""Add the ``colour`` signal to bench results made before it existed, from their saved boxes.

``colour`` (:class:`covviz.diagnosis.signals.ColourSignal`) is a function of the frames and the
tracker's boxes alone, so it can be computed after the run, from the ``.txt`` boxes beside each result
(two decimals: where a box edge sits within 0.005 px of a half pixel, the rounded edge may differ by one
pixel from the run's own). Every other signal is left as it is; each result gains
``diagnosis.backfilled = {"colour": "scripts/backfill_colour.py"}``, so a reader can tell. Results that
already carry the signal are kept unless ``force``. Without ground truth nothing changes: the signal
never reads it.

The command line is ``scripts/backfill_colour.py``.
"""

from __future__ import annotations

import json
from pathlib import Path

from covviz.data.sequences import open_sequence
from covviz.diagnosis.signals import ColourSignal, saved_value
from covviz.experiments.results import ResultError, _atomic_write, load_result

__all__ = ["backfill_colour"]


def backfill_colour(bench: Path, root: Path, force: bool = False, progress: bool = False) -> tuple[int, int]:
    """Results updated and kept, over every sequence folder of ``bench``."""
    bench, root = Path(bench), Path(root)
    done = kept = 0
    for sd in sorted(p for p in bench.iterdir() if p.is_dir()):
        todo = []
        for js in sorted(sd.glob("*.json")):
            try:
                doc, boxes = load_result(js)
            except ResultError:
                continue  # not a result (the manifest), or one without its boxes: nothing to score
            sig = (doc.get("diagnosis") or {}).get("signals")
            if not isinstance(sig, dict):
                continue
            if "colour" in sig and not force:
                kept += 1
                continue
            todo.append((js, doc, boxes))
        if not todo:
            continue
        seq = open_sequence(root / sd.name)
        n = max(len(b) for _, _, b in todo)
        sigs = [ColourSignal() for _ in todo]
        vals = [[] for _ in todo]
        for i in range(n):
            image = seq.frame(i).image
            for k, (_, _, boxes) in enumerate(todo):
                if i < len(boxes):
                    vals[k].append(sigs[k].step(image, boxes[i]))
        for (js, doc, _), v in zip(todo, vals):
            dg = doc["diagnosis"]
            dg["signals"]["colour"] = [saved_value(x) for x in v]
            dg["backfilled"] = {**(dg.get("backfilled") or {}), "colour": "scripts/backfill_colour.py"}
            _atomic_write(js, json.dumps(doc, indent=1, allow_nan=True))
            done += 1
        if progress:
            print(f"{sd.name}: {len(todo)} result(s)", flush=True)
    return done, kept
