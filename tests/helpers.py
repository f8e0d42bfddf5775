"""Helpers the test modules share (a module of its own: no test module imports another)."""

from __future__ import annotations

from pathlib import Path

import cv2
import pytest

from covviz.data.sequences import SyntheticConfig, SyntheticSequence, write_boxes

#: The real sequences beside the checkout (``../shared/sequences``); tests that need them skip without.
SHARED_SEQUENCES = Path(__file__).resolve().parents[2] / "shared" / "sequences"


def real_sequence(name: str) -> Path:
    """The folder of a real sequence, or skip the test when it is not there."""
    folder = SHARED_SEQUENCES / name
    if not folder.is_dir():
        pytest.skip(f"real sequence {name} not available at {folder}")
    return folder


def write_otb(folder: Path, n_frames: int, seed: int) -> None:
    """A small synthetic sequence written as an OTB folder (img/0001.png…, groundtruth_rect.txt)."""
    seq = SyntheticSequence(
        SyntheticConfig(n_frames=n_frames, width=160, height=120, target_w=24, target_h=30, seed=seed)
    )
    (folder / "img").mkdir(parents=True)
    for i in range(n_frames):
        cv2.imwrite(
            str(folder / "img" / f"{i + 1:04d}.png"), cv2.cvtColor(seq.frame(i).image, cv2.COLOR_RGB2BGR)
        )
    write_boxes(folder / "groundtruth_rect.txt", seq.groundtruth)


def _proc_table() -> dict[int, tuple[int, str]]:
    """pid -> (parent pid, command line) of every process."""
    out = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except (OSError, IndexError, ValueError):
            continue
        out[int(d.name)] = (ppid, cmd)
    return out


def descendants(pid: int) -> dict[int, str]:
    """Every process below ``pid`` (read from /proc), pid -> command line."""
    table = _proc_table()
    found, frontier = {}, [pid]
    while frontier:
        p = frontier.pop()
        for c, (pp, cmd) in table.items():
            if pp == p and c not in found:
                found[c] = cmd
                frontier.append(c)
    return found
