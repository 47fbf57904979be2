//! The path recorder's backward pass: every vertex's incident radiance, cost and first roulette
//! from its events and its children's, and the records they make.

use super::vertex::{PathRecord, VertexId};
use super::{Event, EventKind, Kind, NONE, PathRecorder, luminance};
use crate::sample::Sample;
use crate::splitting::Continuation;
use glam::Vec3;

/// The first roulette below a vertex's direction and what arrived before it, in the vertex's
/// units; `None` where none is tracked (none was played, or a split came first).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct FirstRoulette(Option<(Vec3, f32, bool)>);

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

impl PathRecorder {
    pub(super) fn record_of(&self, i: u32) -> Option<PathRecord> {
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
            normal: v.normal.filter(|_| !v.volume),
            second_moment: Some(node.first_roulette.second_moment(value)),
            volume: v.volume,
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

    /// Computes vertex `i`'s incident radiance, cost and first roulette from its events and
    /// its children's results, in the order the events happened.
    pub(super) fn settle(&mut self, i: usize) {
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
    pub(super) fn walk(&mut self) {
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
