"""The maths of the tracker: SPD geometry, the descriptor, the observation model, dynamics and particles.

Nothing here knows about sequences, observers or files; every function is pure and batched, randomness is
passed in as a ``numpy.random.Generator``.
"""
