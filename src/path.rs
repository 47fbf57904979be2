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
//! Second moments without roulette (see [`Sample::second_moment`]) need the first roulette
//! below each vertex and what arrived before it: the recorder finds it from the same events.

use crate::field::GuidingField;
use crate::sample::Sample;
use crate::splitting::{Continuation, ContinuationEstimate, Splitting};
use glam::Vec3;

/// The Rec. 709 luminance of an RGB radiance: the scalar the recorder records.
#[inline]
pub(crate) fn luminance(rgb: Vec3) -> f32 {
    rgb.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

/// A handle to one vertex of the path being recorded, returned by [`PathRecorder::start`] (the
/// camera ray) and [`PathRecorder::push`]. Valid until the next `start`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct VertexId(u32);

impl VertexId {
    /// The handle whose [`index`](Self::index) is `index` (for bindings that pass handles as
    /// integers). A handle the recorder did not hand out in the current path is ignored by
    /// every call, and counted in [`PathRecorderStats::bad_values`].
    pub fn from_index(index: u32) -> Self {
        VertexId(index)
    }

    /// Where the vertex sits in the order of pushes (the camera ray is 0): an index for a
    /// renderer that keeps data of its own beside the recorder's.
    pub fn index(self) -> usize {
        self.0 as usize
    }
}

/// A scattering vertex as the renderer pushes it: where it is, the direction it drew, and the
/// weight that direction carries.
///
/// ```
/// use sdguide::PathVertex;
/// use sdguide::glam::Vec3;
/// let v = PathVertex::new(Vec3::ZERO, Vec3::Y, Vec3::splat(0.25), 0.5)
///     .with_normal(Vec3::Y)
///     .with_mixture(0.3, 0.7);
/// assert_eq!(v.pdfs.map(|p| p.guide), Some(0.7));
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PathVertex {
    /// The vertex (world space).
    pub position: Vec3,
    /// Its shading normal, the one passed to
    /// [`at_surface`](crate::DirectionalDistribution::at_surface) there, facing the side the
    /// path arrived from (`None`: recorded without one).
    pub normal: Option<Vec3>,
    /// The direction drawn, pointing away from `position` (any length).
    pub direction: Vec3,
    /// `f·|cos θ|` toward `direction`, per channel: the BSDF times the cosine, 0 where the
    /// BSDF is (below the surface).
    pub bsdf: Vec3,
    /// The density `direction` was drawn with: the mixture's `q = a·p_guide + (1 − a)·p_bsdf`
    /// where the renderer mixes, finite and positive.
    pub pdf: f32,
    /// The two techniques' pdfs of `direction` when the renderer sampled the one-sample
    /// mixture: what the cell's guide probability learns from (see [`Sample::with_mixture`]).
    pub pdfs: Option<TechniquePdfs>,
}

/// The BSDF's and the guide's pdfs of a direction drawn from their mixture.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TechniquePdfs {
    /// The BSDF sampling pdf (solid angle).
    pub bsdf: f32,
    /// The guide's pdf: the product's where the renderer samples
    /// [`at_surface`](crate::DirectionalDistribution::at_surface), the plain one otherwise.
    pub guide: f32,
}

impl PathVertex {
    /// A vertex at `position` that drew `direction` with density `pdf`, where the BSDF times
    /// the cosine is `bsdf`.
    pub const fn new(position: Vec3, direction: Vec3, bsdf: Vec3, pdf: f32) -> Self {
        PathVertex {
            position,
            normal: None,
            direction,
            bsdf,
            pdf,
            pdfs: None,
        }
    }

    /// The vertex with its shading normal.
    pub const fn with_normal(mut self, normal: Vec3) -> Self {
        self.normal = Some(normal);
        self
    }

    /// The vertex with the BSDF's and the guide's pdfs of its direction.
    pub const fn with_mixture(mut self, bsdf_pdf: f32, guide_pdf: f32) -> Self {
        self.pdfs = Some(TechniquePdfs {
            bsdf: bsdf_pdf,
            guide: guide_pdf,
        });
        self
    }

