//! A bounding volume hierarchy over the scene's shapes: binary, built by splitting at the median
//! centroid along the widest axis, traversed front to back with an explicit stack.

use crate::geometry::{Ray, Shape};
use glam::Vec3;

#[derive(Clone, Copy, Debug)]
struct Node {
    lo: Vec3,
    hi: Vec3,
    /// Leaf: first shape index; interior: index of the second child (the first follows).
    offset: u32,
    /// Leaf: number of shapes (> 0); interior: 0.
    count: u16,
    /// Interior: the split axis.
    axis: u16,
}

/// The hierarchy. Shape indices refer to the slice it was built over.
#[derive(Clone, Debug)]
pub struct Bvh {
    nodes: Vec<Node>,
    order: Vec<u32>,
}

const LEAF_SIZE: usize = 2;

impl Bvh {
    /// Builds the hierarchy over `shapes`.
    pub fn new(shapes: &[Shape]) -> Self {
        let mut bvh = Bvh {
            nodes: Vec::with_capacity(2 * shapes.len()),
            order: (0..shapes.len() as u32).collect(),
        };
        if !shapes.is_empty() {
            let bounds: Vec<(Vec3, Vec3)> = shapes.iter().map(Shape::bounds).collect();
            let mut order = std::mem::take(&mut bvh.order);
            bvh.build(&bounds, &mut order, 0);
            bvh.order = order;
        }
        bvh
    }

    fn build(&mut self, bounds: &[(Vec3, Vec3)], items: &mut [u32], first: usize) -> usize {
        let (lo, hi) = items.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), &i| (lo.min(bounds[i as usize].0), hi.max(bounds[i as usize].1)),
        );
        let index = self.nodes.len();
        self.nodes.push(Node {
            lo,
            hi,
            offset: first as u32,
            count: items.len() as u16,
            axis: 0,
        });
        if items.len() <= LEAF_SIZE {
            return index;
        }
        let centroid = |i: u32| {
            let (l, h) = bounds[i as usize];
            (l + h) * 0.5
        };
        let (clo, chi) = items.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), &i| (lo.min(centroid(i)), hi.max(centroid(i))),
        );
        let extent = chi - clo;
        let axis = if extent.x >= extent.y && extent.x >= extent.z {
            0
        } else if extent.y >= extent.z {
            1
        } else {
            2
        };
        let mid = items.len() / 2;
        items.select_nth_unstable_by(mid, |&a, &b| {
            centroid(a)[axis].total_cmp(&centroid(b)[axis])
        });
        let (left, right) = items.split_at_mut(mid);
        self.build(bounds, left, first);
        let second = self.build(bounds, right, first + mid);
        self.nodes[index].offset = second as u32;
        self.nodes[index].count = 0;
        self.nodes[index].axis = axis as u16;
        index
    }

    /// The closest hit `(distance, shape index)` along `ray`, if any.
    pub fn intersect(&self, shapes: &[Shape], ray: &Ray) -> Option<(f32, u32)> {
        let mut ray = *ray;
        let mut best = None;
        self.traverse(&ray.clone(), |i| {
            if let Some(t) = shapes[i as usize].intersect(&ray) {
                ray.t_max = t;
                best = Some((t, i));
            }
            ray.t_max
        });
        best
    }

    /// Whether anything blocks `ray` before `ray.t_max`.
    pub fn occluded(&self, shapes: &[Shape], ray: &Ray) -> bool {
        let mut hit = false;
        self.traverse(ray, |i| {
            if !hit && shapes[i as usize].intersect(ray).is_some() {
                hit = true;
            }
            if hit { 0.0 } else { ray.t_max }
        });
        hit
    }

    /// Visits the shapes of every leaf the ray reaches, nearest node first; `visit` returns the
    /// current farthest distance of interest (0 stops the walk).
    fn traverse(&self, ray: &Ray, mut visit: impl FnMut(u32) -> f32) {
        if self.nodes.is_empty() {
            return;
        }
        let inv = ray.direction.recip();
        let negative = [inv.x < 0.0, inv.y < 0.0, inv.z < 0.0];
        let mut t_max = ray.t_max;
        let mut stack = [0u32; 64];
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let node = &self.nodes[stack[top] as usize];
            if !slab(node.lo, node.hi, ray.origin, inv, t_max) {
                continue;
            }
            if node.count > 0 {
                let first = node.offset as usize;
                for &shape in &self.order[first..first + node.count as usize] {
                    t_max = visit(shape);
                    if t_max <= 0.0 {
                        return;
                    }
                }
            } else {
                let first = stack[top] + 1;
                let (near, far) = if negative[node.axis as usize] {
                    (node.offset, first)
                } else {
                    (first, node.offset)
                };
                stack[top] = far;
                stack[top + 1] = near;
                top += 2;
            }
        }
    }
}

/// Whether the ray `origin + t·d` (with `inv = 1/d`) meets the box for some `t` in `[0, t_max]`.
///
/// Conservative under rounding: the far distance is widened by `2γ₃` (pbrt's bound on the error
/// of the slab distances), so a box whose true entry lies at or before `t_max` is never culled —
/// without it, a hit one ulp closer on a flat box (a floor triangle) can be missed.
fn slab(lo: Vec3, hi: Vec3, origin: Vec3, inv: Vec3, t_max: f32) -> bool {
    const GAMMA_3: f32 = 3.0 * f32::EPSILON * 0.5 / (1.0 - 3.0 * f32::EPSILON * 0.5);
    let t0 = (lo - origin) * inv;
    let t1 = (hi - origin) * inv;
    let near = t0.min(t1).max_element().max(0.0);
    let far = t0.max(t1).min_element().min(t_max) * (1.0 + 2.0 * GAMMA_3);
    near <= far
}
