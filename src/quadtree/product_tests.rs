//! Helpers the tests of the products share: the final cells of a descent, and a chi-square
//! test of a sampler against their probabilities.

use super::*;
use crate::quadtree::testing::assert_chi_square;

/// A final cell of the product's descent.
pub(crate) struct FinalCell {
    pub(crate) cell: [u32; 2],
    pub(crate) depth: u32,
    /// The probability the descent gives it.
    pub(crate) p: f64,
    /// The first settled cell on the way down to it, and that cell's depth, if any.
    pub(crate) settled_at: Option<([u32; 2], u32)>,
}

impl FinalCell {
    /// The centre of the cell on the square.
    pub(crate) fn centre(&self) -> Vec2 {
        let size = 0.5f32.powi(self.depth as i32);
        (Vec2::new(self.cell[0] as f32, self.cell[1] as f32) + 0.5) * size
    }
}

/// Every final cell of the product's descent of positive probability, depth first.
pub(crate) fn final_cells(tree: &SamplingTree, lobe: &impl Lobe) -> Vec<FinalCell> {
    fn visit(
        tree: &SamplingTree,
        lobe: &impl Lobe,
        at: Cursor,
        (p, settled_at): (f64, Option<([u32; 2], u32)>),
        out: &mut Vec<FinalCell>,
    ) {
        let level = at.level(tree, lobe);
        for q in 0..4 {
            let (ix, iy) = (q & 1, q >> 1);
            let pq = p * f64::from(level.density_factor(ix | iy << 1)) / 4.0;
            if pq == 0.0 {
                continue;
            }
            let mut next = at;
            let goes_on = next.enter(tree, &level, lobe, (ix, iy));
            let settled_at = settled_at.or(next.settled.then_some((next.cell, next.depth)));
            if goes_on {
                visit(tree, lobe, next, (pq, settled_at), out);
            } else {
                out.push(FinalCell {
                    cell: next.cell,
                    depth: next.depth,
                    p: pq,
                    settled_at,
                });
            }
        }
    }
    let mut out = Vec::new();
    visit(tree, lobe, Cursor::ROOT, (1.0, None), &mut out);
    out
}

/// Chi-square test of `draw` (a sampler of the square) against the probabilities of the
/// product's final cells of `tree` and `lobe`.
pub(crate) fn assert_samples_the_product(
    tree: &SamplingTree,
    lobe: &impl Lobe,
    what: &str,
    mut draw: impl FnMut() -> Vec2,
) {
    // Bins: the 32 × 32 grid; each final cell's probability goes to the bins it covers
    // (in equal shares: the density is constant on it).
    let (bins, draws) = (32u32, 1_000_000u64);
    let mut expected = vec![0.0f64; (bins * bins) as usize];
    for FinalCell { cell, depth, p, .. } in final_cells(tree, lobe) {
        if depth >= 5 {
            let shift = depth - 5;
            expected[((cell[1] >> shift) * bins + (cell[0] >> shift)) as usize] += p;
        } else {
            let k = 1u32 << (5 - depth);
            let share = p / f64::from(k * k);
            for j in 0..k {
                for i in 0..k {
                    let (bx, by) = (cell[0] * k + i, cell[1] * k + j);
                    expected[(by * bins + bx) as usize] += share;
                }
            }
        }
    }
    let mut observed = vec![0u64; expected.len()];
    for _ in 0..draws {
        let s = draw();
        let (i, j) = ((s.x * bins as f32) as u32, (s.y * bins as f32) as u32);
        observed[(j * bins + i) as usize] += 1;
    }
    assert_chi_square(&observed, &expected, draws, 150, what);
}
