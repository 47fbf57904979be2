//! The guiding field: a spatial tree whose leaves each own a directional quadtree.
//!
//! [`GuidingField`] is what a renderer holds. Render threads call [`GuidingField::record`] and
//! [`GuidingField::distribution`] through `&self`, concurrently and without locks; between
//! iterations the renderer calls [`GuidingField::refine`], which takes `&mut self`, so the type
//! system guarantees no thread is recording or sampling while the trees change.

use crate::bounds::Aabb;
use crate::config::{ConfigError, GuidingConfig};
use crate::distribution::DirectionalDistribution;
use crate::exact::MAX_TERM;
use crate::filter::{SpatialFilter, hash_jitter};
use crate::moments::{Moments, weights};
use crate::quadtree::{DirectionalCell, RefineScratch, bytes_per_node, tally_priority};
use crate::region::{Guide, RefineOutcome, Region, StepParams};
use crate::rule::{LeafRule, mixture_value};
use crate::sample::{RejectReason, Sample};
use crate::spatial::SpatialTree;
use crate::spatial_split::{self, SpatialSplit, SplitPlan};
use crate::sphere::INV_SPHERE_AREA;
use crate::splitting::{Continuation, ContinuationEstimate};
use crate::stats::{EventCount, FieldStats, RejectCounters, Rejections};
use glam::{Vec2, Vec3};
use rayon::prelude::*;

/// A learned, continuously refined field of directional distributions over a scene.
///
/// ```
/// use sdguide::{Aabb, GuidingConfig, GuidingField, Sample};
/// use glam::{Vec2, Vec3};
///
/// let mut field = GuidingField::new(Aabb::new(Vec3::ZERO, Vec3::ONE), GuidingConfig::default())?;
/// // Light arrives from around +z. Record what a renderer sampling uniformly would have seen.
/// let uniform_pdf = 1.0 / (4.0 * std::f32::consts::PI);
/// for _iteration in 0..4 {
///     for i in 0..10_000 {
///         let u = Vec2::new((i % 100) as f32 + 0.5, (i / 100) as f32 + 0.5) / 100.0;
///         let d = sdguide::sphere::square_to_direction(u);
///         let light = if d.z > 0.9 { 10.0 } else { 0.0 };
///         let (position, direction, value, pdf) = (Vec3::splat(0.5), d, light, uniform_pdf);
///         field.record(&Sample { position, direction, value, pdf, ..Sample::default() });
///     }
///     field.refine();
/// }
/// let dist = field.distribution(Vec3::splat(0.5));
/// assert!(dist.pdf(Vec3::Z) > 5.0 * uniform_pdf);
/// let (dir, pdf) = dist.sample(Vec2::new(0.3, 0.7));
/// assert_eq!(pdf, dist.pdf(dir));
/// # Ok::<(), sdguide::ConfigError>(())
/// ```
#[derive(Clone, Debug)]
pub struct GuidingField {
    pub(crate) bounds: Aabb,
    pub(crate) config: GuidingConfig,
    pub(crate) spatial: SpatialTree,
    /// One per spatial leaf, in the order the spatial tree's leaves index them.
    pub(crate) regions: Vec<Region>,
    pub(crate) iteration: u32,
    /// Rejections in the current iteration (folded into `rejected_before` by `refine`).
    pub(crate) rejected: RejectCounters,
    pub(crate) rejected_before: Rejections,
    /// Samples and continuations whose weights were clamped to the exact sums' range.
    pub(crate) clamped: EventCount,
    pub(crate) recorded_before: u64,
    pub(crate) spatial_refused: u64,
    pub(crate) directional_refused: u64,
}

