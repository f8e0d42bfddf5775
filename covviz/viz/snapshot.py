"""``covviz snapshot RECORDING --frame N --out shot.png``: a PNG of the real viewer, without a display.

Starts the Rerun viewer headless (``rerun --headless --window-size WxH``, which
renders in software through Vulkan: ``apt-get install mesa-vulkan-drivers
libvulkan1``), drives it with :class:`rerun.experimental.ViewerClient` — open
the recording, go to the frame, pause, save a screenshot — and stops it. The
recording's own blueprint decides the layout.

What works here (rerun 0.41, checked): ``ViewerClient.spawn`` has no window
size, so the viewer is started as a subprocess of ours on a free port and the
client connects to it; ``rerun --headless --screenshot-to`` alone cannot
choose a frame (it shows the last one) and shows the start-up notifications.
"""

from __future__ import annotations

import errno
import glob
import logging
import os
import shutil
import signal
import socket
import subprocess
import time
from pathlib import Path

from covviz.errors import InputError, free_space
from covviz.viz.readback import read_layout
from covviz.viz.viewer import find_viewer

log = logging.getLogger("covviz")

__all__ = [
    "SnapshotError",
    "contact_sheet",
    "find_viewer",
    "focus_blueprint",
    "parse_size",
    "snapshot",
    "snapshot_frames",
    "tracker_names",
    "vulkan_available",
]

#: Where Vulkan loaders look for installable client drivers (ICDs).
VULKAN_ICD_DIRS = ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d")


class SnapshotError(RuntimeError):
    """The headless viewer could not produce the screenshot; the message says what to fix."""


def parse_size(text: str) -> tuple[int, int]:
    """``"1600x900"`` -> ``(1600, 900)``; :class:`~covviz.errors.InputError` otherwise."""
    try:
        w, h = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise InputError(f"--size must look like 1600x900, got {text!r}") from None
    if not (200 <= w <= 8000 and 200 <= h <= 8000):
        raise InputError(f"--size must be between 200x200 and 8000x8000, got {text!r}")
    return w, h


def vulkan_available() -> bool:
    """Whether a Vulkan driver is installed (the headless viewer needs one, e.g. Mesa's lavapipe)."""
    if os.environ.get("VK_ICD_FILENAMES") or os.environ.get("VK_DRIVER_FILES"):
        return True
    return any(glob.glob(os.path.join(d, "*.json")) for d in VULKAN_ICD_DIRS)


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is not None:
        return
    try:
        os.killpg(proc.pid, signal.SIGTERM)  # the group we created for this viewer only
    except (ProcessLookupError, PermissionError):
        proc.terminate()
    try:
        proc.wait(timeout=5)
    except subprocess.TimeoutExpired:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait(timeout=5)


def tracker_names(recording: str | Path) -> list[str]:
    """The trackers of a tracking recording (``[]`` for one without a layout)."""
    layout = read_layout(recording)
    return list(layout["trackers"]) if layout else []


def focus_blueprint(recording: str | Path, focus: str):
    """The recording's layout with ``focus``'s panels open; :class:`SnapshotError` if it has no such tracker."""
    from covviz.viz.blueprint import layout_blueprint

    layout = read_layout(recording)
    if layout is None:
        raise SnapshotError(f"{recording}: no layout in the recording (not a 'covviz track' recording, or an old one)")
    if focus not in layout["trackers"]:
        raise SnapshotError(f"--tracker {focus}: the recording's trackers are {', '.join(layout['trackers'])}")
    return layout_blueprint(layout, focus=focus)


#: The frame view's per-tracker likelihood overlays (one shown at a time: the focused tracker's).
_LIKELIHOOD_LEAVES = ("likelihood", "likelihood_peak", "likelihood_region", "likelihood_bar", "likelihood_bar_labels")


def _apply_focus(client, layout: dict, focus: str) -> None:
    """In the viewer's blueprint, open ``focus``'s tab of per-tracker panels and show its likelihood map only.

    Edits the blueprint the viewer holds (read with ``get_blueprint``, written back whole with
    ``set_blueprint``): the Tabs holding the per-tracker containers (named after their tracker) get
    ``focus``'s as the active tab; the frame view's overrides show ``focus``'s likelihood overlay and hide
    the others'.
    """
    d = dict(client.get_blueprint().blueprint)
    mine = [k for k, v in d.items() if v.get("ContainerBlueprint", {}).get("display_name") == focus
            and v["ContainerBlueprint"].get("container_kind") == "Vertical"]
    for v in d.values():
        cb = v.get("ContainerBlueprint")
        if cb and cb.get("container_kind") == "Tabs":
            for key in mine:
                if key in cb.get("contents", []):
                    cb["active_tab"] = key
    if focus not in layout.get("with_cloud", []):
        client.set_blueprint(d, of="recording")  # no map of its own: the recording's map stays
        return
    marker = "/ViewContents/overrides/trackers/"
    views = {k.split("/ViewContents/")[0] for k in d if marker in k and "/video/" in k}
    for view in views:
        for name in layout.get("with_cloud", []):
            for leaf in _LIKELIHOOD_LEAVES:
                d[f"{view}{marker}{name}/video/{leaf}/visualizers"] = {"EntityBehavior": {"visible": name == focus}}
    client.set_blueprint(d, of="recording")