    fn is_valid(&self) -> bool {
        let weight = |w: Vec3| w.is_finite() && w.min_element() >= 0.0;
        let pdf = |p: f32| p.is_finite() && p >= 0.0;
        self.position.is_finite()
            && self.direction.is_finite()
            && self.direction != Vec3::ZERO
            && weight(self.bsdf)
            && self.pdf.is_finite()
            && self.pdf > 0.0
            && (self.bsdf / self.pdf).is_finite()
            && self.pdfs.is_none_or(|p| pdf(p.bsdf) && pdf(p.guide))
    }
}

/// What a finished path recorded at one vertex: its training sample and its continuation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathRecord {
    /// The vertex.
    pub id: VertexId,
    /// The radiance's luminance that arrived along its direction, the direction's pdf, its
    /// normal, mixture terms and second moment without roulette.
    pub sample: Sample,
    /// The light the vertex reflected through this direction, `f·cos·L_i/q` (its own split
    /// weight not included), and what tracing it cost: for roulette and splitting.
    pub continuation: Continuation,
}

/// The recorder's counts of bad input, since it was created. Bad input never panics: it is
/// dropped and counted here.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PathRecorderStats {
    /// Paths finished.
    pub paths: u64,
    /// Vertices pushed with a non-finite position or direction, a zero direction, a negative
    /// or non-finite `bsdf`, a pdf that is not finite and positive (or so small that
    /// `bsdf/pdf` overflows), or technique pdfs that are negative or not finite: kept in the path so
    /// that the handles stay valid, but they record nothing and pass nothing to the vertex
    /// before them.
    pub bad_vertices: u64,
    /// Radiance, costs, roulette probabilities or split factors that were negative or not
    /// finite (or a probability not in `(0, 1]`, a factor not positive): ignored.
    pub bad_values: u64,
    /// Vertices refused because the path already held [`PathRecorder::max_vertices`]:
    /// the handle returned for them is the path's overflow sink, which drops what it is given.
    pub dropped_vertices: u64,
    /// Paths that overflowed: they record nothing (their values would lack what the dropped
    /// vertices gathered), and their estimate lacks it too.
    pub truncated_paths: u64,
    /// Vertices where [`PathRecorder::factor`] gave a splitting factor.
    pub factors: u64,
    /// Vertices where it gave none (the cell had too few continuations, or the image terms
    /// were missing): the renderer played its own roulette there.
    pub no_factor: u64,
}

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
/// - [`split`](Self::split)`(v, q, n)`: at the vertex the ray of `v` reached, `n`
///   continuations are traced for a splitting factor `q` (`E[n] = q`, as
///   [`continuations`](crate::continuations) rounds it); each one pushed after this weighs
///   `1/q`. Efficiency-aware roulette is a split with `q < 1`.
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

/// The first roulette below a vertex's direction and what arrived before it, in the vertex's
/// units; `None` where none is tracked (none was played, or a split came first).
#[derive(Clone, Copy, Debug, Default)]
struct FirstRoulette(Option<(Vec3, f32, bool)>);

impl FirstRoulette {
    /// The estimate of `value²` without the roulette (see [`Sample::second_moment`]).
    fn second_moment(self, value: f32) -> f32 {
        let Some((before, s, survived)) = self.0 else {
            return value * value;
        };
        let a = luminance(before);
        if s >= 1.0 {
            return value * value;
        }
        if !survived {
            return a * a;
        }
        let y = a + s * (value - a);
        ((y * y - (1.0 - s) * a * a) / s).max(0.0)
    }
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

