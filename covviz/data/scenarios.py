"""Named synthetic scenarios: one cause of failure, injected at a known frame.

Each scenario is the calm synthetic sequence (:class:`~covviz.data.synthetic.SyntheticSequence`
with its fast stretch, illumination dip and partial occlusion switched off; its
first frames are those of the default sequence) plus exactly one injected
cause. After a calm stretch on which the default tracker locks on, the cause
starts acting on the target at frame :attr:`Scenario.onset` (0-based), and it
is made decisive: the default tracker (``covviz.trackers.manifold.make()``)
loses the target (IoU with the ground truth below 0.1) within
:attr:`Scenario.window` frames after it, and not before it. The scenarios are
the test cases of the drift diagnosis; what each injects is known exactly,
frame by frame (:meth:`Scenario.truth`).

``open_sequence("synthetic:NAME")`` (and ``covviz track synthetic:NAME``) opens
one; :data:`SCENARIOS` lists them. The ground truth is exact, and the same
scenario gives the same frames, bit for bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from covviz.data.frames import SequenceError
from covviz.data.synthetic import SyntheticConfig, SyntheticSequence
from covviz.metrics import iou

__all__ = [
    "CALM",
    "CAUSES",
    "SCENARIOS",
    "AppearanceChange",
    "Distractor",
    "FastMotion",
    "Illumination",
    "Occlusion",
    "ScaleChange",
    "Scenario",
    "ScenarioTruth",
    "get_scenario",
    "open_scenario",
]

#: The causes of failure the drift diagnosis names, one per scenario.
CAUSES = ("occlusion", "distractor", "illumination", "fast_motion", "scale", "appearance")

#: The synthetic sequence without its events (fast stretch, illumination dip,
#: partial occlusion), 120 frames: frames 0–109 equal the default sequence's.
CALM = SyntheticConfig(
    n_frames=120, fast_start=0, fast_end=0, illum_start=0, illum_end=0, occl_start=0, occl_end=0
)


@dataclass(frozen=True)
class ScenarioTruth:
    """What a scenario injects, frame by frame: the ground truth of the cause.

    Attributes
    ----------
    cause : str
        One of :data:`CAUSES`.
    onset : int
        0-based frame where the cause starts acting on the target.
    window : int
        The default tracker loses the target within ``onset .. onset + window``.
    active : ndarray, shape (n,), bool
        Frames on which the cause acts on the target.
    region : ndarray, shape (n, 4)
        Box ``x, y, w, h`` (0-based pixels) of the injected element in the image:
        the occluder, the distractor, the lit region; ``nan`` where there is none
        (and for fast motion and scale, which inject no element).
    amount : ndarray, shape (n,)
        How strongly the cause acts, in :attr:`amount_unit`.
    amount_unit : str
        What :attr:`amount` measures (it depends on the cause).
    """

    cause: str
    onset: int
    window: int
    active: np.ndarray
    region: np.ndarray
    amount: np.ndarray
    amount_unit: str


@dataclass(frozen=True, kw_only=True)
class Scenario:
    """A named synthetic scenario: the calm sequence plus one cause.

    Subclasses set :attr:`cause`, implement :meth:`truth` and override the
    hooks that :class:`~covviz.data.synthetic.SyntheticSequence` calls:
    :meth:`adjust_poses` (the target's path), :meth:`texture` (its appearance
    at a frame) and :meth:`paint` (anything drawn over the frame, before sensor
    noise).

    Attributes
    ----------
    name : str
        ``synthetic:NAME`` on the command line.
    description : str
        One sentence.
    onset : int
        0-based frame where the cause starts acting on the target.
    window : int
        Frames after ``onset`` within which the default tracker loses the target.
    config : SyntheticConfig
        The sequence it is injected into (:data:`CALM` by default).
    """

    name: str
    description: str
    onset: int
    window: int = 30
    config: SyntheticConfig = CALM
    cause: str = field(default="", init=False)

    def __post_init__(self):
        if self.cause not in CAUSES:
            raise ValueError(f"cause must be one of {', '.join(CAUSES)}, got {self.cause!r}")
        if not 0 < self.onset < self.config.n_frames:
            raise ValueError(f"onset {self.onset} must lie inside the {self.config.n_frames} frames")
        if self.window < 1:
            raise ValueError(f"window must be at least 1 frame, got {self.window}")

    # hooks called by SyntheticSequence ------------------------------------ #
    def adjust_poses(self, poses: np.ndarray, config: SyntheticConfig) -> np.ndarray:
        """The target's path ``(n, 4)`` (``cx, cy, scale, theta``) given the calm one."""
        return poses

    def texture(self, seq: SyntheticSequence, i: int) -> np.ndarray | None:
        """The target's texture at frame ``i`` (None: the sequence's own)."""
        return None

    def paint(self, seq: SyntheticSequence, i: int, img: np.ndarray) -> np.ndarray:
        """Frame ``i`` (float32 grey levels, before sensor noise) with the injected element."""
        return img

    # ground truth of the cause -------------------------------------------- #
    def truth(self, seq: SyntheticSequence) -> ScenarioTruth:  # pragma: no cover - abstract
        raise NotImplementedError

    def _truth(self, active, region, amount, unit) -> ScenarioTruth:
        return ScenarioTruth(
            cause=self.cause,
            onset=self.onset,
            window=self.window,
            active=np.asarray(active, dtype=bool),
            region=np.asarray(region, dtype=np.float64),
            amount=np.asarray(amount, dtype=np.float64),
            amount_unit=unit,
        )