def snapshot(
    recording: str | Path,
    out: str | Path,
    frame: int | None = None,
    size: tuple[int, int] = (1600, 900),
    timeline: str = "frame",
    timeout: float = 60.0,
    settle: float = 1.0,
    focus: str | None = None,
) -> Path:
    """Render ``recording`` in the headless Rerun viewer at ``frame`` and save a PNG.

    Parameters
    ----------
    recording : path
        An ``.rrd`` file.
    out : path
        The PNG to write (its folder is created).
    frame : int, optional
        Position on ``timeline`` (default: the last frame of the recording). A
        recording without timelines (all static, as ``covviz mds`` writes) is
        shown as it is.
    size : (int, int)
        Window size in logical points (the PNG may be larger on HiDPI scaling).
    timeline : str
    timeout : float
        Seconds to wait for the viewer to start and load.
    settle : float
        Seconds to let the views settle before the screenshot.
    focus : str, optional
        A tracker of the recording whose panels to show (its tab of the
        per-tracker panels opened): the recording's layout is rebuilt with
        that focus (:func:`covviz.viz.blueprint.layout_blueprint`) and opened
        after it.

    Raises
    ------
    SnapshotError
        No Vulkan driver or viewer binary, the viewer did not start, or no
        screenshot was written.
    """
    return snapshot_frames(recording, [(out, frame)], size, timeline, timeout, settle, focus=focus)[0]


def snapshot_frames(
    recording: str | Path,
    shots: list[tuple[str | Path, int | None]],
    size: tuple[int, int] = (1600, 900),
    timeline: str = "frame",
    timeout: float = 60.0,
    settle: float = 1.0,
    focus: str | None = None,
) -> list[Path]:
    """Several screenshots of one recording, ``(png, frame)`` each, from a single viewer launch.

    See :func:`snapshot` for the arguments; every frame is checked before the first shot.
    A recording cut mid-message (a full disk) is shown up to the cut, from a
    temporary copy of its whole messages (the viewer opens nothing of it as it is).
    """
    from covviz.viz.readback import cut_note, readable_file

    if not Path(recording).is_file():
        raise SnapshotError(f"{Path(recording).resolve()}: no such recording")
    layout = None
    if focus is not None:
        focus_blueprint(recording, focus)  # checks the name
        layout = read_layout(recording)
    with readable_file(Path(recording)) as (src, cut):
        if cut is not None:
            log.warning("%s", cut_note(Path(recording), cut))
        return _snapshot_frames(src, shots, size, timeline, timeout, settle, layout, focus)


def _snapshot_frames(recording, shots, size, timeline, timeout, settle, layout=None, focus=None) -> list[Path]:
    recording = Path(recording).resolve()
    outs = [Path(o).resolve() for o, _ in shots]
    if not recording.is_file():
        raise SnapshotError(f"{recording}: no such recording")
    if not vulkan_available():
        raise SnapshotError(
            "no Vulkan driver for the headless viewer; install it with "
            "'apt-get install -y mesa-vulkan-drivers libvulkan1'"
        )
    exe = find_viewer()
    if exe is None:
        raise SnapshotError("the rerun viewer is not installed (pip install rerun-sdk)")
    for out in outs:
        out.parent.mkdir(parents=True, exist_ok=True)
        if out.exists():
            out.unlink()
    _check_room(outs, size)

    from rerun.experimental import ViewerClient

    port = _free_port()
    cmd = [
        exe,
        "--headless",
        "--window-size",
        f"{size[0]}x{size[1]}",
        "--port",
        str(port),
        "--hide-welcome-screen",
    ]
    env = dict(os.environ)
    env.setdefault("XDG_RUNTIME_DIR", "/tmp")
    proc = subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env, start_new_session=True
    )
    try:
        deadline = time.monotonic() + timeout
        client = None
        while time.monotonic() < deadline:
            if proc.poll() is not None:
                err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
                tail = " ".join(err.strip().splitlines()[-2:])[-300:]
                raise SnapshotError(
                    f"the headless viewer exited (code {proc.returncode}): {tail or 'no message'}"
                )
            try:
                client = ViewerClient.connect(f"rerun+http://127.0.0.1:{port}/proxy")
                client.get_state()
                break
            except Exception:  # noqa: BLE001 - not listening yet (the client raises several kinds)
                client = None
                time.sleep(0.2)
        if client is None:
            raise SnapshotError(f"the headless viewer did not answer within {timeout:.0f} s")
        _viewer_call("open the recording", client.open, str(recording))
        state = _viewer_call("report its state", client.get_state)
        while state.loading and time.monotonic() < deadline:
            time.sleep(0.2)
            state = _viewer_call("report its state", client.get_state)
        rec = next((r for r in state.recordings if r.store_id == state.active_recording), None)
        if rec is None:
            raise SnapshotError(f"{recording}: the viewer opened no recording from it")
        tl = next((t for t in rec.timelines if t.name == timeline), None)
        wanted = [f for _, f in shots]
        if tl is None and (rec.timelines or any(f is not None for f in wanted)):
            names = ", ".join(t.name for t in rec.timelines) or "none: the recording is static"
            raise SnapshotError(f"{recording}: no timeline {timeline!r} (timelines: {names})")
        targets = [None if tl is None else (tl.end if f is None else int(f)) for f in wanted]
        for t in targets:
            if tl is not None and not tl.start <= t <= tl.end:
                raise SnapshotError(f"frame {t} is outside the recording's frames {tl.start}..{tl.end}")
        if layout is not None:
            time.sleep(settle)  # the recording's own blueprint first, then its focus changed
            _apply_focus(client, layout, focus)
        first = True
        for out, t in zip(outs, targets):
            if t is not None:
                _viewer_call("go to the frame", client.set_time, timeline, sequence=t, play_state="paused")
            time.sleep(settle)
            if first:  # warms up the views (images decoded, plots laid out)
                save_screenshot(client, out)
                time.sleep(settle)
                first = False
            save_screenshot(client, out)
    finally:
        _stop(proc)
        if proc.stderr:
            proc.stderr.close()
    for out in outs:
        if not out.is_file() or out.stat().st_size == 0:
            raise SnapshotError(f"the viewer wrote no screenshot to {out}")
    return outs