impl GuidingField {
    /// A field over `bounds` (the scene's bounding box) that has learned nothing yet: every
    /// distribution is uniform over the sphere until the first [`refine`](Self::refine).
    ///
    /// Fails if `config` is out of range or `bounds` is not a finite box with some extent, or
    /// with an extent too small to partition in `f32` where it lies (a subnormal extent, or one
    /// far below the float spacing at its position).
    ///
    /// # Errors
    ///
    /// A [`ConfigError`] naming the field of `config` that is out of range (see
    /// [`GuidingConfig::validate`]), or `"bounds"` for bounds as described above.
    pub fn new(bounds: Aabb, config: GuidingConfig) -> Result<Self, ConfigError> {
        config.validate()?;
        let extent = bounds.extent();
        let cube = bounds.bounding_cube();
        if !(bounds.min.is_finite() && bounds.max.is_finite() && extent.is_finite())
            || extent.min_element() < 0.0
            || extent.max_element() <= 0.0
            || !SpatialTree::can_partition(cube)
        {
            return Err(ConfigError {
                field: "bounds",
                value: format!("{bounds:?}"),
                requirement: "finite, with min <= max, and an extent that is finite and large \
                              enough to partition in f32 where the box lies",
            });
        }
        let mut root = Region::default();
        root.set_volume(config.volumes.then(Guide::default));
        root.set_signature(config.spatial_split == SpatialSplit::Gain);
        let mut field = Self {
            bounds,
            config,
            spatial: SpatialTree::new(cube),
            regions: vec![root],
            iteration: 0,
            rejected: RejectCounters::default(),
            rejected_before: Rejections::default(),
            clamped: EventCount::default(),
            recorded_before: 0,
            spatial_refused: 0,
            directional_refused: 0,
        };
        field.prepare_recording();
        Ok(field)
    }

    /// Gives the trees what the configured filter records into: pending sums for
    /// [`DirectionalFilter::DeferredBox`](crate::DirectionalFilter::DeferredBox) (refine gives
    /// them to the trees it builds).
    pub(crate) fn prepare_recording(&mut self) {
        if self.config.directional_filter.defers() {
            for r in &mut self.regions {
                r.defer();
            }
        }
    }

    /// Records one sample. Safe to call from any number of threads at once; never blocks.
    ///
    /// A sample that fails [`Sample::check`], or whose position lies outside the bounding cube
    /// by more than 0.1% of its side, is rejected and counted in [`FieldStats::rejected`]; one
    /// just outside is recorded into the nearest cell.
    #[inline]
    pub fn record(&self, sample: &Sample) {
        let _ = self.try_record(sample);
    }

    /// Records one sample like [`record`](Self::record), and says whether it was rejected (a
    /// rejected sample is counted all the same).
    ///
    /// # Errors
    ///
    /// The [`RejectReason`] of a rejected sample (which is counted, as by `record`).
    #[inline]
    pub fn try_record(&self, sample: &Sample) -> Result<(), RejectReason> {
        self.insert(sample)
            .inspect_err(|&reason| self.rejected.count(reason))
    }

    /// Records every sample of a batch on the calling thread, in order (see
    /// [`record`](Self::record)); [`record_batch`](Self::record_batch) records them in
    /// parallel and counts the rejected ones.
    pub fn record_all(&self, samples: &[Sample]) {
        for s in samples {
            self.record(s);
        }
    }

    #[inline]
    fn insert(&self, sample: &Sample) -> Result<(), RejectReason> {
        let square = sample.check()?;
        let p = sample.position;
        if !self.spatial.accepts(p) {
            return Err(RejectReason::OutOfBounds);
        }
        let volume = sample.volume;
        if volume && !self.config.volumes {
            return Err(RejectReason::NoVolumeGuide);
        }
        // The sample's own leaf, and for the spatial filters its extent: one lookup.
        let (home, extent) = match self.config.spatial_filter {
            SpatialFilter::Nearest => (self.spatial.leaf_at(p), Vec3::ZERO),
            SpatialFilter::Stochastic | SpatialFilter::Box => {
                let l = self.spatial.locate(p);
                (l.leaf, l.bounds.extent())
            }
        };
        // One sample in eight tallies its normal (see `quadtree::surfaces`); a medium vertex
        // has none.
        let tallied = sample.normal.filter(|_| !volume).and_then(|n| {
            let priority = tally_priority(p, sample.direction)?;
            Some((crate::sphere::normalize(n)?, priority))
        });
        if let Some((n, priority)) = tallied {
            self.regions[home].record_normal(n, priority);
        }
        let mut value = sample.value;
        let mut clamped = false;
        if let Some(m) = &sample.mixture {
            // The selection belongs to the leaf whose distribution sampled the direction.
            let region = &self.regions[home];
            clamped =
                region.record_selection(volume, m.integrand, m.bsdf_pdf, m.guide_pdf, sample.pdf);
            if self.config.rule == LeafRule::L2Mixture {
                // The region's own pdf is the one the direction was guided with.
                let p_g = f64::from(region.square_pdf(volume, square)) * f64::from(INV_SPHERE_AREA);
                value = mixture_value(m.integrand, m.guide_pdf, p_g, sample.pdf);
            }
        }
        // The second moment without the roulette's added variance, where the sample has one.
        let (w1, w2) = weights(value, sample.pdf);
        let w = (w1, w2 * sample.square_ratio());
        if clamped || w.0.max(w.1) > MAX_TERM {
            self.clamped.count();
        }
        if self.config.spatial_split == SpatialSplit::Gain {
            self.record_signature(p, square, w.1);
        }
        match self.config.spatial_filter {
            SpatialFilter::Nearest => self.insert_directional(home, volume, square, w, true),
            SpatialFilter::Stochastic => {
                let u = sample
                    .jitter
                    .unwrap_or_else(|| hash_jitter(p, sample.direction))
                    .clamp(Vec3::ZERO, Vec3::ONE);
                let moved = self.spatial.cube().clamp(p + (u - 0.5) * extent);
                self.insert_directional(self.spatial.leaf_at(moved), volume, square, w, true);
            }
            SpatialFilter::Box => {
                // The sample counts in its own leaf; its weights spread over the leaf-sized box
                // (clipped to the cube, shares renormalized to the clipped volume).
                let cube = self.spatial.cube();
                let (lo, hi) = (
                    (p - 0.5 * extent).max(cube.min),
                    (p + 0.5 * extent).min(cube.max),
                );
                let size = (hi - lo).max(Vec3::ZERO).as_dvec3().element_product();
                if size <= 0.0 {
                    self.insert_directional(home, volume, square, w, true);
                    return Ok(());
                }
                self.regions[home].count_sample(volume, square, w.1);
                self.spatial.overlapping(lo, hi, |leaf, v| {
                    let share = v / size;
                    let part = (w.0 * share, w.1 * share);
                    self.insert_directional(leaf, volume, square, part, false);
                });
            }
        }
        Ok(())
    }

