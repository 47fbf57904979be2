//! The path recorder: a camera sample's vertices as the renderer traces them, and what each
//! records once the sample is done.
//!
//! A vertex's training sample is the radiance that arrived along its sampled direction, and
//! that is known only when the path below it is finished: every later emission and next-event
//! contribution, times the later vertices' `f·cos/q` and the later roulettes' and splits'
//! weights. The recorder keeps the events in the order the renderer reports them and, at
//! [`PathRecorder::finish`], propagates them backward — children before parents, each
//! vertex's events in their order, with the same floating-point operations a recursive
//! integrator performs — so that a renderer needs no bookkeeping of its own. The vertices form
//! a tree: a renderer that splits pushes several continuations from one vertex.
//!
//! Second moments without roulette (see [`Sample::second_moment`](crate::Sample::second_moment)) need the first roulette
//! below each vertex and what arrived before it: the recorder finds it from the same events.
//!
//! `vertex` holds what goes in and comes out (`PathVertex`, `PathRecord`, the counts of bad
//! input); this file the recorder and its storage; `propagate` the backward pass at `finish`.

mod propagate;
mod vertex;

use crate::field::GuidingField;
use crate::splitting::{ContinuationEstimate, Splitting};
use glam::Vec3;
use propagate::FirstRoulette;
pub(crate) use vertex::luminance;
pub use vertex::{PathRecord, PathRecorderStats, PathVertex, TechniquePdfs, VertexId};

/// A camera sample's path, recorded vertex by vertex, and the training samples and
/// continuations it yields once done. One per render thread, reused for every camera sample:
/// after the first paths it allocates nothing.
///
/// The renderer reports, in the order they happen:
///
/// - [`start`](Self::start): a new camera sample; the handle it returns stands for the
///   camera ray.
/// - [`add_radiance`](Self::add_radiance)`(v, L)`: radiance `L` arriving at `v` along its
///   direction — emission the ray of `v` hit (with its MIS weight), and the next-event
///   contributions at the vertex that ray reached (`f·L_e·w/p_light` there). Not multiplied by
///   anything before it: the recorder applies the path's weights.
/// - [`push`](Self::push)`(v, vertex)`: at the vertex that the ray of `v` reached, a direction
///   was drawn; the new handle stands for that direction's ray. Push also directions that
///   end at once (below the surface, `bsdf` zero): they record value 0, which is what keeps
///   the guide from sampling there.
/// - [`roulette`](Self::roulette)`(v, p, survived)`: the path along `v` went on with
///   probability `p`; what arrives at `v` after this weighs `1/p`.
/// - [`split`](Self::split)`(v, k, n)`: at the vertex the ray of `v` reached, `n`
///   continuations are traced for a splitting factor `k` (`E[n] = k`, as
///   [`continuations`](crate::continuations) rounds it); each one pushed after this weighs
///   `1/k`. Efficiency-aware roulette is a split with `k < 1`. (`q` is the mixture pdf.)
/// - [`add_cost`](Self::add_cost)`(v, c)`: rays (or any cost unit) traced for `v`; a
///   continuation's cost is its subtree's.
/// - [`finish`](Self::finish): the camera sample's estimate; then
///   [`record`](Self::record) (or [`records`](Self::records) for another consumer).
///
/// ```
/// use sdguide::glam::Vec3;
/// use sdguide::{Aabb, GuidingConfig, GuidingField, PathRecorder, PathVertex};
/// let field = GuidingField::new(Aabb::new(Vec3::ZERO, Vec3::ONE), GuidingConfig::default())?;
/// let mut path = PathRecorder::new();
/// let camera = path.start();
/// // The camera ray hits a diffuse floor; the renderer draws a direction there (pdf 0.5,
/// // f·cos 0.2) and plays throughput roulette on it, which it survives with p = 0.4.
/// let v = path.push(camera, PathVertex::new(Vec3::splat(0.5), Vec3::Y, Vec3::splat(0.2), 0.5));
/// path.roulette(v, 0.4, true);
/// path.add_radiance(v, Vec3::splat(3.0)); // it hits a lamp
/// let estimate = path.finish();
/// assert!((estimate - Vec3::splat(0.2 / 0.5 * 3.0 / 0.4)).abs().max_element() < 1e-6);
/// let record = path.records().next().unwrap();
/// assert!((record.sample.value - 7.5).abs() < 1e-6); // 3 / 0.4
/// assert_eq!(path.record(&field), 1);
/// # Ok::<(), sdguide::ConfigError>(())
/// ```
#[derive(Clone, Debug)]
pub struct PathRecorder {
    nodes: Vec<Node>,
    events: Vec<Event>,
    /// Scratch of [`finish`](Self::finish): the open roulette scopes of a vertex.
    scopes: Vec<(Vec3, f32)>,
    /// Scratch of [`finish`](Self::finish): the depth-first walk; then the vertices in the
    /// order their records come out (children before parents, siblings in push order).
    stack: Vec<(u32, u32)>,
    order: Vec<u32>,
    max_vertices: usize,
    overflowed: bool,
    finished: bool,
    stats: PathRecorderStats,
}

