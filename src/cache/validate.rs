//! Structural checks of untrusted trees: node counts within the caps, one tree rooted at 0 with
//! forward children and bounded depth, permutations.

use super::*;

/// A tree's node count: present in the bytes, and between 1 and the configuration's cap.
pub(super) fn node_count(
    r: &mut In<'_>,
    len: usize,
    what: &str,
    max: usize,
) -> Result<usize, CacheError> {
    let n = r.count(len, what)?;
    if n == 0 || n > max {
        return Err(corrupt(
            r.section,
            format!("{n} {what}, expected 1..={max}"),
        ));
    }
    Ok(n)
}

/// Checks that `children(i)` describes one tree over nodes `0..n` rooted at 0: every child
/// comes after its parent and inside the tree (so there are no cycles), every node but the root
/// has exactly one parent, and no node is deeper than `max_depth`.
pub(super) fn check_tree<const K: usize>(
    n: usize,
    max_depth: u32,
    children: impl Fn(usize) -> [Option<usize>; K],
) -> Result<(), String> {
    const UNREACHED: u32 = u32::MAX;
    let mut depth = vec![UNREACHED; n];
    depth[0] = 0;
    for i in 0..n {
        if depth[i] == UNREACHED {
            return Err(format!("node {i} has no parent"));
        }
        for c in children(i).into_iter().flatten() {
            if c <= i || c >= n {
                return Err(format!("node {i} points to {c}, outside {}..{n}", i + 1));
            }
            if depth[c] != UNREACHED {
                return Err(format!("node {c} has two parents"));
            }
            if depth[i] + 1 > max_depth {
                return Err(format!("node {c} is deeper than {max_depth}"));
            }
            depth[c] = depth[i] + 1;
        }
    }
    Ok(())
}

/// Checks that `indices` is a permutation of `0..indices.len()`; the error names the culprit.
pub(super) fn check_permutation(indices: &[usize]) -> Result<(), String> {
    let mut seen = vec![false; indices.len()];
    for &k in indices {
        match seen.get_mut(k) {
            Some(s) if !*s => *s = true,
            Some(_) => return Err(format!("{k} appears twice")),
            None => return Err(format!("{k} is out of range 0..{}", indices.len())),
        }
    }
    Ok(())
}
