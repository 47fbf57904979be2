//! What a guided sample costs against an unguided one, measured the way a comparison at equal
//! spp needs it: passes of the same size rendered alternately without and with a trained
//! field, in one process, each guided pass divided by the unguided pass of its round.
//!
//! The machine's speed drifts by several percent over seconds, more than the effects this
//! measures; a ratio within one round of a fraction of a second cancels the drift, and
//! alternating which pass goes first cancels what one pass leaves in the cache for the next.

use crate::integrator::{Continuing, Guiding};
use crate::passes::PassImage;
use crate::render::render_pass_image;
use crate::scene::Scene;
use sdguide::GuidingField;
use std::time::{Duration, Instant};

/// The per-round measurements of [`paired_cost`].
#[derive(Clone, Debug)]
pub struct Cost {
    /// Each round's guided pass time over its unguided pass time.
    pub ratios: Vec<f64>,
    /// Each round's unguided pass time.
    pub unguided: Vec<Duration>,
    /// Rays traced by all unguided passes and by all guided passes: the two render the same
    /// pixels and samples, so these differ only by where the guide sends the paths.
    pub rays: [f64; 2],
}

impl Cost {
    /// The ratios' least, lower quartile, median, upper quartile and largest (`None` without
    /// rounds).
    pub fn spread(&self) -> Option<[f64; 5]> {
        let mut r = self.ratios.clone();
        r.sort_by(f64::total_cmp);
        let last = r.len().checked_sub(1)?;
        Some([0, 1, 2, 3, 4].map(|q| r[q * last / 4]))
    }
}

/// Renders `rounds` rounds of two passes of `spp` samples per pixel of a `width × height`
/// image of `scene`, unguided and guided by `field` (its learned guide probabilities, classic
/// roulette: what the demo's final render does with its field), the unguided pass first in
/// even rounds and second in odd ones. Both passes of a round draw the same pixels' random
/// streams.
pub fn paired_cost(
    scene: &Scene,
    field: &GuidingField,
    (width, height): (usize, usize),
    spp: u32,
    rounds: u32,
) -> Cost {
    let guiding = Guiding {
        field,
        record: false,
        guide_probability: None,
    };
    let mut cost = Cost {
        ratios: Vec::new(),
        unguided: Vec::new(),
        rays: [0.0; 2],
    };
    for round in 0..rounds {
        let mut time = [Duration::ZERO; 2];
        let order = if round % 2 == 0 { [0, 1] } else { [1, 0] };
        for which in order {
            let mut image = PassImage::new(width, height);
            let guide = (which == 1).then_some(guiding);
            let start = Instant::now();
            render_pass_image(
                scene,
                guide,
                &Continuing::CLASSIC,
                &mut image,
                (spp, 1, round),
            );
            time[which] = start.elapsed();
            cost.rays[which] += image.rays;
        }
        cost.ratios
            .push(time[1].as_secs_f64() / time[0].as_secs_f64().max(1e-9));
        cost.unguided.push(time[0]);
    }
    cost
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::method::{Budget, Method, Rrs, Training, render};
    use crate::scenes;
    use sdguide::GuidingConfig;

    #[test]
    fn every_round_renders_both_passes_over_the_same_samples() {
        let scene = scenes::door();
        let outcome = render(
            &scene,
            Method::Guided(sdguide::LeafRule::L2),
            (32, 24),
            Budget {
                time: None,
                spp: Some(8),
                ..Budget::default()
            },
            1,
            Training {
                config: &GuidingConfig::default(),
                cache: None,
                guide_probability: None,
                rrs: Rrs::Classic,
            },
            &|_, _, _| {},
        )
        .expect("renders");
        let field = outcome.field.expect("a guided render keeps its field");
        let cost = paired_cost(&scene, &field, (32, 24), 2, 5);
        assert_eq!(cost.ratios.len(), 5);
        assert_eq!(cost.unguided.len(), 5);
        assert!(cost.ratios.iter().all(|r| r.is_finite() && *r > 0.0));
        // Every camera sample traces at least its camera ray, in both passes.
        let samples = (5 * 32 * 24 * 2) as f64;
        assert!(cost.rays.iter().all(|&r| r >= samples), "{:?}", cost.rays);
        let spread = cost.spread().expect("five rounds");
        assert!(spread.is_sorted(), "{spread:?}");
        let none = Cost {
            ratios: Vec::new(),
            ..cost
        };
        assert_eq!(none.spread(), None);
    }
}