#: Times a viewer call is tried when it times out (a busy machine: the viewer's gRPC deadline expired).
VIEWER_CALL_TRIES = 3


def _viewer_call(what: str, fn, *args, tries: int = VIEWER_CALL_TRIES, **kwargs):
    """``fn(*args, **kwargs)`` on the viewer client, retried when its deadline expires; then one line."""
    for attempt in range(tries):
        try:
            return fn(*args, **kwargs)
        except Exception as exc:
            if not _timed_out(exc):
                raise
            if attempt == tries - 1:
                raise SnapshotError(
                    f"the headless viewer did not {what} in time, {tries} tries (the machine is busy?); "
                    "run the command again when it is quieter, or give a larger --timeout"
                ) from None
            time.sleep(1.0 + attempt)


def _timed_out(exc: BaseException) -> bool:
    return isinstance(exc, TimeoutError) or "deadline" in str(exc).lower()


def save_screenshot(client, out: Path) -> None:
    """``client.save_screenshot(out)``, with a full disk and a busy viewer each said in one line."""
    try:
        _viewer_call("take the screenshot", client.save_screenshot, str(out))
    except SnapshotError:
        raise
    except Exception as exc:  # noqa: BLE001 - the viewer reports a failed write as a ConnectionError
        text = str(exc)
        if "no space left" in text.lower() or getattr(exc, "errno", None) == errno.ENOSPC:
            raise SnapshotError(f"no space left on the device while writing {out} ({free_space(out)}); "
                                "free some space, or choose another --out") from None
        raise SnapshotError(f"the viewer could not write {out}: {' '.join(text.split())[:200]}") from None


#: Bytes a screenshot may take per pixel of the window: raw RGBA (its PNG of a 1600x900 window is 0.3-3 MB).
SCREENSHOT_BYTES_PER_PIXEL = 4


def _check_room(outs: list[Path], size: tuple[int, int]) -> None:
    """Refuse before the viewer starts if the screenshots cannot fit on the disk."""
    need = len(outs) * size[0] * size[1] * SCREENSHOT_BYTES_PER_PIXEL
    for folder in {o.parent for o in outs}:
        try:
            free = shutil.disk_usage(folder).free
        except OSError:
            continue
        if free < need:
            raise SnapshotError(f"not enough free space for the screenshot in {folder}: about {need / 1e6:.0f} MB "
                                f"needed, {free / 1e6:.1f} MB free; free some space, or choose another --out")


def contact_sheet(images: list[Path], labels: list[str], out: str | Path, scale: float = 0.75) -> Path:
    """Screenshots stacked top to bottom, each under a caption strip, scaled by ``scale``; one PNG."""
    import cv2
    import numpy as np

    rows = []
    for path, label in zip(images, labels):
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is None:
            raise SnapshotError(f"cannot read the screenshot {path}")
        if scale != 1.0:
            img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        strip = np.full((34, img.shape[1], 3), 32, np.uint8)
        cv2.putText(strip, label, (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (235, 235, 235), 1, cv2.LINE_AA)
        rows += [strip, img]
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows]
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), np.concatenate(rows, axis=0)):
        raise SnapshotError(f"cannot write {out}")
    return out
