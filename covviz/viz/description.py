"""The markdown description logged into every recording (the "How to read this" tab).

The viewer's font has no glyph for some symbols (``∇``, ``∝`` ...), and a missing
glyph *crashes* the viewer (rerun 0.41, checked headless): text shown in the
viewer must stick to :data:`VIEWER_SAFE_EXTRA` beyond Latin-1, or go through
:func:`viewer_safe`.
"""

from __future__ import annotations

__all__ = ["DESCRIPTION", "MDS_DESCRIPTION", "VIEWER_SAFE_EXTRA", "VIEWER_SPELLED", "viewer_safe"]

#: Characters beyond Latin-1 that the viewer's font draws (checked one by one with rerun 0.41).
VIEWER_SAFE_EXTRA = frozenset("−≥≤▲▼–—→σπ")


#: Characters the viewer lacks, spelled out instead of shown as ``?``.
VIEWER_SPELLED = {"ε": "eps", "≈": "~", "✓": "yes", "✗": "no", "…": "...", "•": "-", "√": "sqrt", "∞": "inf",
                  "Δ": "delta", "λ": "lambda", "μ": "mu"}


def viewer_safe(text: str) -> str:
    """``text`` with what the viewer may not draw spelled out (:data:`VIEWER_SPELLED`), else replaced by ``?``."""
    return "".join(
        c if ord(c) < 0x100 or c in VIEWER_SAFE_EXTRA else VIEWER_SPELLED.get(c, "?") for c in str(text)
    )


