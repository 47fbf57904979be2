//! Volume guides through the C API: the configuration flag, medium samples, the volume
//! distribution and its product with the phase function, and the statistics.

use sdguide_c::*;
use std::ptr::null_mut;

fn v(x: f32, y: f32, z: f32) -> sdg_vec3 {
    sdg_vec3 { x, y, z }
}

/// A field over the unit cube with the default configuration, and volumes if asked.
fn field(volumes: bool) -> *mut sdg_field {
    let mut c = std::mem::MaybeUninit::<sdg_config>::uninit();
    let mut f = null_mut();
    // SAFETY: valid pointers; `sdg_config_default` initializes `c` on success.
    unsafe {
        assert_eq!(sdg_config_default(c.as_mut_ptr()), sdg_status::Ok);
        let mut c = c.assume_init();
        if volumes {
            c.flags |= SDG_CONFIG_VOLUMES;
        }
        assert_eq!(
            sdg_field_create(&c, v(0.0, 0.0, 0.0), v(1.0, 1.0, 1.0), &mut f),
            sdg_status::Ok
        );
    }
    f
}

/// A medium sample at the centre: light from −x.
fn medium_sample(direction: sdg_vec3, value: f32) -> sdg_sample {
    sdg_sample {
        position: v(0.5, 0.5, 0.5),
        direction,
        value,
        pdf: 1.0 / (4.0 * std::f32::consts::PI),
        flags: SDG_SAMPLE_VOLUME,
        ..sdg_sample::default()
    }
}

#[test]
fn medium_samples_train_the_volume_distribution_and_its_phase_product() {
    let f = field(true);
    let mut stats = sdg_stats::default();
    // SAFETY: valid pointers throughout; distributions are destroyed before the field.
    unsafe {
        for k in 0..4000 {
            let u = (k as f32 + 0.5) / 4000.0;
            let d = sdguide::sphere::square_to_direction(glam::Vec2::new(
                u,
                (k * 37 % 4000) as f32 / 4000.0,
            ));
            let value = if d.x < -0.9 { 10.0 } else { 0.01 };
            let s = medium_sample(v(d.x, d.y, d.z), value);
            assert_eq!(sdg_field_record(f, &s), sdg_status::Ok);
        }
        assert_eq!(sdg_field_stats(f, &mut stats), sdg_status::Ok);
        assert_eq!(
            (stats.samples_recorded, stats.volume_samples_recorded),
            (4000, 4000)
        );
        assert_eq!(sdg_field_refine(f), sdg_status::Ok);
        assert_eq!(sdg_field_stats(f, &mut stats), sdg_status::Ok);
        assert!(stats.volume_directional_nodes > 0);

        let (mut surface, mut medium) = (null_mut(), null_mut());
        let centre = v(0.5, 0.5, 0.5);
        assert_eq!(
            sdg_field_distribution(f, centre, &mut surface),
            sdg_status::Ok
        );
        assert_eq!(
            sdg_field_volume_distribution(f, centre, &mut medium),
            sdg_status::Ok
        );
        let (mut ps, mut pm) = (0.0f32, 0.0f32);
        assert_eq!(
            sdg_distribution_pdf(surface, v(-1.0, 0.0, 0.0), &mut ps),
            sdg_status::Ok
        );
        assert_eq!(
            sdg_distribution_pdf(medium, v(-1.0, 0.0, 0.0), &mut pm),
            sdg_status::Ok
        );
        // The surface guide learned nothing (uniform); the volume guide, after one iteration,
        // gives the light's cap (5% of the sphere, 99.8% of the flux) more than the uniform
        // density.
        assert!(
            (ps - 1.0 / (4.0 * std::f32::consts::PI)).abs() < 1e-6,
            "{ps}"
        );
        assert!(pm > 1.5 * ps, "{pm} vs {ps}");

        // A phase function on the surface distribution is refused; on the volume one, every
        // draw has the pdf `sdg_distribution_pdf` gives it.
        assert_eq!(
            sdg_distribution_set_phase(surface, v(1.0, 0.0, 0.0), 0.5),
            sdg_status::InvalidArgument
        );
        assert_eq!(
            sdg_distribution_set_phase(medium, v(1.0, 0.0, 0.0), f32::NAN),
            sdg_status::InvalidArgument
        );
        assert_eq!(
            sdg_distribution_set_phase(medium, v(1.0, 0.0, 0.0), 0.9),
            sdg_status::Ok
        );
        let (mut d, mut p, mut q) = (sdg_vec3::default(), 0.0f32, 0.0f32);
        for k in 0..64 {
            let u = (k as f32 + 0.5) / 64.0;
            assert_eq!(
                sdg_distribution_sample(medium, u, 1.0 - u, &mut d, &mut p),
                sdg_status::Ok
            );
            assert_eq!(sdg_distribution_pdf(medium, d, &mut q), sdg_status::Ok);
            assert!(p > 0.0 && p == q, "{p} vs {q}");
        }
        // Forward scattering along +x: ahead is far likelier than behind.
        let (mut ahead, mut behind) = (0.0f32, 0.0f32);
        assert_eq!(
            sdg_distribution_pdf(medium, v(1.0, 0.0, 0.0), &mut ahead),
            sdg_status::Ok
        );
        assert_eq!(
            sdg_distribution_pdf(medium, v(-1.0, 0.0, 0.0), &mut behind),
            sdg_status::Ok
        );
        assert!(ahead > 10.0 * behind, "{ahead} vs {behind}");
        let mut a = 0.0f32;
        assert_eq!(
            sdg_distribution_guide_probability(medium, &mut a),
            sdg_status::Ok
        );
        assert_eq!(a, 0.5);
        sdg_distribution_destroy(surface);
        sdg_distribution_destroy(medium);
        sdg_field_destroy(f);
    }
}

#[test]
fn without_volumes_medium_samples_are_rejected_and_counted() {
    let f = field(false);
    let mut stats = sdg_stats::default();
    // SAFETY: valid pointers throughout.
    unsafe {
        let s = medium_sample(v(0.0, 0.0, 1.0), 1.0);
        assert_eq!(sdg_field_record(f, &s), sdg_status::SampleRejected);
        assert_eq!(sdg_field_stats(f, &mut stats), sdg_status::Ok);
        assert_eq!(stats.rejected_no_volume_guide, 1);
        assert_eq!(stats.samples_recorded, 0);
        let mut medium = null_mut();
        assert_eq!(
            sdg_field_volume_distribution(f, v(0.5, 0.5, 0.5), &mut medium),
            sdg_status::Ok
        );
        let mut a = 1.0f32;
        assert_eq!(
            sdg_distribution_guide_probability(medium, &mut a),
            sdg_status::Ok
        );
        assert_eq!(a, 0.0);
        sdg_distribution_destroy(medium);
        sdg_field_destroy(f);
    }
}