def _covered_fraction(box: np.ndarray, region: np.ndarray) -> np.ndarray:
    """Fraction of each ``box`` ``(n, 4)`` inside ``region`` ``(n, 4)``; 0 where ``region`` is ``nan``."""
    x1 = np.maximum(box[:, 0], region[:, 0])
    y1 = np.maximum(box[:, 1], region[:, 1])
    x2 = np.minimum(box[:, 0] + box[:, 2], region[:, 0] + region[:, 2])
    y2 = np.minimum(box[:, 1] + box[:, 3], region[:, 1] + region[:, 3])
    inter = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
    return np.nan_to_num(inter / (box[:, 2] * box[:, 3]), nan=0.0)


# --------------------------------------------------------------------------- #
# occlusion
# --------------------------------------------------------------------------- #
@dataclass(frozen=True, kw_only=True)
class Occlusion(Scenario):
    """A flat panel slides in from the right edge of the frame and stops, hiding the target.

    The panel covers the frame right of its edge ``x_e(i) = min(W, max(stop_x,
    edge_at_onset - speed·(i - onset)))``, full height; the target keeps moving
    behind it. ``amount`` is the fraction of the ground-truth box it hides.
    """

    edge_at_onset: float = 278.0
    speed: float = 4.0
    stop_x: float = 140.0
    value: float = 128.0
    cause: str = field(default="occlusion", init=False)

    def edge(self, i: int) -> float:
        """x (pixels) of the panel's left edge at frame ``i``; ``W`` while it is out of the frame."""
        x = self.edge_at_onset - self.speed * (i - self.onset)
        return float(min(self.config.width, max(self.stop_x, x)))

    def paint(self, seq, i, img):
        x = self.edge(i)
        if x >= self.config.width:
            return img
        img = img.copy()
        x0 = math.floor(x)
        img[:, x0 + 1 :] = self.value
        keep = x - x0  # pixel x0 spans [x0, x0 + 1): the panel covers its part right of x
        img[:, x0] = img[:, x0] * keep + self.value * (1 - keep)
        return img

    def truth(self, seq):
        W, H = self.config.width, self.config.height
        n = len(seq)
        region = np.full((n, 4), np.nan)
        for i in range(n):
            x = self.edge(i)
            if x < W:
                region[i] = (x, 0.0, W - x, H)
        amount = _covered_fraction(seq.groundtruth, region)
        return self._truth(amount > 0, region, amount, "fraction of the ground-truth box hidden")


