"""The layout a covviz recording opens on (a Rerun blueprint).

Three columns:

* left — the **story strip** (a state timeline: per tracker, on track / model
  / search / estimate failure / lost, the replays' verdicts, label-free
  alarms), the frame with the top particles (all of them one toggle away), the
  estimate, the ground truth and the likelihood map; under it two plots with
  short titles and their legend in a corner: IoU with the particles' reach and
  the events (x drift began, ▼ lost, ▲ recovered, in each tracker's
  colour); *why off track*: the likelihood distance at the truth and at the
  estimate, with the frames labelled model / search / estimate failures (the
  centre error instead for trackers without templates);
* middle — one tab per tracker with templates, each with its own panels: the
  zoom (warped patches at the estimate, the truth and the initial box), the
  likelihood along scale and rotation at the estimate's and the truth's
  centres, the template cloud on the manifold (MDS) alone and with the
  background, its template / observation / difference heatmaps and its
  likelihood terms; ``focus`` chooses the open tab;
* right — the events with the diagnosis of every loss (open by default), the
  description, the summary and the config in tabs; below them the particle
  weights and the template cloud's distances, spread, the target's gap to it,
  the background's margin and the MDS stress (each plot tall enough for its
  legend), and the timings.

Entity paths come from :mod:`covviz.viz.paths`.
"""

from __future__ import annotations

from collections.abc import Sequence

import rerun.blueprint as rrb
import rerun.blueprint.encodings as rrbe

from covviz.viz import paths as P

