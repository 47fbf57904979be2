//! The `SPATIAL` and `DIRECTIONAL` sections: the spatial tree's node entries, and every
//! directional tree (sampling nodes, recording topology, moments), each encoder beside its
//! decoder.

use super::*;

pub(super) fn encode_spatial(tree: &SpatialTree) -> Vec<u8> {
    let nodes = tree.nodes();
    let mut out = Out(Vec::with_capacity(4 + 4 * nodes.len()));
    out.u32(nodes.len() as u32);
    for &n in nodes {
        out.u32(n);
    }
    out.0
}

pub(super) fn decode_spatial(
    bytes: &[u8],
    field: &GuidingField,
) -> Result<SpatialTree, CacheError> {
    let mut r = In::new(bytes, "spatial");
    let n = r.count(4, "nodes")?;
    if n == 0 || n > field.config.max_spatial_nodes as usize {
        return Err(corrupt(
            "spatial",
            format!("{n} nodes, expected 1..={}", field.config.max_spatial_nodes),
        ));
    }
    let nodes = (0..n).map(|_| r.u32()).collect::<Result<Vec<u32>, _>>()?;
    check_tree(n, MAX_SPATIAL_DEPTH, |i| {
        let e = nodes[i];
        if e & spatial::LEAF_BIT != 0 {
            [None, None]
        } else {
            [Some(e as usize), Some(e as usize + 1)]
        }
    })
    .map_err(|d| corrupt("spatial", d))?;
    // Leaves index directional trees 0..leaves, each exactly once.
    let leaves: Vec<usize> = nodes
        .iter()
        .filter(|&&e| e & spatial::LEAF_BIT != 0)
        .map(|&e| (e & !spatial::LEAF_BIT) as usize)
        .collect();
    check_permutation(&leaves).map_err(|d| corrupt("spatial", format!("leaf {d}")))?;
    Ok(SpatialTree::from_nodes(field.spatial.cube(), nodes))
}

pub(super) fn encode_directional(trees: &[impl GuideView]) -> Vec<u8> {
    let mut out = Out(Vec::new());
    out.u32(trees.len() as u32);
    for t in trees {
        let s = t.sampling().nodes();
        out.u32(s.len() as u32);
        for n in s {
            for p in n.px.iter().chain(n.py.iter().flatten()) {
                out.f32(*p);
            }
            for c in n.child {
                out.u16(c);
            }
        }
        let r = t.recording();
        out.u32(r.nodes.len() as u32);
        for slots in r.nodes.iter() {
            for &s in slots {
                out.u32(s);
            }
        }
        // The deferred filter's pending sums stay apart (the `PENDING` section): spreading
        // them rounds, and a farm's merged workers must spread what one machine would.
        out.u32(r.moments.len() as u32);
        for k in 0..r.moments.len() {
            let m = r.exact_moments(k);
            out.sum(m.sum);
            out.sum(m.sum_sq);
            out.u64(m.count);
        }
    }
    out.0
}

/// Reads a `DIRECTIONAL` (or `VOLUME_DIRECTIONAL`, named `section`) section: one guide per
/// spatial leaf.
pub(super) fn decode_directional(
    bytes: &[u8],
    section: &'static str,
    field: &GuidingField,
    major: u16,
) -> Result<Vec<Guide>, CacheError> {
    let mut r = In::with_sums(bytes, section, major);
    let leaves = field.spatial.leaves().len();
    let n = r.count(12, "trees")?;
    if n != leaves {
        return Err(corrupt(
            section,
            format!("{n} trees for {leaves} spatial leaves"),
        ));
    }
    let c = &field.config;
    (0..n)
        .map(|i| {
            decode_tree(&mut r, section, c).map_err(|e| match e {
                CacheError::Corrupt { section, detail } => {
                    corrupt(section, format!("tree {i}: {detail}"))
                }
                other => other,
            })
        })
        .collect()
}

pub(super) fn decode_tree(
    r: &mut In<'_>,
    section: &'static str,
    c: &GuidingConfig,
) -> Result<Guide, CacheError> {
    // Interior node depth is at most max_depth − 1: their children, the leaves, reach max_depth.
    let max_node_depth = c.max_directional_depth - 1;
    let max_nodes = c.max_directional_nodes as usize;

    let n = node_count(r, SAMPLING_NODE_LEN, "sampling nodes", max_nodes)?;
    let mut sampling = Vec::with_capacity(n);
    for i in 0..n {
        let mut p = [0f32; 6];
        for x in &mut p {
            *x = r.f32()?;
        }
        let node = SamplingNode {
            px: [p[0], p[1]],
            py: [[p[2], p[3]], [p[4], p[5]]],
            child: [r.u16()?, r.u16()?, r.u16()?, r.u16()?],
        };
        for pair in [node.px, node.py[0], node.py[1]] {
            let ok = pair.iter().all(|&x| x > 0.0 && x <= 1.0)
                && (pair[0] + pair[1] - 1.0).abs() <= SUM_TOLERANCE;
            if !ok {
                return Err(corrupt(
                    section,
                    format!("sampling node {i}: probabilities {pair:?}"),
                ));
            }
        }
        sampling.push(node);
    }
    check_tree(n, max_node_depth, |i| {
        sampling[i]
            .child
            .map(|ch| (ch != quadtree::NO_CHILD).then_some(usize::from(ch)))
    })
    .map_err(|d| corrupt(section, format!("sampling tree: {d}")))?;

    let n = node_count(r, RECORDING_NODE_LEN, "recording nodes", max_nodes)?;
    let mut nodes = Vec::with_capacity(n);
    for _ in 0..n {
        nodes.push([r.u32()?, r.u32()?, r.u32()?, r.u32()?]);
    }
    check_tree(n, max_node_depth, |i| {
        nodes[i].map(|s| (s & quadtree::LEAF_BIT == 0).then_some(s as usize))
    })
    .map_err(|d| corrupt(section, format!("recording tree: {d}")))?;
    let leaf_slots: Vec<usize> = nodes
        .iter()
        .flatten()
        .filter(|&&s| s & quadtree::LEAF_BIT != 0)
        .map(|&s| (s & !quadtree::LEAF_BIT) as usize)
        .collect();
    check_permutation(&leaf_slots).map_err(|d| corrupt(section, format!("recording leaf {d}")))?;

    let m = r.count(MOMENTS_LEN, "leaf moments")?;
    if m != leaf_slots.len() {
        return Err(corrupt(
            section,
            format!("{m} leaf moments for {} leaves", leaf_slots.len()),
        ));
    }
    let (mut moments, mut quadrants) = (Vec::with_capacity(m), Vec::with_capacity(m));
    for _ in 0..m {
        // A zero count may carry sums: a box filter spreads shares into leaves it does not count.
        moments.push(AtomicSums::from_exact((r.sum()?, r.sum()?)));
        // The count is the quadrants'; until `QUADRANTS` (if present) says how it divides,
        // the first quadrant holds it.
        let count = r.u64()?;
        quadrants.push(AtomicQuadrants::from_exact(&[
            (Sum::ZERO, count),
            (Sum::ZERO, 0),
            (Sum::ZERO, 0),
            (Sum::ZERO, 0),
        ]));
    }
    Ok(Guide::new(
        SamplingTree::new(sampling.into_boxed_slice()),
        RecordingTree {
            nodes: nodes.into_boxed_slice(),
            quadrants: quadrants.into_boxed_slice(),
            moments: moments.into_boxed_slice(),
            pending: Box::default(),
        },
    ))
}