/// Where no event follows.
const NONE: u32 = u32::MAX;
/// The handle the recorder returns past its capacity: everything sent to it is dropped.
const SINK: VertexId = VertexId(u32::MAX);

#[derive(Clone, Copy, Debug)]
enum Kind {
    Camera,
    Scatter,
    /// A delta vertex (a specular bounce): passes its weight on, records nothing.
    Delta,
    /// A vertex pushed with bad input: passes nothing on, records nothing.
    Bad,
}

#[derive(Clone, Copy, Debug)]
struct Node {
    kind: Kind,
    vertex: PathVertex,
    /// `f·cos/q` (or a delta vertex's weight): what the vertex multiplies its arrivals by.
    factor: Vec3,
    /// The split weight `1/q` its parent applied to it.
    weight: f32,
    /// The split weight the vertex applies to continuations pushed from it from now on.
    split_weight: f32,
    first_event: u32,
    last_event: u32,
    own_cost: f32,
    // What `finish` computes.
    incident: Vec3,
    cost: f32,
    first_roulette: FirstRoulette,
}

#[derive(Clone, Copy, Debug)]
enum EventKind {
    Radiance(Vec3),
    Child(u32),
    Roulette { probability: f32, survived: bool },
    Split { factor: f32, traced: u32 },
}

#[derive(Clone, Copy, Debug)]
struct Event {
    kind: EventKind,
    next: u32,
}

impl Default for PathRecorder {
    fn default() -> Self {
        Self::new()
    }
}

impl PathRecorder {
    /// Vertices a path holds by default before it overflows.
    pub const DEFAULT_MAX_VERTICES: usize = 4096;

    /// An empty recorder holding up to [`DEFAULT_MAX_VERTICES`](Self::DEFAULT_MAX_VERTICES)
    /// vertices per path.
    pub fn new() -> Self {
        Self::with_max_vertices(Self::DEFAULT_MAX_VERTICES)
    }

    /// An empty recorder holding up to `max_vertices` vertices per path (the camera ray
    /// included; at least 1, at most `2³² − 2`); set it to what one camera sample of the
    /// renderer can push, splits included.
    pub fn with_max_vertices(max_vertices: usize) -> Self {
        PathRecorder {
            nodes: Vec::new(),
            events: Vec::new(),
            scopes: Vec::new(),
            stack: Vec::new(),
            order: Vec::new(),
            max_vertices: max_vertices.clamp(1, (u32::MAX - 1) as usize),
            overflowed: false,
            finished: false,
            stats: PathRecorderStats::default(),
        }
    }

    /// Vertices a path holds before it overflows.
    pub fn max_vertices(&self) -> usize {
        self.max_vertices
    }

    /// The counts of bad input so far.
    pub fn stats(&self) -> PathRecorderStats {
        self.stats
    }

