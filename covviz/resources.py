"""What a run needs from the machine, estimated before it starts: memory.

The estimate is an upper bound calibrated on peak RSS (``ru_maxrss`` of
``covviz track``, manifold and ipca, 2-core Linux box, numpy 2, rerun 0.41):

====================================  ===========  ================
run                                   no recording  with a recording
====================================  ===========  ================
600 particles, 360×240 frames          112 MB       219 MB
600 particles, 1440×960 frames         147 MB       301 MB
manifold, 16 000 particles             271 MB       397 MB
ipca, 16 000 particles                 284 MB       424 MB
manifold, 64 000 particles             762 MB       –
====================================  ===========  ================

so about 10–12 KB a particle (the particle set, its warped patches and
features are processed in blocks), 8–9 KB more with a recording (the records
queued for the logger thread), 8–10 frames' worth of pixels (20 with a
recording), and ~110 MB for Python, numpy and OpenCV (~220 MB with Rerun).
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["available_memory", "run_memory"]

#: Python, numpy, OpenCV (and Rerun, with a recording), bytes.
BASE_BYTES = 150_000_000
BASE_BYTES_RECORDING = 260_000_000
#: Per particle and particle tracker, bytes (measured ≤ 12.3 KB; 21 KB with a recording).
PARTICLE_BYTES = 13_000
PARTICLE_BYTES_RECORDING = 22_000
#: Frames' worth of RGB pixels held at once (measured ~9; ~20 with a recording).
FRAMES_HELD = 12
FRAMES_HELD_RECORDING = 28


def run_memory(n_particles: int, frame_shape, n_trackers: int = 1, recording: bool = False) -> int:
    """Upper estimate of the peak memory of a run, in bytes.

    Parameters
    ----------
    n_particles : int
        Particles of each particle tracker.
    frame_shape : tuple
        ``(H, W[, C])`` of the frames.
    n_trackers : int
        Particle trackers in the run (each holds its own particles).
    recording : bool
        Whether the run is recorded (Rerun).
    """
    h, w = int(frame_shape[0]), int(frame_shape[1])
    frame = h * w * 3
    if recording:
        return int(BASE_BYTES_RECORDING + FRAMES_HELD_RECORDING * frame
                   + n_trackers * n_particles * PARTICLE_BYTES_RECORDING)
    return int(BASE_BYTES + FRAMES_HELD * frame + n_trackers * n_particles * PARTICLE_BYTES)


def available_memory(meminfo: str | Path = "/proc/meminfo", cgroup: str | Path = "/sys/fs/cgroup") -> int | None:
    """Bytes a run can allocate without swapping, or None where it is not known.

    ``MemAvailable`` of ``/proc/meminfo``, or less if the process's cgroup (v2
    ``memory.max``, v1 ``memory/memory.limit_in_bytes``) leaves less.
    """
    avail = None
    try:
        for line in Path(meminfo).read_text().splitlines():
            if line.startswith("MemAvailable:"):
                avail = int(line.split()[1]) * 1024
                break
    except (OSError, ValueError, IndexError):
        return None
    cg = Path(cgroup)
    for limit_file, usage_file in (("memory.max", "memory.current"),
                                   ("memory/memory.limit_in_bytes", "memory/memory.usage_in_bytes")):
        try:
            limit = (cg / limit_file).read_text().strip()
            usage = int((cg / usage_file).read_text().strip())
        except (OSError, ValueError):
            continue
        if limit.isdigit() and int(limit) < 1 << 60:
            left = max(0, int(limit) - usage)
            avail = left if avail is None else min(avail, left)
        break
    return avail
