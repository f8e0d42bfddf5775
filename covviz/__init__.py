"""covviz: a particle-filter tracker on the Riemannian manifold of covariance
matrices, and the Rerun app to see why it holds on or drifts."""

__version__ = "0.1.0"