    fn record_of(&self, i: u32) -> Option<PathRecord> {
        let node = &self.nodes[i as usize];
        if !matches!(node.kind, Kind::Scatter) {
            return None;
        }
        let v = &node.vertex;
        let value = luminance(node.incident);
        let mut sample = Sample {
            position: v.position,
            direction: v.direction,
            value,
            pdf: v.pdf,
            normal: v.normal,
            second_moment: Some(node.first_roulette.second_moment(value)),
            ..Sample::default()
        };
        if let Some(p) = v.pdfs {
            sample = sample.with_mixture(luminance(v.bsdf * node.incident), p.bsdf, p.guide);
        }
        Some(PathRecord {
            id: VertexId(i),
            sample,
            continuation: Continuation {
                position: v.position,
                value: luminance(node.factor * node.incident),
                cost: node.cost,
            },
        })
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

    /// Computes vertex `i`'s incident radiance, cost and first roulette from its events and
    /// its children's results, in the order the events happened.
    fn settle(&mut self, i: usize) {
        self.scopes.clear();
        self.scopes.push((Vec3::ZERO, 1.0));
        let mut cost = self.nodes[i].own_cost;
        // The first roulette below the vertex: the radiance before it, and whether the search
        // is over.
        let (mut before, mut first, mut searching) = (Vec3::ZERO, FirstRoulette(None), true);
        let mut e = self.nodes[i].first_event;
        while e != NONE {
            let Event { kind, next } = self.events[e as usize];
            e = next;
            match kind {
                EventKind::Radiance(l) => {
                    self.top().0 += l;
                    if searching {
                        before += l;
                    }
                }
                EventKind::Roulette {
                    probability,
                    survived,
                } => {
                    self.scopes.push((Vec3::ZERO, probability));
                    if searching {
                        first = FirstRoulette(Some((before, probability, survived)));
                        searching = false;
                    }
                }
                EventKind::Split { factor, traced } => {
                    if searching && factor != 1.0 {
                        if factor < 1.0 {
                            first = FirstRoulette(Some((before, factor, traced > 0)));
                        }
                        searching = false;
                    }
                }
                EventKind::Child(c) => {
                    let child = self.nodes[c as usize];
                    cost += child.cost;
                    if matches!(child.kind, Kind::Bad) {
                        searching = false;
                        continue;
                    }
                    let reflected = child.factor * child.incident;
                    let (weight, below) = (child.weight, child.first_roulette);
                    self.top().0 += weight * reflected;
                    if searching {
                        // A continuation of weight 1: the first roulette below it, seen from
                        // here. (Where a split weighed it, the search ended at the split.)
                        let factor = child.factor;
                        first = FirstRoulette(below.0.map(|(b, p, s)| (before + factor * b, p, s)));
                        searching = false;
                    }
                }
            }
        }
        // Innermost scope first: each one's sum over its roulette's probability joins the
        // scope around it.
        let (mut incident, mut p) = self.scopes.pop().unwrap_or((Vec3::ZERO, 1.0));
        while let Some((sum, outer)) = self.scopes.pop() {
            incident = sum + incident / p;
            p = outer;
        }
        let node = &mut self.nodes[i];
        node.incident = incident;
        node.cost = cost;
        node.first_roulette = first;
    }

    fn top(&mut self) -> &mut (Vec3, f32) {
        let last = self.scopes.len() - 1;
        &mut self.scopes[last]
    }

    /// The records' order: a depth-first walk from the camera ray, each vertex after its
    /// children.
    fn walk(&mut self) {
        self.order.clear();
        self.stack.clear();
        self.stack.push((0, self.nodes[0].first_event));
        while let Some(&mut (node, ref mut e)) = self.stack.last_mut() {
            let mut child = None;
            while *e != NONE && child.is_none() {
                let event = self.events[*e as usize];
                *e = event.next;
                if let EventKind::Child(c) = event.kind {
                    child = Some(c);
                }
            }
            match child {
                Some(c) => self.stack.push((c, self.nodes[c as usize].first_event)),
                None => {
                    self.order.push(node);
                    self.stack.pop();
                }
            }
        }
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
            first_roulette: FirstRoulette(None),
        }
    }
}