# --------------------------------------------------------------------------- #
# distractor
# --------------------------------------------------------------------------- #
@dataclass(frozen=True, kw_only=True)
class Distractor(Scenario):
    """A second copy of the target crosses in front of it, then moves on.

    The copy has the target's texture, scale and rotation; its centre moves on
    a straight line at ``velocity`` (pixels per frame) and passes over the
    target's centre at frame ``cross``. It is drawn over the target, so while
    they overlap it is the one fully visible. ``amount`` is the IoU of the
    copy's box with the ground-truth box.
    """

    cross: int
    velocity: tuple[float, float] = (-5.0, 0.0)
    cause: str = field(default="distractor", init=False)

    def __post_init__(self):
        super().__post_init__()
        if not 0 <= self.cross < self.config.n_frames:
            raise ValueError(f"cross {self.cross} must lie inside the {self.config.n_frames} frames")

    def poses(self, seq: SyntheticSequence) -> np.ndarray:
        """The copy's ``cx, cy, scale, theta`` per frame, ``(n, 4)``."""
        p = seq.poses
        t = np.arange(len(p)) - self.cross
        out = p.copy()
        out[:, 0] = p[self.cross, 0] + self.velocity[0] * t
        out[:, 1] = p[self.cross, 1] + self.velocity[1] * t
        return out

    def boxes(self, seq: SyntheticSequence) -> np.ndarray:
        """The copy's boxes (as the ground truth is drawn), ``nan`` where it is outside the frame."""
        p = self.poses(seq)
        w, h = self.config.target_w * p[:, 2], self.config.target_h * p[:, 2]
        b = np.stack([p[:, 0] - w / 2, p[:, 1] - h / 2, w, h], axis=1)
        W, H = self.config.width, self.config.height
        outside = (b[:, 0] >= W) | (b[:, 1] >= H) | (b[:, 0] + w <= 0) | (b[:, 1] + h <= 0)
        b[outside] = np.nan
        return b

    def paint(self, seq, i, img):
        b = self.boxes(seq)[i]
        if not np.all(np.isfinite(b)):
            return img
        return seq.paint_target(img, self.poses(seq)[i])

    def truth(self, seq):
        region = self.boxes(seq)
        amount = np.nan_to_num(iou(region, seq.groundtruth), nan=0.0)
        return self._truth(
            amount > 0, region, amount, "IoU of the distractor's box with the ground-truth box"
        )


# --------------------------------------------------------------------------- #
# fast motion
# --------------------------------------------------------------------------- #
@dataclass(frozen=True, kw_only=True)
class FastMotion(Scenario):
    """The target jumps by ``displacement`` pixels in ``frames`` frames, then goes on along its path.

    From frame ``onset`` on, the path is shifted by ``displacement · min(1,
    (i - onset + 1) / frames)``. ``amount`` is the motion of the true centre
    since the previous frame, in target sizes (``sqrt(w·h)``).
    """

    displacement: tuple[float, float] = (-150.0, 60.0)
    frames: int = 2
    cause: str = field(default="fast_motion", init=False)

    def adjust_poses(self, poses, config):
        t = np.arange(len(poses), dtype=np.float64)
        k = np.clip((t - self.onset + 1) / self.frames, 0.0, 1.0)
        out = poses.copy()
        out[:, 0] += self.displacement[0] * k
        out[:, 1] += self.displacement[1] * k
        return out

    def truth(self, seq):
        g = seq.groundtruth
        c = g[:, :2] + g[:, 2:] / 2
        step = np.r_[0.0, np.hypot(*np.diff(c, axis=0).T)] / np.sqrt(g[:, 2] * g[:, 3])
        i = np.arange(len(g))
        active = (i >= self.onset) & (i < self.onset + self.frames)
        return self._truth(
            active,
            np.full((len(g), 4), np.nan),
            step,
            "motion of the true centre since the previous frame, target sizes sqrt(w*h)",
        )