__all__ = ["build_blueprint", "layout_blueprint", "mds_blueprint"]


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
    focus: str | None = None,
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
    focus : str, optional
        The tracker whose panels are open (default: the first;
        ``covviz snapshot --tracker`` and ``--event`` choose it).

    Notes
    -----
    On top, the **story strip**: a state timeline with each tracker's lanes
    (on track / model / search / estimate failure / lost; the verdicts of
    the replays; label-free alarms). The plots have short titles and their
    legend in a corner (the colour key in the plot, not in a title the
    layout cuts off); every tracker has its own colour, used for its box,
    its curves and its event markers (x drift, ▼ loss, ▲ recovery).
    Each tracker with templates has its own tab of panels
    (zoom, slices, cloud, heatmaps, likelihood terms).
    Only the top particles are drawn over the frame; all of them are one toggle
    away (the eye icon of ``particles`` in the frame view).
    """
    tp = [P.TrackerPaths(n) for n in trackers]
    pp = [P.TrackerPaths(n) for n in trackers if n in with_particles]
    cp = [P.TrackerPaths(n) for n in trackers if n in with_cloud]
    shown = focus if focus in with_cloud else (cp[0].name if cp else None)
    bounds = None
    if image_size is not None:
        bounds = rrb.VisualBounds2D(x_range=(0.0, float(image_size[0])), y_range=(0.0, float(image_size[1])))
    strip = rrb.StateTimelineView(
        name="Story: on track · model / search / estimate failure · lost · verdict · alarm",
        origin="/",
        contents=[f"+ /{p.story_lane(lane)}" for p in tp for lane in P.STORY_LANES],
    )
    frame_view = rrb.Spatial2DView(
        name="Frame",
        origin="/",
        contents=[f"+ /{P.VIDEO}/**"] + [f"+ /{p.video}/**" for p in tp],
        visual_bounds=bounds,
        # All particles drawn hide the target: only the top ones by default (toggle 'particles' to see all).
        overrides={
            **{f"/{path}": rrb.EntityBehavior(visible=False) for p in pp for path in (p.particles, p.particle_dots)},
            # One likelihood map at a time (two overlap into noise): the focused tracker's.
            **{f"/{path}": rrb.EntityBehavior(visible=False) for p in cp if p.name != shown
               for path in (p.likelihood, p.likelihood_peak, p.likelihood_region, p.likelihood_bar,
                            p.likelihood_bar_labels)},
        },
    )
    legend = rrb.PlotLegend(corner="LeftBottom", visible=True)
    plots = [
        rrb.TimeSeriesView(
            name="IoU",
            origin="/",
            contents=[f"+ /{p.iou}" for p in tp] + [f"+ /{p.marker(k)}" for p in tp for k in ("drift", "lost",
                                                                                                "recovered")]
            + [f"+ /{p.metrics}/replay/**" for p in tp] + [f"+ /{p.why_series('reach')}" for p in pp]
            + [f"+ /{p.root}/drift/**" for p in tp],  # the label-free drift probability (covviz.viz.drift)
            axis_y=rrb.ScalarAxis(range=(0.0, 1.05)),
            plot_legend=legend,
        ),
    ]
    if cp:
        plots.append(
            rrb.TimeSeriesView(
                name="Why off track (d)",
                origin="/",
                contents=[f"+ /{p.why_series(k)}" for p in cp for k in ("best_truth", "best_est", "d_truth", "d_est")]
                + [f"+ /{p.why}/label/**" for p in cp],
                axis_y=rrb.ScalarAxis(range=(0.0, 11.0)),
                plot_legend=rrb.PlotLegend(corner="LeftTop", visible=True),
            )
        )
    else:
        plots.append(
            rrb.TimeSeriesView(
                name="Centre error (px)",
                origin="/",
                contents=[f"+ /{p.center_error}" for p in tp],
                plot_legend=legend,
            )
        )
    if pp:
        plots.append(
            rrb.TimeSeriesView(
                name="Weights",
                origin="/",
                contents=[f"+ /{p.weights}/**" for p in pp],
                # below 0: a strip for the observation pull's held-frame markers, apart from the series
                axis_y=rrb.ScalarAxis(range=(P.PULL_HELD_LEVEL * 2, 1.05)),
                plot_legend=rrb.PlotLegend(corner="LeftTop", visible=True),
            )
        )
    if cp:
        plots.append(
            rrb.TimeSeriesView(
                name="Template cloud",
                origin="/",
                contents=[f"+ /{p.distance}/**" for p in cp] + [f"+ /{p.cloud_health}/**" for p in cp],
                axis_y=rrb.ScalarAxis(range=(-1.0, 6.0)),
                plot_legend=rrb.PlotLegend(corner="LeftTop", visible=True),
            )
        )
    # IoU and why off track under the frame; the filter's own plots (weights, template cloud) under the events,
    # so that each plot is tall enough for its legend (four in a 2x2 grid under the frame had their legends
    # clipped at 1600x900 and covering the curves).
    plot_box = rrb.Horizontal(*plots[:2])
    side_plots = plots[2:]
    strip_share = min(0.45 + 0.45 * len(tp), 1.5)  # three lanes per tracker
    left = rrb.Vertical(strip, frame_view, plot_box, row_shares=[strip_share, 2.0, 1.25])

    middles = []
    for p in cp:
        panels = [
            rrb.Spatial2DView(name=f"Zoom: estimate | truth | initial · {p.name}", origin=f"/{p.zoom}"),
            rrb.Spatial2DView(name=f"d along scale | rotation · {p.name}", origin=f"/{p.slices}"),
            rrb.Tabs(
                rrb.Spatial2DView(name=f"Template cloud (MDS) · {p.name}", origin=f"/{p.cloud_zoom}"),
                rrb.Spatial2DView(name=f"Cloud + background · {p.name}", origin=f"/{p.cloud}"),
            ),
            rrb.Tabs(
                rrb.Spatial2DView(name=f"Template | observed | diff · {p.name}", origin=f"/{p.heatmap}"),
                *([rrb.TimeSeriesView(
                    name=f"Likelihood terms · {p.name}",
                    origin="/",
                    contents=[f"+ /{p.terms}/**"],
                    axis_y=rrb.ScalarAxis(range=(0.0, 1.05)),
                    plot_legend=rrb.PlotLegend(corner="LeftTop", visible=True),
                )] if p.name in with_particles else []),
            ),
        ]
        middles.append(rrb.Vertical(*panels, row_shares=[0.55, 1.1, 1.5, 1.1], name=p.name))
    names = [p.name for p in cp]
    active = names.index(focus) if focus in names else 0
    middle = None
    if len(middles) == 1:
        middle = middles[0]
    elif middles:
        middle = rrb.Tabs(*middles, active_tab=active)

    docs = rrb.Tabs(
        rrb.TextLogView(
            name="Events",
            origin=f"/{P.TRACKERS}",
            contents=[f"+ /{p.events}" for p in tp],
            # The entity path is the tracker's, which the headline already names, and the level is the
            # headline's kind (LOST, DRIFT, SUSPECT ...): their columns go, so the headline (kind, frame,
            # cause, verdict) has the width.
            columns=rrb.TextLogColumns(
                timeline_columns=[rrbe.TimelineColumn(P.FRAME_TIMELINE), rrbe.TimelineColumn(P.TIME_TIMELINE,
                                                                                             visible=False)],
                text_log_columns=[rrbe.TextLogColumn("Body"), rrbe.TextLogColumn("LogLevel", visible=False),
                                  rrbe.TextLogColumn("EntityPath", visible=False)],
            ),
        ),
        rrb.TextDocumentView(name="How to read this", origin=f"/{P.DESCRIPTION}"),
        rrb.TextDocumentView(name="Summary", origin=f"/{P.SUMMARY}"),
        rrb.TextDocumentView(name="Config", origin=f"/{P.CONFIG}"),
        active_tab=0,
    )
    timings = rrb.TimeSeriesView(
        name="Timings (ms)",
        origin="/",
        contents=[f"+ /{p.timings}/**" for p in tp] + [f"+ /{P.LOGGER_TIME}"],
        plot_legend=rrb.PlotLegend(visible=False),
    )
    right = rrb.Vertical(docs, *side_plots, timings, row_shares=[2.2] + [1.2] * len(side_plots) + [0.8])

    columns = [left] + ([middle] if middle is not None else []) + [right]
    shares = [4.4, 2.6, 3.0] if middle is not None else [6, 3]
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


def layout_blueprint(layout: dict, focus: str | None = None, collapse_panels: bool = True) -> rrb.Blueprint:
    """The blueprint of a recording from its static ``layout`` entity (see :func:`covviz.viz.readback.read_layout`)."""
    size = layout.get("image_size")
    return build_blueprint(
        layout["trackers"], layout.get("with_cloud", ()), layout.get("with_particles", ()),
        image_size=tuple(size) if size else None, collapse_panels=collapse_panels, focus=focus,
    )


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
