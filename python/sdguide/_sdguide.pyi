"""Type stubs of the extension module (re-exported by ``sdguide``).

Arrays: vectors ``float32 (N, 3)``, uniform pairs ``float32 (N, 2)``, scalars ``float32 (N,)``,
masks ``bool (N,)``, handles ``uint32 (N,)``; C-contiguous, else ``ValueError``.
"""

from collections.abc import Sequence
from os import PathLike
from typing import Any

import numpy as np
import numpy.typing as npt

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
U32 = npt.NDArray[np.uint32]
Mask = npt.NDArray[np.bool_]
Vec3Like = Sequence[float]

FORMAT_VERSION: tuple[int, int]
"""The cache format this build writes: ``(major, minor)``."""
NO_VERTEX: int
"""The handle ``PathRecorderBatch`` returns for an inactive lane (``2**32 - 1``)."""

class ConfigError(ValueError):
    """A configuration value out of its documented range, an unknown keyword, or bad bounds."""

class CacheError(Exception):
    """A cache that cannot be written or read: I/O, a bad magic or checksum, an unsupported
    version, inconsistent contents."""

class MergeError(ValueError):
    """Fields that cannot be merged: different bounds, configurations or states."""

class GuidingField:
    """A guiding field over the box ``lower``–``upper`` of the scene.

    Keyword arguments are the Rust ``GuidingConfig``'s fields (``rule="l2"``,
    ``spatial_threshold=12000``, ``filter_samples=None``, …); enum values are case- and
    dash-insensitive (``"l2-mixture"``, ``"deferred_box"``). An unknown keyword or a value out
    of range raises ``ConfigError``.
    """

    def __init__(self, lower: Vec3Like, upper: Vec3Like, **config: Any) -> None: ...
    def sample(self, positions: F32, u: F32, normals: F32 | None = None) -> tuple[F32, F32]:
        """Draws one direction per lane (with ``normals``: from the product with the clamped
        cosine): ``(directions (N, 3), pdfs (N,))``; ``pdfs[i] == pdf(...)[i]`` to the bit."""
    def pdf(self, positions: F32, directions: F32, normals: F32 | None = None) -> F32:
        """The solid-angle pdf of ``directions[i]`` at ``positions[i]``: ``(N,)``."""
    def guide_probability(self, positions: F32) -> F32:
        """The learned probability of sampling the guide rather than the BSDF: ``(N,)``."""
    def record(
        self,
        positions: F32,
        directions: F32,
        values: F32,
        pdfs: F32,
        *,
        normals: F32 | None = None,
        integrands: F32 | None = None,
        bsdf_pdfs: F32 | None = None,
        guide_pdfs: F32 | None = None,
        volume: Mask | None = None,
    ) -> int:
        """Records one sample per lane; returns how many were rejected (counted in
        ``stats()["rejected"]``, never raised)."""
    def splitting_factor(
        self,
        positions: F32,
        throughputs: F32,
        pixels: U32,
        image: ImageStatistics,
        *,
        mode: str = "splitting",
        min_survival: float = 0.05,
        max_splits: float = 8.0,
    ) -> F32:
        """The efficiency-aware factor per vertex (``"roulette"``: at most 1); NaN where
        there is none yet."""
    def refine(self) -> None:
        """Ends an iteration: learns from what was recorded since the last ``refine``."""
    def merge(self, other: GuidingField) -> None:
        """Adds ``other``'s statistics of the current iteration (exact; any order)."""
    def to_bytes(self) -> bytes:
        """The field's cache bytes."""
    @staticmethod
    def from_bytes(data: bytes) -> GuidingField:
        """The field a cache holds; ``CacheError`` otherwise."""
    def save(self, path: str | PathLike[str]) -> None:
        """Writes the cache to ``path``; ``CacheError`` on failure."""
    @staticmethod
    def load(path: str | PathLike[str]) -> GuidingField:
        """The field the cache at ``path`` holds; ``CacheError`` otherwise."""
    def stats(self) -> dict[str, Any]:
        """Iteration, tree sizes, samples recorded and rejected by reason, bytes, …"""
    @property
    def config(self) -> dict[str, Any]:
        """The configuration, as a dict of the constructor's keywords."""
    @property
    def bounds(self) -> tuple[list[float], list[float]]:
        """``(lower, upper)``."""
    @property
    def iteration(self) -> int:
        """Refinements so far."""