DESCRIPTION = """\
# covviz: why the tracker holds on, or drifts

Start at the **story strip** (top left): per tracker, a lane of its frames - **on track**, a
**model** / **search** / **estimate** failure, **lost** - a lane of the replays' **verdicts**
(the smallest fix that keeps the track) and a lane for label-free **alarms**; click a band to go
to its frame. Then **Events** (right): every row leads with its kind, frame and cause
(`LOST 84 · OCCLUSION · drift began 71`); expand it for the full diagnosis - the numbers behind
it, and the frames to look at. Scrub the **frame** timeline (bottom bar) to a frame
number; frames are numbered from 1 (`img/0001.jpg`), as in the events. Each tracker lives under
`trackers/<name>/`; the frame and the ground truth under `video/`.

## Events and diagnoses
Losses (IoU < 0.1), the frame each **drift began**, recoveries and resampling storms come from
the ground truth and the weights. A **storm** is ESS/N < 0.05 on 3 frames while the IoU falls
below 0.5 (without ground truth: 30 frames): peaked weights on a run that stays on track are a
sharp likelihood, not a storm, so a calm run lists none. A loss's card counts its off-track
frames from its drift to the loss; the story strip shows them over the whole run. The paper's
`r_on_track` (centre error within the truth's size) can be high beside a LOST (the IoU rule):
a box of the wrong size keeps its centre on the target. Each loss is read against the target's look before the drift
and named from a fixed vocabulary, the first rule that holds: **fast motion** (the truth jumped
out of the particles' reach), **scale** (the centre held, the size went wrong), **illumination**
(part of the target became much darker or brighter), **distractor** (the target still looks as
before, and the tracker follows a look-alike the likelihood scores as well), **occlusion** (some
quadrants changed while another held, or something static stands in front), **appearance** (the
whole target changed faster than the templates follow), **impoverishment** (the weights sat on a
handful of particles), else **unknown**. Without ground truth, the **drift probability** (in
the IoU plot) comes from label-free signals alone: the forward-backward optical-flow error in
the box, its look against its first and recent looks, a peak-to-sidelobe ratio and, for
particle filters, the weights. A **drift alarm** row in Events shows where it crossed its
threshold, with the signals that drove it. The older **suspects** (weights collapsing, the best
distance leaving its running range, a second mode, the scale running away) are still listed.
Thresholds: `config`, `diagnosis`.

## Frame
* **red box**: ground truth. **Coloured box** (yellow for `manifold`): the estimate as scored;
  the thin outline of the same colour is the estimated rotated region. With several trackers,
  each one's name sits by its own corner of its box.
* **bold green outlines**: the top 10 particles (hover one: its weight, its distance, the
  distance it was weighed by, its four quadrant distances and each term of the likelihood,
  weighted: `d_eff² = distance² + the sum of term_*`). **Dots**: particle centres, sized
  by weight. All particles' outlines, coloured by weight, are one toggle away (the eye of
  `particles` in this view).
* **Likelihood map** (every *k*-th frame and on every frame around an event): a heat overlay of
  the log-likelihood of the estimate's template over the searched region (orange outline) around
  the estimate, exactly as the particles are weighed, on a square-root scale from the map's worst
  (dark) to its best (bright); the colour bar above the region gives its range in nats, and the
  thin white ring is the best match (it does not hide the target). *Bright away from the target:
  the particles will go there.* With several trackers, the open tracker's map.
* **Blue outlines**: the background regions of the template cloud's picture.

## Plots (short titles, the key in a corner of each plot; each tracker has its own colour)
IoU and why off track under the frame; weights and cloud on the right, under these tabs.
* **IoU** with the truth (bold) and the **particles' best IoU** (thin: did any particle reach the
  truth?); markers **x** drift began, **▼** lost, **▲** recovered.
* **Why off track**: the likelihood distance `d_eff` at the **truth** (bright) and at the
  **estimate** (dim), for the best template of the cloud (bold) and the estimate's template
  (thin). Off-track frames are labelled: **x model** failure (the truth scores no better than
  the estimate: the likelihood prefers the wrong place), **▲ search** failure (the truth would
  score better, but no particle reached it), **diamond estimate** failure (particles reached the
  better-scoring truth, the estimate is elsewhere).
* **Weights**: ESS/N, max weight, survivors of resampling (dots: resampled), the loss evidence
  and the re-detected share; markers below 0 where the observation pull was held by its light
  gate (diamonds) or its look gate (squares): the templates did not learn that frame's look.
  The **Why off track** label carries, in the diagnosis of a loss, which part of the likelihood
  (descriptor, quadrants, colour) preferred the estimate's place to the truth's.
* **Cloud**: min and weighted-mean `d(C, C*)`, the template **spread**, the target's **gap** to
  the cloud relative to its usual gap on track (1 = healthy; 2 and more: the target has left the
  templates' reach), the **background margin** (>0: the target is nearer the cloud than any
  background region) and the **stress-1** of the cloud's MDS picture (0.1 fair, 0.2 poor: do not
  read a poor picture as a map).

## Per-tracker panels (middle: one tab per tracker with templates)
* **Zoom**: the 32x32 patches the model samples at the estimate, the truth and the initial box.
* **Slices**: `d_eff` of the estimate's template along scale (x0.6 .. x1.67) and rotation
  (-20 .. +20 degrees) about the estimate's centre (its tracker's colour) and the truth's (red),
  drawn on the frames of the likelihood map; lower is preferred, the vertical line is the pose's
  own. *Flat across scale: the likelihood cannot tell
  the size.*
* **Template cloud** (MDS of Riemannian distances): green generated templates (bright: top 10),
  red the target, white the initial template, yellow the estimate's template; with the blue
  background in the second tab.

* **Heatmaps** (a tab under the cloud): the estimate's template `logm(C)`, the descriptor observed at the estimate `logm(C*)` and their
difference, on fixed colour scales (the bars below them); rows and columns are the 9 features.
* **Likelihood terms** (the next tab, trackers whose likelihood has terms beyond `d(C, C*)`): each part
of `d_eff²` (`descriptor` = `d²`, `quadrants`, `colour`) as its **share** of what the weighted
particles were weighed by (bold; the shares sum to 1) and the **weight it moved** (thin: the total
variation between the weights and the weights without that part; 0 = it changed nothing, near 1 =
it alone decided who carries the weight). *A term whose moved weight jumps as the IoU drops is the
one the failure came from.*
**Timings** (right, below the events): milliseconds per stage of the update, and the recorder's own time.

## Reading a drift
1. In the **story strip**, find where the lane turns from on track to a failure; in **Events**,
   read the loss's row (its cause, its verdict) and expand it; click its `drift began` line.
2. **Why off track**: model failure (fix the likelihood) or search failure (fix the dynamics)?
3. **Zoom** and **slices**: does the truth still look like the initial box? Is the curve flat?
4. Step forward: watch the top particles leave the red box, and ESS/N collapse.
"""

MDS_DESCRIPTION = """\
# The paper's manifold figures

**Target vs background** (left): covariance descriptors of the target (from the ground-truth
box, **red**) and of background regions (**blue**) over the whole sequence, placed by MDS of
their affine-invariant Riemannian distances. The paper claims a clear separation: its number is
the silhouette of the two groups on the distances themselves (below: 0.25 or more holds).

**Random walk of the templates** (right): at a few frames, as the paper's caption says, the 10
generated templates most similar to the truth (**near**, green; brighter = later frame), the truth
(**red**, labelled with its frame) and background regions around it (**blue**); and the whole
cloud: a sample of every particle's template (**template**), the estimate's (**estimate**) and
the initial one (**white**), in one common MDS map. Hide `template` and `estimate` in the entity
tree to see the paper's picture alone. The paper claims the target is well modelled by the
generated covariances: its number is the coverage, the distance to the nearest template over the
median distance of the templates to their mean (1 or less holds).

An MDS picture with a stress-1 above 0.1 misrepresents the distances: read the numbers below.
"""
