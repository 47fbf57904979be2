"""sdguide: path guiding with variance-optimal SD-trees, from Python.

The field learns, while a renderer renders, where light comes from, and hands back a directional
distribution to sample at every path vertex. Every call here works on a batch of lanes — one per
path vertex, as a wavefront renderer processes a bounce — held in numpy arrays:

* vectors: C-contiguous ``float32`` arrays of shape ``(N, 3)``;
* pairs of uniform numbers: ``(N, 2)``; scalars: ``(N,)``; masks: ``bool`` ``(N,)``;
  vertex handles: ``uint32`` ``(N,)``.

Anything else (float64, a strided view, a wrong length) raises ``ValueError`` naming the
argument; nothing is converted silently. Bad values inside well-formed arrays (NaN, zero pdfs,
positions outside the bounds) never raise: a query answers with the uniform fallback, a record
is rejected and counted in ``GuidingField.stats()``.

    >>> import numpy as np, sdguide
    >>> field = sdguide.GuidingField((0, 0, 0), (1, 1, 1), rule="l2")
    >>> x = np.full((4, 3), 0.5, dtype=np.float32)
    >>> d, pdf = field.sample(x, np.random.default_rng(1).random((4, 2), dtype=np.float32))
    >>> field.record(x, d, np.ones(4, np.float32), pdf)
    0
    >>> field.refine()

The batch calls release the GIL and run their lanes in parallel (rayon; ``RAYON_NUM_THREADS``
sets the threads). Each lane returns the one-vertex Rust call's result to the bit, and training
is deterministic: the same samples give the same ``to_bytes()`` whatever the threads or the
order in which worker fields are merged.
"""

from ._sdguide import (
    FORMAT_VERSION,
    NO_VERTEX,
    CacheError,
    ConfigError,
    GuidingField,
    ImageStatistics,
    MergeError,
    PathRecorderBatch,
    continuations,
    pass_weights,
)

__all__ = [
    "FORMAT_VERSION",
    "NO_VERTEX",
    "CacheError",
    "ConfigError",
    "GuidingField",
    "ImageStatistics",
    "MergeError",
    "PathRecorderBatch",
    "continuations",
    "pass_weights",
]
