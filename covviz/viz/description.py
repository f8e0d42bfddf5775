"""The markdown description logged into every recording (the "How to read this" tab).

The viewer's font has no glyph for some symbols (``∇``, ``∝`` ...), and a missing
glyph *crashes* the viewer (rerun 0.41, checked headless): text shown in the
viewer must stick to :data:`VIEWER_SAFE_EXTRA` beyond Latin-1, or go through
:func:`viewer_safe`.
"""

from __future__ import annotations

__all__ = ["DESCRIPTION", "MDS_DESCRIPTION", "VIEWER_SAFE_EXTRA", "viewer_safe"]

#: Characters beyond Latin-1 that the viewer's font draws (checked one by one with rerun 0.41).
VIEWER_SAFE_EXTRA = frozenset("−≥≤▲▼–—→σπ")


def viewer_safe(text: str) -> str:
    """``text`` with every character the viewer may not draw replaced by ``?``."""
    return "".join(c if ord(c) < 0x100 or c in VIEWER_SAFE_EXTRA else "?" for c in str(text))


DESCRIPTION = """\
# covviz: why the tracker holds on, or drifts

Scrub the **frame** timeline (bottom bar; `time` is seconds when the sequence has a frame rate).
Each tracker lives under `trackers/<name>/`; the frame and the ground truth under `video/`.

## Frame · particles · estimate · ground truth
* **red box**: ground truth. **Coloured box** (yellow for `manifold`): the estimate as scored;
  the thin outline of the same colour is the estimated rotated region.
* **green outlines**: every particle's region, brighter and more opaque the higher its weight
  (weight divided by the frame's largest weight). The **bold green** ones are the top 10.
  **Dots**: particle centres, sized by weight. Hover a bold outline to read its weight and distance
  (for `manifold`, also the distance it was weighed by, quadrant term included, and its four
  quadrant distances).
* **Likelihood map** (every *k*-th frame, see `config`): the log-likelihood of the estimate's
  template at positions around the estimate (±1 region size; with the tracker's quadrant term
  when it has one, exactly as the particles are weighed), from 20 nats below its best
  position (transparent) to the best (bright yellow); the white dot is the best match.
  *A bright blob away from the target means the background matches the template as well as or
  better than the target does: the particles will go there.*
* **Blue outlines** (same frames as the template cloud): the background regions sampled for it.

## Template cloud (MDS): with the background, and alone
A 2-D map of Riemannian distances between covariance matrices (MDS, aligned to the previous
picture so it does not flip), every *k*-th frame: **green** generated templates (the
particles' templates; **bright green** the top 10 by weight), **red** the descriptor observed at
the ground truth (the target), **blue** background regions around the target, **white** the
initial template, **yellow** the estimate's template. Distances in the picture are distances on
the manifold. The first view includes the background (classical MDS; the template cloud is
often a small knot there: the target is far from the background, which is what makes tracking
work); the second leaves the background out and fits all distances (SMACOF), so the cloud's
own spread shows.
*Healthy*: the green cloud around the red target, blue far away. *Drifting*: the cloud moves
towards the blue points, or the red target leaves the cloud (the appearance changed faster than
the template random walk can follow).

## IoU and centre error
Against the ground truth, all trackers on one plot. Markers: **×** where a drift began
(the first frame of the fall of IoU that ended in a loss), **▼** loss of track (IoU < 0.1),
**▲** recovery (IoU ≥ 0.3 for 3 frames).

## Weights
**ESS/N** (effective sample size over particle count; the tracker resamples below 0.5,
white dots), **max weight**, **survivors/N** (distinct ancestors kept by a resampling).
A *resampling storm* (ESS/N < 0.05) means the likelihood is so peaked that a handful of
particles carry all the weight: the filter is close to losing its diversity.

## Distance d(C, C*) · template spread
**min d** and the **weighted mean d** between each particle's template and what it observes,
and the **template spread** (mean geodesic distance of the templates to their Karcher mean).
Rising distances with a steady spread: the target's appearance changes faster than the
templates follow. A spread that grows without bound: the random walk is too loose.

## Tensors, timings, events
The estimate's 9×9 **template** in log space (`logm(C)`, where the template random walk
moves), the **observed** descriptor at the estimate (`logm(C*)`) and their **difference**
`logm(C*) − logm(C)`: which feature (co)variances changed. Rows and columns: x, y, I, |Ix|,
|Iy|, |grad I|, atan(|Ix|/|Iy|), |Ixx|, |Iyy|.
**Timings**: milliseconds per stage of the tracker's update, and the logger's own time.
**Events**: storms, loss, drift onset and recovery, with frame numbers (click to jump).

## Reading a drift
1. Find the **×** on the IoU plot (or the `drift began` line in Events) and go to that frame.
2. Look at the likelihood map: is there a second bright blob? Where is the white dot?
3. Look at the clouds: is the red target still inside the green cloud? Are blue points closer?
4. Step forward: watch the bright particles leave the red box, and ESS/N collapse.
"""

MDS_DESCRIPTION = """\
# The paper's manifold figures

**Target vs background** (left): covariance descriptors of the target (from the ground-truth
box, **red**) and of background regions (**blue**) over the whole sequence, placed by MDS of
their affine-invariant Riemannian distances. Well separated clouds are what makes the tracker
work; blue points inside the red cloud are distractors.

**Random walk of the templates** (right): at a few frames (labels), the initial template
(**white**), the particles' generated templates (**green**, brighter = later frame, larger =
among the top 10 by weight) and the target descriptor at that frame (**red**), in one common MDS
map: the templates follow the target's appearance across the manifold by a random walk.
"""
