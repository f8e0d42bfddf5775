"""What a run needs from the machine, estimated before it starts: memory.

The estimate is an upper bound calibrated on peak RSS (``ru_maxrss`` of
``covviz track``, 2-core Linux box, numpy 2, numba kernels loaded, rerun 0.41):

=======================================  ===========  ================
run (Car4, 360×240, 300 frames)          no recording  with a recording
=======================================  ===========  ================
manifold, 600 particles                  238 MB       457 MB
manifold, 4000 particles                 283 MB       623 MB
manifold, 600 particles, 659 frames      231 MB       482 MB
=======================================  ===========  ================

so about 13 KB a particle (the particle set, its warped patches and
features are processed in blocks), 49 KB with a recording (the records
queued for the logger thread, the particles' regions and weights it draws),
~230 MB for Python, numpy, OpenCV and the kernels (~420 MB with Rerun and the
recorder's views), and, recorded, what Rerun's encoder holds as the recording
grows (see :data:`RECORDING_BYTES_PER_FRAME`).
"""

from __future__ import annotations

from pathlib import Path

from covviz.data.prefetch import AHEAD

__all__ = ["available_memory", "run_memory"]

#: Python, numpy, OpenCV, the compiled kernels (and Rerun, with a recording), bytes (measured 227 / 420 MB).
BASE_BYTES = 245_000_000
BASE_BYTES_RECORDING = 450_000_000
#: Per particle and particle tracker, bytes (measured 13.2 KB; 48.8 KB with a recording).
PARTICLE_BYTES = 15_000
PARTICLE_BYTES_RECORDING = 55_000
#: Frames' worth of RGB pixels held at once (measured ~9; ~20 with a recording, before the frames were
#: read ahead), and those read ahead (:mod:`covviz.data.prefetch`: ``AHEAD`` queued, one being read).
FRAMES_HELD = 12 + AHEAD + 1
FRAMES_HELD_RECORDING = 28 + AHEAD + 1
#: Resident memory a recorded run gains per frame after warm-up (Rerun's native side), bytes.
RECORDING_BYTES_PER_FRAME = 20_000


def run_memory(n_particles: int, frame_shape, n_trackers: int = 1, recording: bool = False,
               n_frames: int = 0) -> int:
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
    n_frames : int
        Frames to track (a recorded run grows with them).
    """
    h, w = int(frame_shape[0]), int(frame_shape[1])
    frame = h * w * 3
    if recording:
        return int(BASE_BYTES_RECORDING + FRAMES_HELD_RECORDING * frame
                   + n_trackers * n_particles * PARTICLE_BYTES_RECORDING + n_frames * RECORDING_BYTES_PER_FRAME)
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