class PathRecorderBatch:
    """One path recorder per camera sample, driven a bounce at a time. Lane ``i`` belongs to
    path ``i``, or with ``paths`` (sorted ``uint32``) to path ``paths[i]``: a split's
    continuations are more lanes of their path. See the package README."""

    def __init__(self, paths: int, max_vertices: int = 4096) -> None: ...
    def __len__(self) -> int: ...
    def start(self) -> U32:
        """Starts a camera sample on every path; returns the camera rays' handles."""
    def add_radiance(
        self, at: U32, radiance: F32, *, paths: U32 | None = None, active: Mask | None = None
    ) -> None:
        """Radiance (RGB) arriving at ``at[i]`` along its direction."""
    def add_cost(
        self, at: U32, costs: F32, *, paths: U32 | None = None, active: Mask | None = None
    ) -> None:
        """A cost (rays) spent tracing for ``at[i]``."""
    def push(
        self,
        at: U32,
        positions: F32,
        directions: F32,
        bsdf: F32,
        pdfs: F32,
        *,
        normals: F32 | None = None,
        bsdf_pdfs: F32 | None = None,
        guide_pdfs: F32 | None = None,
        volume: Mask | None = None,
        paths: U32 | None = None,
        active: Mask | None = None,
    ) -> U32:
        """A direction drawn at the vertex the ray of ``at[i]`` reached; returns its handle."""
    def push_delta(
        self,
        at: U32,
        positions: F32,
        weights: F32,
        *,
        paths: U32 | None = None,
        active: Mask | None = None,
    ) -> U32:
        """A delta (specular) vertex of weight ``weights[i]``; returns its handle."""
    def roulette(
        self,
        at: U32,
        probabilities: F32,
        survived: Mask,
        *,
        paths: U32 | None = None,
        active: Mask | None = None,
    ) -> None:
        """Russian roulette on the path along ``at[i]``."""
    def split(
        self,
        at: U32,
        factors: F32,
        traced: U32,
        *,
        paths: U32 | None = None,
        active: Mask | None = None,
    ) -> None:
        """``traced[i]`` continuations for the factor ``factors[i]`` at the vertex the ray of
        ``at[i]`` reached; each pushed after this weighs ``1/factors[i]``."""
    def finish(self) -> F32:
        """Ends every path's camera sample; returns the estimates, ``(P, 3)``."""
    def record(self, field: GuidingField) -> int:
        """Records the finished paths into ``field``; returns the vertices recorded."""
    def stats(self) -> dict[str, int]:
        """The recorders' counts of paths, bad input and factors, summed over the paths."""

class ImageStatistics:
    """A render's camera samples per pixel over its passes, and the image terms of the
    efficiency-aware factor they give for the next pass."""

    def __init__(self, width: int, height: int, epsilon: float = 0.01) -> None: ...
    def add(self, pixels: U32, values: F32, costs: F32) -> None:
        """Adds camera samples: luminance ``values[i]`` costing ``costs[i]`` rays in
        ``pixels[i]``."""
    def end_pass(self) -> None:
        """Ends the pass: with at least 4 samples per pixel it sets the next factors."""
    def set_estimate(self, estimate: F32 | None = None) -> None:
        """The pixels' estimated luminance ``(H·W,)``, or ``None``: the samples' mean."""
    def pixel_values(self) -> F32:
        """``P = sqrt(Ĩ² + ε)`` per pixel, ``(H·W,)``."""
    @property
    def relative_variance(self) -> float | None: ...
    @property
    def cost_per_sample(self) -> float | None: ...
    @property
    def passes(self) -> int: ...

def continuations(factors: F32, u: F32) -> tuple[U32, F32]:
    """How many continuations each factor traces (stochastic rounding with ``u``) and the
    weight ``1/q`` each carries; NaN: one, weight 1."""

def pass_weights(
    width: int, height: int, sums: F64, squares: F64, counts: U32
) -> npt.NDArray[np.float64] | None:
    """The weights ``(K,)`` that combine ``K`` passes by inverse variance (``Σ w = 1``):
    ``sums``/``squares`` ``float64 (K, H·W)`` per-pixel luminance sums, ``counts``
    ``uint32 (K, H·W)``; oldest pass first, the final render last. ``None``: no pass
    can be weighed."""
