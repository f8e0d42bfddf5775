"""Defaults of the recorder that the command line shows in ``--help`` (here, so building it imports no rerun)."""

#: The template cloud's MDS picture (and by default the likelihood map) every this many frames.
MDS_EVERY = 10