    /// Starts a new camera sample (dropping the last one's vertices) and returns the handle
    /// of its camera ray.
    pub fn start(&mut self) -> VertexId {
        self.nodes.clear();
        self.events.clear();
        self.overflowed = false;
        self.finished = false;
        self.nodes
            .push(Node::new(Kind::Camera, PathVertex::default()));
        VertexId(0)
    }

    /// Radiance `radiance` arriving at `at` along its direction (per channel, non-negative
    /// and finite; otherwise ignored and counted).
    pub fn add_radiance(&mut self, at: VertexId, radiance: Vec3) {
        if !(radiance.is_finite() && radiance.min_element() >= 0.0) {
            self.stats.bad_values += 1;
            return;
        }
        self.event(at, EventKind::Radiance(radiance));
    }

    /// A cost `cost` (rays, say) spent tracing for `at` (finite and non-negative; otherwise
    /// ignored and counted).
    pub fn add_cost(&mut self, at: VertexId, cost: f32) {
        if !(cost.is_finite() && cost >= 0.0) {
            self.stats.bad_values += 1;
            return;
        }
        if let Some(node) = self.node_mut(at) {
            node.own_cost += cost;
        }
    }

    /// A direction drawn at the vertex the ray of `from` reached; returns its handle. A vertex
    /// with bad input is kept (and counted) but records nothing and passes nothing on; past
    /// [`max_vertices`](Self::max_vertices) the handle is the overflow sink.
    pub fn push(&mut self, from: VertexId, vertex: PathVertex) -> VertexId {
        let kind = if vertex.is_valid() {
            Kind::Scatter
        } else {
            self.stats.bad_vertices += 1;
            Kind::Bad
        };
        self.push_node(from, Node::new(kind, vertex))
    }

    /// A delta vertex (a perfectly specular bounce or a pass through a smooth dielectric) at
    /// the vertex the ray of `from` reached, with weight `weight` (`f/p` per channel,
    /// non-negative and finite): it passes `weight` times what arrives along it on to `from`,
    /// and records nothing, since no guide can sample a delta lobe. A renderer whose delta
    /// vertices have weight 1 may instead keep adding to `from`.
    pub fn push_delta(&mut self, from: VertexId, position: Vec3, weight: Vec3) -> VertexId {
        let valid = weight.is_finite() && weight.min_element() >= 0.0 && position.is_finite();
        let mut node = Node::new(
            if valid { Kind::Delta } else { Kind::Bad },
            PathVertex {
                position,
                ..PathVertex::default()
            },
        );
        if valid {
            node.factor = weight;
        } else {
            self.stats.bad_vertices += 1;
        }
        self.push_node(from, node)
    }

    /// Russian roulette on the path along `at`: it went on with probability `probability`
    /// (in `(0, 1]`; otherwise ignored and counted) if `survived`, else it ended there. What
    /// arrives at `at` afterwards weighs `1/probability`.
    pub fn roulette(&mut self, at: VertexId, probability: f32, survived: bool) {
        if !(probability > 0.0 && probability <= 1.0) {
            self.stats.bad_values += 1;
            return;
        }
        if probability < 1.0 {
            self.event(
                at,
                EventKind::Roulette {
                    probability,
                    survived,
                },
            );
        }
    }

    /// Roulette or splitting at the vertex the ray of `at` reached: `traced` continuations for
    /// the factor `factor` (finite and positive; otherwise ignored and counted), each pushed
    /// after this call weighing `1/factor`.
    pub fn split(&mut self, at: VertexId, factor: f32, traced: u32) {
        if !(factor.is_finite() && factor > 0.0) {
            self.stats.bad_values += 1;
            return;
        }
        let Some(node) = self.node_mut(at) else {
            return;
        };
        node.split_weight = 1.0 / factor;
        self.event(at, EventKind::Split { factor, traced });
    }

