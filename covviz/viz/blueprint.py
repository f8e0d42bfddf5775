"""The layout a covviz recording opens on (a Rerun blueprint).

Three columns:

* left — the frame with the top particles (all of them one toggle away), the
  estimate, the ground truth and the likelihood map; under it four plots: IoU
  with the particles' reach and the events (x drift began, ▼ lost, ▲ recovered,
  * suspect, in each tracker's colour); *why off track*: the likelihood
  distance at the truth and at the estimate, with the frames labelled model /
  search / estimate failures; the particle weights; the template cloud's
  distances, spread, the target's gap to it, the background's margin and the
  MDS stress;
* middle (per tracker with templates) — the zoom (warped patches at the
  estimate, the truth and the initial box), the likelihood along scale and
  rotation at the estimate's and the truth's centres, and the template cloud
  on the manifold (MDS) alone and with the background;
* right — the events with the diagnosis of every loss (open by default), the
  description, the summary and the config in tabs; below, the estimate's
  template, observation and difference as labelled heatmaps, and timings.

Entity paths come from :mod:`covviz.viz.paths`.
"""

from __future__ import annotations

from collections.abc import Sequence

import rerun.blueprint as rrb

from covviz.viz import paths as P

__all__ = ["build_blueprint", "mds_blueprint"]


def _tabs_or_single(views: list, name: str | None = None):
    if len(views) == 1:
        return views[0]
    return rrb.Tabs(*views, name=name)