    /// Records a sample's second-moment weight `w2` at `square` into the split signature of
    /// the leaf at `p` (see [`crate::spatial_split`]). Out of line, with a lookup of its own
    /// (the one that knows the leaf's depth): it costs only fields that split by gain.
    #[inline(never)]
    fn record_signature(&self, p: Vec3, square: Vec2, w2: f64) {
        let leaf = self.spatial.locate(p);
        let (cell, group) = self
            .spatial
            .cell_below(p, leaf.depth, spatial_split::LEVELS);
        self.regions[leaf.leaf].record_signature(cell, group, square, w2);
    }

    /// Records weights `w` at `square` into spatial leaf `leaf`'s surface (or medium,
    /// `volume`) guide through the directional filter; `counted`: as the sample's own record
    /// (see `Region::record`).
    #[inline]
    fn insert_directional(
        &self,
        leaf: usize,
        volume: bool,
        square: Vec2,
        w: (f64, f64),
        counted: bool,
    ) {
        self.regions[leaf].record(volume, self.config.directional_filter, square, w, counted);
    }

    /// Records one traced continuation of a path vertex (see [`Continuation`]), for the
    /// roulette and splitting factors of [`Splitting`](crate::Splitting). Safe to call from
    /// any number of threads at once; never blocks. A continuation that fails
    /// [`Continuation::check`] or lies outside the bounds (as for [`record`](Self::record)) is
    /// rejected and counted in [`FieldStats::rejected`].
    #[inline]
    pub fn record_continuation(&self, continuation: &Continuation) {
        let _ = self.try_record_continuation(continuation);
    }

    /// Records one continuation like [`record_continuation`](Self::record_continuation), and
    /// says whether it was rejected (and counted).
    ///
    /// # Errors
    ///
    /// The [`RejectReason`] of a rejected continuation.
    #[inline]
    pub fn try_record_continuation(&self, c: &Continuation) -> Result<(), RejectReason> {
        c.check()
            .and_then(|()| {
                if self.spatial.accepts(c.position) {
                    Ok(())
                } else {
                    Err(RejectReason::OutOfBounds)
                }
            })
            .map(|()| {
                let region = &self.regions[self.spatial.leaf_at(c.position)];
                if region.record_continuation(c.value, c.cost) {
                    self.clamped.count();
                }
            })
            .inspect_err(|&reason| self.rejected.count(reason))
    }

    /// The continuation estimate of the spatial cell at `position` (the nearest cell's outside
    /// the bounds), for [`Splitting::factor`](crate::Splitting::factor).
    #[inline]
    pub fn continuation(&self, position: Vec3) -> ContinuationEstimate {
        self.regions[self.spatial.leaf_at(position)].continuation()
    }