# --------------------------------------------------------------------------- #
# scale
# --------------------------------------------------------------------------- #
@dataclass(frozen=True, kw_only=True)
class ScaleChange(Scenario):
    """The target shrinks (or grows) by ``factor`` in ``frames`` frames, about its centre, then keeps that size.

    From frame ``onset`` on, the calm path's scale is multiplied by
    ``factor ** min(1, (i - onset + 1) / frames)`` (a geometric ramp); the
    centre follows the calm path. ``amount`` is that multiplier.
    """

    factor: float = 0.25
    frames: int = 10
    cause: str = field(default="scale", init=False)

    def multiplier(self, n: int) -> np.ndarray:
        t = np.arange(n, dtype=np.float64)
        return self.factor ** np.clip((t - self.onset + 1) / self.frames, 0.0, 1.0)

    def adjust_poses(self, poses, config):
        out = poses.copy()
        out[:, 2] *= self.multiplier(len(poses))
        return out

    def truth(self, seq):
        m = self.multiplier(len(seq))
        i = np.arange(len(seq))
        active = (i >= self.onset) & (i < self.onset + self.frames)
        return self._truth(active, np.full((len(seq), 4), np.nan), m, "scale relative to the calm path")


# --------------------------------------------------------------------------- #
# illumination
# --------------------------------------------------------------------------- #
@dataclass(frozen=True, kw_only=True)
class Illumination(Scenario):
    """A deep shadow sweeps down over the scene: first a light-to-dark edge across the target, then darkness.

    Every pixel above the shadow's edge ``y_e(i) = edge_at_onset + speed·(i -
    onset)`` is multiplied by ``level``, with a penumbra ``soft`` pixels wide
    (a smoothstep) around the edge. A global gain is harmless to a tracker that
    normalises gain; this one is not global: while the edge crosses the target,
    its lit and shadowed parts differ by a factor ``1 / level``, and once the
    target is inside, its contrast is a few grey levels against sensor noise.
    ``amount`` is the mean gain over the ground-truth box (1: unlit by the
    change); :meth:`gain` gives the whole field.
    """

    edge_at_onset: float = 86.0
    speed: float = 4.0
    level: float = 0.03
    soft: float = 6.0
    cause: str = field(default="illumination", init=False)

    def edge(self, i: int) -> float:
        """y (pixels) of the middle of the shadow's edge at frame ``i``."""
        return self.edge_at_onset + self.speed * (i - self.onset)

    def gain_rows(self, i: int, y) -> np.ndarray:
        """The light gain at heights ``y`` (pixels, continuous) in frame ``i``."""
        t = np.clip((np.asarray(y, dtype=np.float64) - (self.edge(i) - self.soft / 2)) / self.soft, 0.0, 1.0)
        lit = t * t * (3.0 - 2.0 * t)  # 0 in the shadow, 1 (exactly) outside it
        return 1.0 - (1.0 - self.level) * (1.0 - lit)

    def gain(self, i: int) -> np.ndarray:
        """The light gain of every pixel of frame ``i``, ``(H, W)`` float32 (1: unchanged)."""
        H, W = self.config.height, self.config.width
        g = self.gain_rows(i, np.arange(H) + 0.5).astype(np.float32)
        return np.broadcast_to(g[:, None], (H, W))

    def paint(self, seq, i, img):
        if self.edge(i) + self.soft / 2 <= 0:
            return img
        return img * self.gain(i)

    def truth(self, seq):
        W, H = self.config.width, self.config.height
        n = len(seq)
        region = np.full((n, 4), np.nan)
        amount = np.ones(n)
        g = seq.groundtruth
        for i in range(n):
            bottom = min(float(H), self.edge(i) + self.soft / 2)
            if bottom > 0:
                region[i] = (0.0, 0.0, W, bottom)
            y = g[i, 1] + g[i, 3] * (np.arange(64) + 0.5) / 64
            amount[i] = self.gain_rows(i, y).mean()
        return self._truth(amount < 1, region, amount, "mean light gain over the ground-truth box")