    /// [`Splitting::factor`] at a vertex (see there), counted in
    /// [`stats`](Self::stats): `factors` where it gives one, `no_factor` where it does not.
    pub fn factor(
        &mut self,
        policy: &Splitting,
        estimate: &ContinuationEstimate,
        throughput: f32,
        pixel: f32,
    ) -> Option<f32> {
        let q = policy.factor(estimate, throughput, pixel);
        match q {
            Some(_) => self.stats.factors += 1,
            None => self.stats.no_factor += 1,
        }
        q
    }

    /// Ends the camera sample: computes every vertex's incident radiance, second moment and
    /// continuation, and returns the camera sample's estimate (the radiance arriving along the
    /// camera ray, every weight applied).
    pub fn finish(&mut self) -> Vec3 {
        if self.nodes.is_empty() {
            return Vec3::ZERO;
        }
        if !self.finished {
            self.finished = true;
            self.stats.paths += 1;
            if self.overflowed {
                self.stats.truncated_paths += 1;
            }
            // Children come after their parents: backward, every child is done before its
            // parent reads it.
            for i in (0..self.nodes.len()).rev() {
                self.settle(i);
            }
            self.walk();
        }
        self.nodes[0].incident
    }

    /// What the finished path recorded, vertex by vertex (children before parents, siblings
    /// in the order they were pushed); nothing before [`finish`](Self::finish), nothing for a
    /// path that overflowed, for the camera ray, for delta vertices or for bad ones.
    pub fn records(&self) -> impl Iterator<Item = PathRecord> + '_ {
        let live = self.finished && !self.overflowed;
        self.order
            .iter()
            .filter(move |_| live)
            .filter_map(|&i| self.record_of(i))
    }

    /// Records the finished path into `field`: every vertex's sample and its continuation
    /// (see [`records`](Self::records)). Returns how many vertices it recorded.
    pub fn record(&self, field: &GuidingField) -> usize {
        self.records()
            .map(|r| {
                field.record(&r.sample);
                field.record_continuation(&r.continuation);
            })
            .count()
    }

    fn node_mut(&mut self, at: VertexId) -> Option<&mut Node> {
        if self.finished || at == SINK {
            return None;
        }
        if at.index() >= self.nodes.len() {
            self.stats.bad_values += 1;
            return None;
        }
        self.nodes.get_mut(at.index())
    }

    fn push_node(&mut self, from: VertexId, mut node: Node) -> VertexId {
        if from == SINK && self.overflowed && !self.finished {
            // Below a dropped vertex: dropped too.
            self.stats.dropped_vertices += 1;
            return SINK;
        }
        let Some(parent) = self.node_mut(from) else {
            return SINK;
        };
        node.weight = parent.split_weight;
        if self.nodes.len() >= self.max_vertices {
            self.overflowed = true;
            self.stats.dropped_vertices += 1;
            return SINK;
        }
        let id = self.nodes.len() as u32;
        self.nodes.push(node);
        self.event(from, EventKind::Child(id));
        VertexId(id)
    }

    fn event(&mut self, at: VertexId, kind: EventKind) {
        if self.node_mut(at).is_none() {
            return;
        }
        let id = self.events.len() as u32;
        self.events.push(Event { kind, next: NONE });
        let node = &mut self.nodes[at.index()];
        match node.last_event {
            NONE => node.first_event = id,
            last => self.events[last as usize].next = id,
        }
        node.last_event = id;
    }
}

impl Node {
    fn new(kind: Kind, vertex: PathVertex) -> Self {
        let factor = match kind {
            Kind::Scatter => vertex.bsdf / vertex.pdf,
            Kind::Bad => Vec3::ZERO,
            Kind::Camera | Kind::Delta => Vec3::ONE,
        };
        Node {
            kind,
            vertex,
            factor,
            weight: 1.0,
            split_weight: 1.0,
            first_event: NONE,
            last_event: NONE,
            own_cost: 0.0,
            incident: Vec3::ZERO,
            cost: 0.0,
            first_roulette: FirstRoulette::default(),
        }
    }
}
