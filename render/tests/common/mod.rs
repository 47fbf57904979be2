//! What several of the demo's tests train on.

use sdguide::{GuidingConfig, GuidingField};
use sdguide_render::method::field_bounds;
use sdguide_render::render::training_pass;
use sdguide_render::scene::Scene;
use sdguide_render::scenes::door;

/// `door`, and a field trained on it with the defaults: four passes of 2, 4, 8, 16 spp at
/// 48 × 36, seed 11.
pub fn trained_door() -> (Scene, GuidingField) {
    let scene = door();
    let mut field = GuidingField::new(field_bounds(&scene), GuidingConfig::default()).unwrap();
    for pass in 0..4 {
        training_pass(&scene, &mut field, (48, 36), 2 << pass, 11, pass, None);
    }
    (scene, field)
}