# --------------------------------------------------------------------------- #
# appearance
# --------------------------------------------------------------------------- #
@dataclass(frozen=True, kw_only=True)
class AppearanceChange(Scenario):
    """The target turns round in ``frames`` frames: its texture cross-fades into a striped back.

    The back is horizontal stripes, ``period`` pixels (of the texture), grey
    levels ``40`` and ``200``, with no dark rim: nothing of the front's
    structure is left. ``amount`` is the weight of the back (0 to 1).
    """

    frames: int = 8
    period: float = 6.0
    cause: str = field(default="appearance", init=False)

    def weight(self, i: int) -> float:
        return float(np.clip((i - self.onset + 1) / self.frames, 0.0, 1.0))

    def back(self) -> np.ndarray:
        """The texture the target turns into, ``(target_h, target_w)`` float32."""
        h, w = self.config.target_h, self.config.target_w
        rows = np.where(np.sin(2 * np.pi * (np.arange(h) + 0.5) / self.period) >= 0, 200.0, 40.0)
        return np.broadcast_to(rows[:, None], (h, w)).astype(np.float32)

    def texture(self, seq, i):
        a = self.weight(i)
        if a == 0:
            return None
        return ((1 - a) * seq._texture + a * self.back()).astype(np.float32)

    def truth(self, seq):
        n = len(seq)
        a = np.array([self.weight(i) for i in range(n)])
        return self._truth(a > 0, np.full((n, 4), np.nan), a, "weight of the new texture")


# --------------------------------------------------------------------------- #
# the catalogue
# --------------------------------------------------------------------------- #
SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        Occlusion(
            name="occlusion",
            description="A flat panel slides in from the right and hides the target, which keeps moving behind it.",
            onset=70,
        ),
        Distractor(
            name="distractor",
            description="An identical copy of the target crosses in front of it and carries the track away.",
            onset=70,
            cross=80,
        ),
        Illumination(
            name="illumination",
            description="A deep shadow sweeps down over the target: a light-to-dark edge across it, then darkness.",
            onset=70,
        ),
        FastMotion(
            name="fast-motion",
            description="The target jumps three target sizes in two frames, then goes on along its path.",
            onset=70,
        ),
        ScaleChange(
            name="scale",
            description="The target shrinks to a quarter of its size in ten frames about its slowly moving centre.",
            onset=70,
        ),
        AppearanceChange(
            name="appearance",
            description="The target turns round in eight frames and shows a striped back without its dark rim.",
            onset=70,
        ),
    )
}


def get_scenario(name: str) -> Scenario:
    """The scenario called ``name`` (case and ``_``/``-`` do not matter).

    Raises
    ------
    SequenceError
        If there is none; the message lists the known names.
    """
    key = str(name).strip().lower().replace("_", "-")
    if key not in SCENARIOS:
        raise SequenceError(f"unknown synthetic scenario {name!r}; choose from {', '.join(SCENARIOS)}")
    return SCENARIOS[key]


def open_scenario(scenario: str | Scenario, **config) -> SyntheticSequence:
    """A :class:`~covviz.data.synthetic.SyntheticSequence` of ``scenario`` (a name or a spec).

    Keyword arguments replace fields of the scenario's :class:`SyntheticConfig`
    (``n_frames=…`` for a shorter sequence, say).
    """
    sc = get_scenario(scenario) if isinstance(scenario, str) else scenario
    if config:
        sc = replace(sc, config=replace(sc.config, **config))
    return SyntheticSequence(scenario=sc)
