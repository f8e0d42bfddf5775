"""The embedded synthetic sequence: a deterministic textured target with exact ground truth.

The default sequence of ``covviz track`` on a fresh machine, and the base of
the controlled failures of :mod:`covviz.data.scenarios`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from covviz.data.frames import Sequence

__all__ = ["SyntheticConfig", "SyntheticSequence"]


@dataclass(frozen=True)
class SyntheticConfig:
    """Parameters of the synthetic sequence (all defaults in one place).

    Frame indices of the events are 0-based; every event lies inside
    ``n_frames`` for the default length and is skipped if the sequence is shorter.
    """

    n_frames: int = 300
    width: int = 320
    height: int = 240
    target_w: int = 40
    target_h: int = 52
    seed: int = 7
    noise_std: float = 3.0  # sensor noise, grey levels
    fast_start: int = 110  # stretch of fast pose change
    fast_end: int = 135
    illum_start: int = 170  # illumination ramps down to illum_gain and back
    illum_end: int = 230
    illum_gain: float = 0.55
    occl_start: int = 245  # an occluder covers part of the target
    occl_end: int = 270
    occl_fraction: float = 0.35  # fraction of the target width it covers
    frame_rate: float = 30.0

    def __post_init__(self):
        if self.n_frames < 2:
            raise ValueError("a synthetic sequence needs at least 2 frames")
        if not (16 <= self.target_w < self.width / 2 and 16 <= self.target_h < self.height / 2):
            raise ValueError("target size must be at least 16 px and below half the frame")


class SyntheticSequence(Sequence):
    """Deterministic textured target on a cluttered background, with ground truth.

    The target follows a smooth path with a slow scale change and rotation
    (±20°); during ``fast_start..fast_end`` it moves and turns several times
    faster; during ``illum_*`` the whole frame dims to ``illum_gain``; during
    ``occl_*`` a grey bar covers part of the target. The same config gives the
    same frames, bit for bit. Ground truth is the unrotated box of the target's
    size at its centre (how OTB annotates), in 0-based pixels.

    ``scenario`` (a :class:`covviz.data.scenarios.Scenario`; its own config unless
    ``config`` is given) injects one cause of failure at a known frame: it may
    change the path, the target's texture and what is drawn over the frame;
    :attr:`scenario_truth` says what it injected, frame by frame.
    """

    def __init__(self, config: SyntheticConfig | None = None, scenario=None):
        if config is None and scenario is not None:
            config = scenario.config
        self.config = cfg = config or SyntheticConfig()
        self.scenario = scenario
        self.name = "synthetic" if scenario is None else f"synthetic-{scenario.name}"
        self.frame_rate = cfg.frame_rate
        rng = np.random.default_rng(cfg.seed)
        self._background = _clutter(rng, cfg.height, cfg.width)
        self._texture = _target_texture(rng, cfg.target_h, cfg.target_w)
        self._poses = self._trajectory()
        if scenario is not None:
            self._poses = scenario.adjust_poses(self._poses, cfg)
        cx, cy, s = self._poses[:, 0], self._poses[:, 1], self._poses[:, 2]
        w, h = cfg.target_w * s, cfg.target_h * s
        self.groundtruth = np.stack([cx - w / 2, cy - h / 2, w, h], axis=1)

    @property
    def scenario_truth(self):
        """The injected cause frame by frame (:class:`covviz.data.scenarios.ScenarioTruth`), or None."""
        return None if self.scenario is None else self.scenario.truth(self)

    @property
    def poses(self) -> np.ndarray:
        """True ``cx, cy, scale, theta`` per frame, shape ``(n, 4)``."""
        return self._poses.copy()

    def _trajectory(self) -> np.ndarray:
        cfg = self.config
        t = np.arange(cfg.n_frames, dtype=np.float64)
        # "phase" runs faster inside the fast stretch: pose changes ~4x quicker there.
        speed = np.ones_like(t)
        speed[(t >= cfg.fast_start) & (t < cfg.fast_end)] = 4.0
        phase = np.concatenate([[0.0], np.cumsum(speed[:-1])])
        W, H = cfg.width, cfg.height
        mx, my = 0.30 * W, 0.28 * H
        cx = W / 2 + mx * _libm(math.sin, 2 * np.pi * phase / 260.0)
        cy = H / 2 + my * _libm(math.sin, 2 * np.pi * phase / 170.0 + 0.6)
        scale = 1.0 + 0.22 * _libm(math.sin, 2 * np.pi * phase / 300.0)
        theta = np.deg2rad(20.0) * _libm(math.sin, 2 * np.pi * phase / 140.0)
        return np.stack([cx, cy, scale, theta], axis=1)

    def paint_target(self, img: np.ndarray, pose, texture: np.ndarray | None = None) -> np.ndarray:
        """``img`` (float32, ``(H, W)``) with the target texture drawn at ``pose`` ``(cx, cy, scale, theta)``."""
        cfg = self.config
        texture = self._texture if texture is None else texture
        cx, cy, s, th = pose
        # Target: rotate+scale the texture about its centre onto the frame.
        th_, tw_ = texture.shape
        c, si = math.cos(th), math.sin(th)
        # maps texture coords (u, v) -> image: p = R(th) * s * ((u, v) - centre) + (cx, cy)
        A = np.array([[s * c, -s * si], [s * si, s * c]])
        centre = np.array([tw_ / 2.0, th_ / 2.0])
        t = np.array([cx, cy]) - A @ centre
        M = np.hstack([A, (t + A @ np.array([0.5, 0.5]) - 0.5)[:, None]])
        tex = cv2.warpAffine(texture, M, (cfg.width, cfg.height), flags=cv2.INTER_LINEAR)
        mask = cv2.warpAffine(np.ones_like(texture), M, (cfg.width, cfg.height), flags=cv2.INTER_LINEAR)
        return img * (1 - mask) + tex * mask

    def _read(self, i: int) -> np.ndarray:
        cfg = self.config
        cx, cy, s = self._poses[i, :3]
        texture = None if self.scenario is None else self.scenario.texture(self, i)
        img = self.paint_target(self._background.copy(), self._poses[i], texture)
        # Partial occlusion: a vertical grey bar over the target's left part.
        if cfg.occl_start <= i < cfg.occl_end:
            bw = cfg.occl_fraction * cfg.target_w * s
            x0 = cx - cfg.target_w * s / 2 - 2
            y0, y1 = cy - 0.8 * cfg.target_h * s, cy + 0.8 * cfg.target_h * s
            img[max(0, int(y0)) : max(0, int(y1)), max(0, int(x0)) : max(0, int(x0 + bw + 2))] = 120.0
        # Illumination: a smooth dip of the global gain.
        if cfg.illum_start <= i < cfg.illum_end:
            u = (i - cfg.illum_start) / (cfg.illum_end - cfg.illum_start)
            img = img * (1.0 - (1.0 - cfg.illum_gain) * math.sin(math.pi * u))
        if self.scenario is not None:
            img = self.scenario.paint(self, i, img)
        noise = np.random.default_rng([cfg.seed, i]).normal(0.0, cfg.noise_std, img.shape)
        gray = np.clip(img + noise, 0, 255).astype(np.uint8)
        # Mild colour tint so the frames are RGB like real ones.
        return np.stack([gray, gray, np.clip(gray.astype(np.int16) - 8, 0, 255).astype(np.uint8)], axis=2)


def _libm(fn, x) -> np.ndarray:
    """``fn`` (a :mod:`math` function) of every element of ``x``, as a float64 array of its shape.

    The same bits on every CPU: NumPy's ``sin``/``cos``/``exp`` on arrays take
    the CPU's SIMD code (AVX-512 SVML on one machine, other code on an AVX2 one),
    which differs in the last bit; one such bit in the pose of frame 299 moved a
    pixel across a grey level and changed the frame. The C library's scalar
    functions do not follow the vector width (glibc picks one variant for every
    x86-64 CPU with FMA, as every machine covviz is tested on has);
    ``tests/test_scenarios.py`` checks the frames with NumPy held to SSE.
    """
    a = np.asarray(x, dtype=np.float64)
    return np.fromiter(map(fn, a.ravel().tolist()), dtype=np.float64, count=a.size).reshape(a.shape)


def _clutter(rng: np.random.Generator, H: int, W: int) -> np.ndarray:
    """Cluttered background: smooth shading plus random rectangles, ellipses and lines."""
    # separable shading: sin of the column times cos of the row (each through libm, see _libm)
    sx = _libm(math.sin, np.arange(W, dtype=np.float64) / W * 3.1 + 0.4)
    cy = _libm(math.cos, np.arange(H, dtype=np.float64) / H * 2.3)
    img = (90 + 40 * cy[:, None] * sx[None, :]).astype(np.float32)
    for _ in range(70):
        kind = rng.integers(3)
        val = float(rng.uniform(20, 235))
        x, y = int(rng.integers(0, W)), int(rng.integers(0, H))
        if kind == 0:
            w, h = int(rng.integers(6, 50)), int(rng.integers(6, 50))
            cv2.rectangle(img, (x, y), (x + w, y + h), val, -1)
        elif kind == 1:
            ax = (int(rng.integers(4, 30)), int(rng.integers(4, 30)))
            cv2.ellipse(img, (x, y), ax, float(rng.uniform(0, 180)), 0, 360, val, -1)
        else:
            x2, y2 = int(rng.integers(0, W)), int(rng.integers(0, H))
            cv2.line(img, (x, y), (x2, y2), val, int(rng.integers(1, 4)))
    return _blur3(img, 0.8)


def _blur3(img: np.ndarray, sigma: float) -> np.ndarray:
    """A 3x3 Gaussian blur (border reflected without its edge, as OpenCV's default), float32.

    Written out in NumPy rather than ``cv2.GaussianBlur``, whose float32 result
    follows the CPU (its AVX2 and SSE code differ in the last bit): element-wise
    float64 products and sums in a fixed order are the same bits everywhere.
    """
    e = math.exp(-1.0 / (2.0 * sigma * sigma))
    k0, k1 = e / (1.0 + 2.0 * e), 1.0 / (1.0 + 2.0 * e)
    a = np.pad(np.asarray(img, dtype=np.float64), 1, mode="reflect")  # reflect = OpenCV's BORDER_REFLECT_101
    rows = k0 * a[:-2, :] + k1 * a[1:-1, :] + k0 * a[2:, :]
    return (k0 * rows[:, :-2] + k1 * rows[:, 1:-1] + k0 * rows[:, 2:]).astype(np.float32)


def _target_texture(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """A face-like textured target: bright oval, dark blobs, fine stripes."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    u, v = (xx + 0.5) / w - 0.5, (yy + 0.5) / h - 0.5
    tex = 200 - 120 * (u**2 + v**2)  # bright, vignetted
    for _ in range(5):
        bx, by = rng.uniform(-0.35, 0.35), rng.uniform(-0.35, 0.35)
        r = rng.uniform(0.06, 0.14)
        tex -= rng.uniform(60, 140) * _libm(math.exp, -((u - bx) ** 2 + (v - by) ** 2) / (2 * r * r))
    tex += 25 * _libm(math.sin, 2 * np.pi * (3.0 * u + 2.0 * v) * 2)
    tex[:, :2] = tex[:, -2:] = 40  # dark rim gives the target strong edges
    tex[:2, :] = tex[-2:, :] = 40
    return np.clip(tex, 0, 255).astype(np.float32)
