"""The layout a covviz recording opens on (a Rerun blueprint).

Three columns:

* left — the frame with the particles, the estimate, the ground truth and the
  likelihood map (fitted to the image); under it four plots: IoU and centre
  error against the ground truth (all trackers on one plot, with markers where
  a drift began, the track was lost and recovered), the particle weights
  (ESS/N, max weight, survivors of resampling) and the distances (best and
  weighted-mean ``d(C, C*)``, spread of the templates);
* middle — the template cloud on the manifold (MDS): with the background
  regions, and alone (one tab per tracker with templates);
* right — the description, the event log, the summary and the config in tabs;
  below, the estimate's template, observed descriptor and their difference as
  9×9 tensors, and per-stage timings.

Entity paths come from :mod:`covviz.viz.paths`.
"""

from __future__ import annotations

from collections.abc import Sequence

import rerun as rr
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
        Trackers that have templates (get the MDS views and the tensor views).
    with_particles : sequence of str
        Trackers that have particles (their weights and distances are plotted).
    image_size : (int, int), optional
        ``(width, height)`` of the frames: the frame view opens fitted to the image.
    collapse_panels : bool
        Start with the blueprint and selection panels collapsed and the time
        panel reduced to its scrub bar (more room for the views).
    """
    tp = [P.TrackerPaths(n) for n in trackers]
    pp = [P.TrackerPaths(n) for n in trackers if n in with_particles]
    bounds = None
    if image_size is not None:
        bounds = rrb.VisualBounds2D(x_range=(0.0, float(image_size[0])), y_range=(0.0, float(image_size[1])))
    frame_view = rrb.Spatial2DView(
        name="Frame · particles · estimate · ground truth",
        origin="/",
        contents=[f"+ /{P.VIDEO}/**"] + [f"+ /{p.video}/**" for p in tp],
        visual_bounds=bounds,
    )
    plots = [
        rrb.TimeSeriesView(
            name="IoU with ground truth",
            origin="/",
            contents=[f"+ /{p.metrics}/**" for p in tp] + [f"- /{p.center_error}" for p in tp],
            axis_y=rrb.ScalarAxis(range=(0.0, 1.0)),
            plot_legend=rrb.PlotLegend(corner="LeftBottom"),
        ),
        rrb.TimeSeriesView(
            name="Centre error (px)",
            origin="/",
            contents=[f"+ /{p.center_error}" for p in tp],
            plot_legend=rrb.PlotLegend(corner="LeftTop"),
        ),
    ]
    if pp:
        plots += [
            rrb.TimeSeriesView(
                name="Weights: ESS/N · max weight · survivors",
                origin="/",
                contents=[f"+ /{p.weights}/**" for p in pp],
                axis_y=rrb.ScalarAxis(range=(0.0, 1.0)),
                plot_legend=rrb.PlotLegend(corner="LeftTop"),
            ),
            rrb.TimeSeriesView(
                name="Distance d(C, C*) · template spread",
                origin="/",
                contents=[f"+ /{p.distance}/**" for p in pp],
                plot_legend=rrb.PlotLegend(corner="LeftTop"),
            ),
        ]
    plot_box = rrb.Grid(*plots, grid_columns=2) if len(plots) > 2 else rrb.Horizontal(*plots)
    left = rrb.Vertical(frame_view, plot_box, row_shares=[2.2, 1.6 if len(plots) > 2 else 1.0])

    clouds = []
    for n in trackers:
        if n in with_cloud:
            p = P.TrackerPaths(n)
            clouds.append(
                rrb.Vertical(
                    rrb.Spatial2DView(name=f"Template cloud + background (MDS) · {n}", origin=f"/{p.cloud}"),
                    rrb.Spatial2DView(name=f"Template cloud alone (MDS) · {n}", origin=f"/{p.cloud_zoom}"),
                    name=n,
                )
            )
    middle = _tabs_or_single(clouds) if clouds else None

    docs = rrb.Tabs(
        rrb.TextDocumentView(name="How to read this", origin=f"/{P.DESCRIPTION}"),
        rrb.TextLogView(name="Events", origin=f"/{P.TRACKERS}", contents=[f"+ /{p.events}" for p in tp]),
        rrb.TextDocumentView(name="Summary", origin=f"/{P.SUMMARY}"),
        rrb.TextDocumentView(name="Config", origin=f"/{P.CONFIG}"),
        active_tab=0,
    )
    lower = []
    for n in trackers:
        if n in with_cloud:
            p = P.TrackerPaths(n)
            mapping = rrb.TensorScalarMapping(colormap="Viridis")
            # One (3, 9, 9) tensor, three views: each shows one slice of the first dimension.
            for k, title in enumerate(("Template logm(C)", "Observed logm(C*)", "Difference")):
                sel = rrb.TensorSliceSelection(
                    width=2,
                    height=1,
                    indices=[rr.encodings.TensorDimensionIndexSelection(dimension=0, index=k)],
                    slider=[],
                )
                lower.append(
                    rrb.TensorView(
                        name=f"{title} · {n}",
                        origin=f"/{p.tensors}",
                        slice_selection=sel,
                        scalar_mapping=mapping,
                    )
                )
    lower.append(
        rrb.TimeSeriesView(
            name="Timings (ms)",
            origin="/",
            contents=[f"+ /{p.timings}/**" for p in tp] + [f"+ /{P.LOGGER_TIME}"],
            plot_legend=rrb.PlotLegend(corner="LeftTop"),
        )
    )
    right = rrb.Vertical(docs, rrb.Tabs(*lower), row_shares=[1.3, 1])

    columns = [left] + ([middle] if middle is not None else []) + [right]
    shares = [4.8, 2.9, 2.6] if middle is not None else [6, 3]
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