    /// The directional distribution to sample at `position`. Positions outside the bounds get
    /// the nearest cell's distribution, so a renderer always receives a valid one.
    #[inline]
    pub fn distribution(&self, position: Vec3) -> DirectionalDistribution<'_> {
        self.regions[self.spatial.leaf_at(position)].distribution()
    }

    /// The directional distribution to sample at `position` inside a participating medium:
    /// the guide learned from medium samples ([`Sample::volume`]), whose product with the
    /// phase function [`with_phase`](DirectionalDistribution::with_phase) gives, and whose
    /// [`guide_probability`](DirectionalDistribution::guide_probability) is the learned
    /// guide-vs-phase-function one. In a field without
    /// [`volumes`](GuidingConfig::volumes): the uniform distribution with guide probability 0
    /// (sample the phase function alone). Positions outside the bounds get the nearest cell's.
    ///
    /// ```
    /// use sdguide::{Aabb, GuidingConfig, GuidingField};
    /// use glam::{Vec2, Vec3};
    /// let config = GuidingConfig { volumes: true, ..GuidingConfig::default() };
    /// let field = GuidingField::new(Aabb::new(Vec3::ZERO, Vec3::ONE), config)?;
    /// // A ray travelling along +x scatters at the centre, in fog with g = 0.8.
    /// let fog = field.volume_distribution(Vec3::splat(0.5)).with_phase(Vec3::X, 0.8);
    /// let (direction, pdf) = fog.sample(Vec2::new(0.3, 0.6));
    /// assert_eq!(pdf, fog.pdf(direction));
    /// // Forward scattering: ahead is far likelier than behind.
    /// assert!(fog.pdf(Vec3::X) > 100.0 * fog.pdf(-Vec3::X));
    /// # Ok::<(), sdguide::ConfigError>(())
    /// ```
    #[inline]
    pub fn volume_distribution(&self, position: Vec3) -> DirectionalDistribution<'_> {
        self.regions[self.spatial.leaf_at(position)].volume_distribution()
    }

    /// Ends an iteration. Every spatial leaf turns its recorded moments into its next sampling
    /// distribution (by [`GuidingConfig::rule`]) and its next directional topology (split and
    /// collapse by [`GuidingConfig::refinement`], in parallel over leaves); then spatial leaves
    /// that received more than `c·sqrt(2^k)` samples in iteration `k` split, the children
    /// starting from copies of the parent's new distribution. Statistics restart for the next
    /// iteration. A leaf that recorded nothing keeps its distribution.
    pub fn refine(&mut self) {
        let c = &self.config;
        // The memory budget binds the directional trees too: what the spatial tree and the
        // trees' fixed parts leave of it, shared evenly, caps each tree's interior nodes.
        let deferred = c.directional_filter.defers();
        let regions = self.regions.len() as u64;
        let (trees, volume_bytes) = if c.volumes {
            (2 * regions, Region::fixed_volume_bytes(deferred))
        } else {
            (regions, 0)
        };
        let signature_bytes = if c.spatial_split == SpatialSplit::Gain {
            spatial_split::SIGNATURE_BYTES
        } else {
            0
        };
        let fixed = self.spatial.bytes() as u64
            + regions * (Region::fixed_bytes(deferred) + volume_bytes + signature_bytes);
        let per_tree =
            c.max_memory_bytes.saturating_sub(fixed) / (trees * bytes_per_node(deferred));
        let max_nodes = c.max_directional_nodes.min(per_tree.max(1) as u32);
        let params = StepParams::new(c, self.iteration, max_nodes);
        let outcomes: Vec<RefineOutcome> = self
            .regions
            .par_iter_mut()
            .map_init(RefineScratch::default, |scratch, r| {
                r.refine(&params, scratch)
            })
            .collect();
        let recorded = outcomes
            .iter()
            .fold(0u64, |a, o| a.saturating_add(o.samples));
        self.recorded_before = self.recorded_before.saturating_add(recorded);
        self.rejected_before = self.rejected_before.plus(&self.rejected.take());
        self.clamped.end_iteration();
        self.directional_refused += outcomes.iter().map(|o| o.refused).sum::<u64>();
        self.fit_surface_products();

        let c = &self.config;
        let threshold = params.spatial_threshold;
        let plans: Vec<SplitPlan> = outcomes
            .iter()
            .map(|o| {
                o.plan
                    .unwrap_or_else(|| SplitPlan::by_count(o.samples, threshold))
            })
            .collect();
        let budget = c.max_memory_bytes;
        let mut bytes = self.bytes();
        let regions = &mut self.regions;
        self.spatial_refused +=
            self.spatial
                .split(&plans, threshold, c.max_spatial_nodes as usize, |leaf| {
                    let cost = (regions[leaf].bytes() + 2 * size_of::<u32>()) as u64;
                    if bytes + cost > budget {
                        return None;
                    }
                    bytes += cost;
                    regions.push(regions[leaf].clone());
                    Some(regions.len() - 1)
                });
        self.iteration += 1;
    }

    /// Drops stored surface products, the largest first, while the field's footprint exceeds
    /// the memory budget: they only speed queries up (a query without one takes the per-query
    /// product, the same distribution), so they give way before the guide does.
    fn fit_surface_products(&mut self) {
        let mut over = self.bytes().saturating_sub(self.config.max_memory_bytes);
        if over == 0 {
            return;
        }
        let mut order: Vec<usize> = (0..self.regions.len()).collect();
        order.sort_by_key(|&i| std::cmp::Reverse(self.regions[i].surface_bytes()));
        for i in order {
            if over == 0 {
                break;
            }
            let freed = self.regions[i].drop_surface_products() as u64;
            over = over.saturating_sub(freed);
        }
    }

    /// Size, depth and bookkeeping of the field.
    pub fn stats(&self) -> FieldStats {
        let leaves = self.spatial.leaves();
        let mut s = FieldStats {
            iteration: self.iteration,
            spatial_nodes: self.spatial.node_count() as u64,
            spatial_leaves: leaves.len() as u64,
            spatial_depth: leaves.iter().map(|l| l.depth).max().unwrap_or(0),
            rejected: self.rejected_before.plus(&self.rejected.get()),
            clamped_samples: self.clamped.total(),
            spatial_splits_refused: self.spatial_refused,
            directional_splits_refused: self.directional_refused,
            bytes: self.bytes(),
            ..FieldStats::default()
        };
        for r in &self.regions {
            r.add_stats(&mut s);
        }
        s.samples_recorded_total = self.recorded_before.saturating_add(s.samples_recorded);
        s
    }

    /// The spatial leaf whose distribution [`distribution`](Self::distribution) returns at
    /// `position`, for inspection.
    pub fn cell_at(&self, position: Vec3) -> SpatialCell<'_> {
        let l = self.spatial.locate(position);
        SpatialCell {
            bounds: l.bounds,
            depth: l.depth,
            region: &self.regions[l.leaf],
        }
    }

    /// Every spatial leaf, for inspection: its box, its distribution and what it has recorded.
    pub fn cells(&self) -> impl Iterator<Item = SpatialCell<'_>> {
        self.spatial.leaves().into_iter().map(|l| SpatialCell {
            bounds: l.bounds,
            depth: l.depth,
            region: &self.regions[l.leaf],
        })
    }

    /// The box the field was created with.
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// The configuration the field runs with.
    pub fn config(&self) -> &GuidingConfig {
        &self.config
    }

    /// Completed iterations (calls to [`refine`](Self::refine)).
    pub fn iteration(&self) -> u32 {
        self.iteration
    }

    fn bytes(&self) -> u64 {
        (self.spatial.bytes() + self.regions.iter().map(Region::bytes).sum::<usize>()) as u64
    }
}

/// A spatial leaf, as [`GuidingField::cells`] shows it.
#[derive(Clone, Copy, Debug)]
pub struct SpatialCell<'a> {
    /// The leaf's box.
    pub bounds: Aabb,
    /// Its depth in the spatial tree (the root is 0).
    pub depth: u32,
    region: &'a Region,
}

impl<'a> SpatialCell<'a> {
    /// The distribution queries at positions in this cell receive.
    pub fn distribution(&self) -> DirectionalDistribution<'a> {
        self.region.distribution()
    }

    /// The leaves of the current iteration's recording topology and their moments. Under
    /// [`DirectionalFilter::DeferredBox`](crate::DirectionalFilter::DeferredBox) the sums still
    /// pending are spread first, so the moments
    /// hold every recorded sample's filtered share.
    pub fn recorded(&self) -> Vec<(DirectionalCell, Moments)> {
        self.region.recorded()
    }
}