def build_blueprint(
    trackers: Sequence[str],
    with_cloud: Sequence[str] = (),
    with_particles: Sequence[str] = (),
    image_size: tuple[int, int] | None = None,
    collapse_panels: bool = True,
) -> rrb.Blueprint:
    """The default layout of a tracking recording.

    Parameters
    ----------
    trackers : sequence of str
        Tracker names as in the entity paths (``trackers/<name>``).
    with_cloud : sequence of str
        Trackers that have templates (get the diagnosis views: likelihood at the
        truth and the estimate, zoom, slices, heatmaps, the template cloud).
    with_particles : sequence of str
        Trackers that have particles (their weights are plotted).
    image_size : (int, int), optional
        ``(width, height)`` of the frames: the frame view opens fitted to the image.
    collapse_panels : bool
        Start with the blueprint and selection panels collapsed and the time
        panel reduced to its scrub bar (more room for the views).

    Notes
    -----
    The plots have no legend box (with a few series each it would cover half
    the plot at 1600×900); their titles name the series, every tracker has its
    own colour (its box on the frame carries its name), its event markers
    (x drift, ▼ loss, ▲ recovery, * suspect) are drawn in that colour, and
    hovering a curve shows its full name.
    Only the top particles are drawn over the frame; all of them are one toggle
    away (the eye icon of ``particles`` in the frame view).
    """
    tp = [P.TrackerPaths(n) for n in trackers]
    pp = [P.TrackerPaths(n) for n in trackers if n in with_particles]
    cp = [P.TrackerPaths(n) for n in trackers if n in with_cloud]
    bounds = None
    if image_size is not None:
        bounds = rrb.VisualBounds2D(x_range=(0.0, float(image_size[0])), y_range=(0.0, float(image_size[1])))
    frame_view = rrb.Spatial2DView(
        name="Frame · top particles · estimate · ground truth",
        origin="/",
        contents=[f"+ /{P.VIDEO}/**"] + [f"+ /{p.video}/**" for p in tp],
        visual_bounds=bounds,
        # All particles drawn hide the target: only the top ones by default (toggle 'particles' to see all).
        overrides={f"/{p.particles}": rrb.EntityBehavior(visible=False) for p in pp},
    )
    plots = [
        rrb.TimeSeriesView(
            name="IoU with the truth (bold) · particles' best IoU (thin) · drift probability (label-free) · "
            "x drift ▼ lost ▲ recovered * suspect",
            origin="/",
            contents=[f"+ /{p.metrics}/**" for p in tp] + [f"- /{p.center_error}" for p in tp]
            + [f"+ /{p.why_series('reach')}" for p in pp]
            + [f"+ /{p.root}/drift/**" for p in tp],  # issue 21: covviz.viz.drift
            axis_y=rrb.ScalarAxis(range=(0.0, 1.05)),
            plot_legend=rrb.PlotLegend(visible=False),
        ),
    ]
    if cp:
        plots.append(
            rrb.TimeSeriesView(
                name="Why off track: d at the truth (bright) vs the estimate (dim); bold = best template; "
                "x model ▲ search, diamond estimate failure",
                origin="/",
                contents=[f"+ /{p.why_series(k)}" for p in cp for k in ("best_truth", "best_est", "d_truth", "d_est")]
                + [f"+ /{p.why}/label/**" for p in cp],
                axis_y=rrb.ScalarAxis(range=(0.0, 11.0)),
                plot_legend=rrb.PlotLegend(visible=False),
            )
        )
    else:
        plots.append(
            rrb.TimeSeriesView(
                name="Centre error (px)",
                origin="/",
                contents=[f"+ /{p.center_error}" for p in tp],
                plot_legend=rrb.PlotLegend(visible=False),
            )
        )
    if pp:
        plots.append(
            rrb.TimeSeriesView(
                name="Weights: ESS/N (yellow) · max weight (red) · survivors (blue) · resampled (dots)",
                origin="/",
                contents=[f"+ /{p.weights}/**" for p in pp],
                axis_y=rrb.ScalarAxis(range=(0.0, 1.05)),
                plot_legend=rrb.PlotLegend(visible=False),
            )
        )
    if cp:
        plots.append(
            rrb.TimeSeriesView(
                name="Cloud: min/mean d · spread (violet) · target's gap/usual (bold) · bg margin · MDS stress",
                origin="/",
                contents=[f"+ /{p.distance}/**" for p in cp] + [f"+ /{p.cloud_health}/**" for p in cp],
                axis_y=rrb.ScalarAxis(range=(-1.0, 6.0)),
                plot_legend=rrb.PlotLegend(visible=False),
            )
        )
    plot_box = rrb.Grid(*plots, grid_columns=2) if len(plots) > 2 else rrb.Horizontal(*plots)
    left = rrb.Vertical(frame_view, plot_box, row_shares=[2.1, 1.7 if len(plots) > 2 else 1.0])

    middles = []
    for p in cp:
        middles.append(
            rrb.Vertical(
                rrb.Spatial2DView(name=f"Zoom: estimate | truth | initial · {p.name}", origin=f"/{p.zoom}"),
                rrb.Spatial2DView(
                    name=f"d along scale | rotation at the estimate's and the truth's centres (0..10, lower = "
                    f"preferred; centre line = their own) · {p.name}",
                    origin=f"/{p.slices}",
                ),
                rrb.Tabs(
                    rrb.Spatial2DView(name=f"Template cloud alone (MDS) · {p.name}", origin=f"/{p.cloud_zoom}"),
                    rrb.Spatial2DView(name=f"Template cloud + background (MDS) · {p.name}", origin=f"/{p.cloud}"),
                ),
                row_shares=[0.75, 1.0, 2.0],
                name=p.name,
            )
        )
    middle = _tabs_or_single(middles) if middles else None

    docs = rrb.Tabs(
        rrb.TextLogView(name="Events", origin=f"/{P.TRACKERS}", contents=[f"+ /{p.events}" for p in tp]),
        rrb.TextDocumentView(name="How to read this", origin=f"/{P.DESCRIPTION}"),
        rrb.TextDocumentView(name="Summary", origin=f"/{P.SUMMARY}"),
        rrb.TextDocumentView(name="Config", origin=f"/{P.CONFIG}"),
        active_tab=0,
    )
    lower = [
        rrb.Spatial2DView(name=f"Template | observed | difference (log space) · {p.name}", origin=f"/{p.heatmap}")
        for p in cp
    ]
    if pp:
        lower.append(
            rrb.TimeSeriesView(
                name="Likelihood terms: share of d_eff² (bold) · weight each moved (thin), 0..1",
                origin="/",
                contents=[f"+ /{p.terms}/**" for p in pp],
                axis_y=rrb.ScalarAxis(range=(0.0, 1.05)),
                plot_legend=rrb.PlotLegend(visible=False),
            )
        )
    lower.append(
        rrb.TimeSeriesView(
            name="Timings (ms)",
            origin="/",
            contents=[f"+ /{p.timings}/**" for p in tp] + [f"+ /{P.LOGGER_TIME}"],
            plot_legend=rrb.PlotLegend(visible=False),
        )
    )
    right = rrb.Vertical(docs, rrb.Tabs(*lower), row_shares=[1.4, 1])

    columns = [left] + ([middle] if middle is not None else []) + [right]
    shares = [4.6, 2.6, 2.8] if middle is not None else [6, 3]
    parts = [rrb.Horizontal(*columns, column_shares=shares)]
    if collapse_panels:
        parts += [
            rrb.BlueprintPanel(state="collapsed"),
            rrb.SelectionPanel(state="collapsed"),
            rrb.TimePanel(state="collapsed", timeline=P.FRAME_TIMELINE),
        ]
    else:
        parts += [rrb.TimePanel(timeline=P.FRAME_TIMELINE)]
    return rrb.Blueprint(*parts)


def mds_blueprint(collapse_panels: bool = True) -> rrb.Blueprint:
    """Layout of the ``covviz mds`` recording: the two paper figures side by side and the description."""
    parts = [
        rrb.Horizontal(
            rrb.Spatial2DView(
                name="Target vs background on the manifold (MDS)", origin=f"/{P.FIGURE_SEPARATION}"
            ),
            rrb.Spatial2DView(name="Random walk of the templates (MDS)", origin=f"/{P.FIGURE_RANDOM_WALK}"),
            rrb.TextDocumentView(name="How to read this", origin=f"/{P.DESCRIPTION}"),
            column_shares=[3, 3, 1.6],
        )
    ]
    if collapse_panels:
        parts += [
            rrb.BlueprintPanel(state="collapsed"),
            rrb.SelectionPanel(state="collapsed"),
            rrb.TimePanel(state="collapsed"),
        ]
    return rrb.Blueprint(*parts)
