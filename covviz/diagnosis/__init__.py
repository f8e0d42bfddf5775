"""Why a tracker drifted: events, per-frame evidence, causes, suspects (no Rerun here)."""
