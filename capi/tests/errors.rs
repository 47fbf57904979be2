//! The C API's error paths: null pointers, non-finite inputs, bad configurations and bad cache
//! bytes give status codes and messages, never a crash.

use sdguide_c::*;
use sdguide_lab::rng::Rng;
use std::ffi::{CStr, CString};
use std::ptr::{null, null_mut};

fn last_error() -> String {
    // SAFETY: `sdg_last_error` returns a valid NUL-terminated string owned by this thread.
    unsafe { CStr::from_ptr(sdg_last_error()) }
        .to_string_lossy()
        .into_owned()
}

fn v(x: f32, y: f32, z: f32) -> sdg_vec3 {
    sdg_vec3 { x, y, z }
}

fn config() -> sdg_config {
    let mut c = std::mem::MaybeUninit::<sdg_config>::uninit();
    // SAFETY: a valid out-pointer; `sdg_config_default` initializes it on success.
    assert_eq!(
        unsafe { sdg_config_default(c.as_mut_ptr()) },
        sdg_status::Ok
    );
    // SAFETY: initialized by the successful call above.
    unsafe { c.assume_init() }
}

fn field() -> *mut sdg_field {
    let mut f = null_mut();
    // SAFETY: valid pointers.
    let status = unsafe { sdg_field_create(&config(), v(0.0, 0.0, 0.0), v(1.0, 1.0, 1.0), &mut f) };
    assert_eq!(status, sdg_status::Ok);
    f
}

#[test]
fn null_pointers_are_errors_with_messages() {
    let f = field();
    let (mut d, mut p) = (sdg_vec3::default(), 0.0f32);
    let mut out = null_mut();
    // SAFETY: every pointer is either null or valid; null is what is being tested.
    unsafe {
        assert_eq!(sdg_config_default(null_mut()), sdg_status::NullPointer);
        assert_eq!(
            sdg_field_create(null(), v(0.0, 0.0, 0.0), v(1.0, 1.0, 1.0), &mut out),
            sdg_status::NullPointer
        );
        assert!(last_error().contains("config"), "{}", last_error());
        assert_eq!(
            sdg_field_create(&config(), v(0.0, 0.0, 0.0), v(1.0, 1.0, 1.0), null_mut()),
            sdg_status::NullPointer
        );
        assert_eq!(sdg_field_record(null(), null()), sdg_status::NullPointer);
        assert_eq!(sdg_field_record(f, null()), sdg_status::NullPointer);
        assert!(last_error().contains("sample"));
        assert_eq!(
            sdg_field_record_batch(f, null(), 3),
            sdg_status::NullPointer
        );
        assert_eq!(sdg_field_record_batch(f, null(), 0), sdg_status::Ok);
        assert_eq!(
            sdg_field_sample(null(), v(0.5, 0.5, 0.5), 0.1, 0.2, &mut d, &mut p),
            sdg_status::NullPointer
        );
        assert_eq!(
            sdg_field_sample(f, v(0.5, 0.5, 0.5), 0.1, 0.2, null_mut(), &mut p),
            sdg_status::NullPointer
        );
        assert_eq!(
            sdg_field_pdf(f, v(0.5, 0.5, 0.5), v(0.0, 0.0, 1.0), null_mut()),
            sdg_status::NullPointer
        );
        assert_eq!(
            sdg_field_distribution(f, v(0.5, 0.5, 0.5), null_mut()),
            sdg_status::NullPointer
        );
        assert_eq!(
            sdg_distribution_sample(null(), 0.1, 0.2, &mut d, &mut p),
            sdg_status::NullPointer
        );
        assert_eq!(
            sdg_distribution_pdf(null(), v(0.0, 0.0, 1.0), &mut p),
            sdg_status::NullPointer
        );
        assert_eq!(
            sdg_distribution_guide_probability(null(), &mut p),
            sdg_status::NullPointer
        );
        assert_eq!(sdg_field_refine(null_mut()), sdg_status::NullPointer);
        assert_eq!(sdg_field_stats(f, null_mut()), sdg_status::NullPointer);
        assert_eq!(sdg_field_save(f, null()), sdg_status::NullPointer);
        assert_eq!(sdg_field_load(null(), &mut out), sdg_status::NullPointer);
        assert_eq!(
            sdg_field_save_to_buffer(f, null_mut(), null_mut()),
            sdg_status::NullPointer
        );
        assert_eq!(
            sdg_field_load_from_buffer(null(), 10, &mut out),
            sdg_status::NullPointer
        );
        assert_eq!(sdg_field_merge(f, null()), sdg_status::NullPointer);
        assert_eq!(sdg_field_merge(f, f), sdg_status::InvalidArgument);
        // Destroying null is a no-op.
        sdg_field_destroy(null_mut());
        sdg_distribution_destroy(null_mut());
        sdg_buffer_free(null_mut(), 0);
        sdg_field_destroy(f);
    }
}

#[test]
fn non_finite_inputs_are_rejected_or_refused() {
    let f = field();
    let nan = f32::NAN;
    let (mut d, mut p) = (sdg_vec3::default(), 0.0f32);
    let mut dist = null_mut();
    // SAFETY: valid pointers throughout.
    unsafe {
        // Recording: rejected and counted, not an error.
        let bad = sdg_sample {
            position: v(nan, 0.5, 0.5),
            direction: v(0.0, 0.0, 1.0),
            value: 1.0,
            pdf: 1.0,
            ..Default::default()
        };
        assert_eq!(sdg_field_record(f, &bad), sdg_status::SampleRejected);
        let bad_pdf = sdg_sample {
            position: v(0.5, 0.5, 0.5),
            direction: v(0.0, 0.0, 1.0),
            value: 1.0,
            pdf: nan,
            ..Default::default()
        };
        let good = sdg_sample {
            pdf: 0.5,
            ..bad_pdf
        };
        assert_eq!(
            sdg_field_record_batch(f, [good, bad_pdf, good].as_ptr(), 3),
            sdg_status::SampleRejected
        );
        // Mixture terms are checked like the rest: a negative BSDF pdf rejects the sample.
        let bad_mixture = sdg_sample {
            integrand: 1.0,
            bsdf_pdf: -1.0,
            guide_pdf: 0.1,
            flags: SDG_SAMPLE_MIXTURE,
            ..good
        };
        assert_eq!(
            sdg_field_record(f, &bad_mixture),
            sdg_status::SampleRejected
        );
        // So is the second moment: a negative one rejects the sample as a bad value; without
        // its flag it is not read.
        let bad_moment = sdg_sample {
            second_moment: -1.0,
            flags: SDG_SAMPLE_SECOND_MOMENT,
            ..good
        };

        assert_eq!(sdg_field_record(f, &bad_moment), sdg_status::SampleRejected);
        let moment = sdg_sample {
            second_moment: 0.5,
            flags: SDG_SAMPLE_SECOND_MOMENT,
            ..good
        };
        assert_eq!(sdg_field_record(f, &moment), sdg_status::Ok);
        let mut stats = sdg_stats::default();
        assert_eq!(sdg_field_stats(f, &mut stats), sdg_status::Ok);
        assert_eq!(
            (
                stats.rejected[0],
                stats.rejected[3],
                stats.rejected[4],
                stats.samples_recorded
            ),
            (1, 1, 2, 3)
        );
        // Queries: a non-finite position, sample or direction is an invalid argument.
        assert_eq!(
            sdg_field_sample(f, v(nan, 0.5, 0.5), 0.1, 0.2, &mut d, &mut p),
            sdg_status::InvalidArgument
        );
        assert!(last_error().contains("position"), "{}", last_error());
        assert_eq!(
            sdg_field_sample(f, v(0.5, 0.5, 0.5), nan, 0.2, &mut d, &mut p),
            sdg_status::InvalidArgument
        );
        assert_eq!(
            sdg_field_pdf(f, v(0.5, 0.5, 0.5), v(nan, 0.0, 1.0), &mut p),
            sdg_status::InvalidArgument
        );
        assert_eq!(
            sdg_field_distribution(f, v(0.5, f32::INFINITY, 0.5), &mut dist),
            sdg_status::InvalidArgument
        );
        assert!(dist.is_null());
        // Bad configurations and bounds.
        let mut out = null_mut();
        let c = sdg_config {
            subdivision_threshold: 3.0,
            ..config()
        };
        assert_eq!(
            sdg_field_create(&c, v(0.0, 0.0, 0.0), v(1.0, 1.0, 1.0), &mut out),
            sdg_status::Config
        );
        assert!(
            last_error().contains("subdivision_threshold"),
            "{}",
            last_error()
        );
        let c = sdg_config {
            rule: 7,
            ..config()
        };
        assert_eq!(
            sdg_field_create(&c, v(0.0, 0.0, 0.0), v(1.0, 1.0, 1.0), &mut out),
            sdg_status::Config
        );
        assert_eq!(
            sdg_field_create(&config(), v(1.0, 1.0, 1.0), v(0.0, 0.0, 0.0), &mut out),
            sdg_status::Config
        );
        // Every rule constant makes a field.
        for rule in [SDG_RULE_L1, SDG_RULE_L2, SDG_RULE_L2_MIXTURE] {
            let c = sdg_config { rule, ..config() };
            assert_eq!(
                sdg_field_create(&c, v(0.0, 0.0, 0.0), v(1.0, 1.0, 1.0), &mut out),
                sdg_status::Ok
            );
            sdg_field_destroy(out);
            out = null_mut();
        }
        // Both spatial split rules make a field; an unknown one, or a gain threshold out of
        // range, does not.
        for (spatial_split, tau, status) in [
            (SDG_SPATIAL_SPLIT_COUNT, 0.05, sdg_status::Ok),
            (SDG_SPATIAL_SPLIT_GAIN, 0.0, sdg_status::Ok),
            (2, 0.05, sdg_status::Config),
            (SDG_SPATIAL_SPLIT_GAIN, 1.0, sdg_status::Config),
        ] {
            let c = sdg_config {
                spatial_split,
                spatial_gain_threshold: tau,
                ..config()
            };
            assert_eq!(
                sdg_field_create(&c, v(0.0, 0.0, 0.0), v(1.0, 1.0, 1.0), &mut out),
                status
            );
            sdg_field_destroy(out);
            out = null_mut();
        }
        // The deferred box is a directional filter only.
        let c = sdg_config {
            spatial_filter: SDG_FILTER_DEFERRED_BOX,
            ..config()
        };
        assert_eq!(
            sdg_field_create(&c, v(0.0, 0.0, 0.0), v(1.0, 1.0, 1.0), &mut out),
            sdg_status::Config
        );
        assert!(last_error().contains("spatial filter"), "{}", last_error());
        assert!(out.is_null());
        let c = sdg_config {
            directional_filter: SDG_FILTER_DEFERRED_BOX,
            ..config()
        };
        assert_eq!(
            sdg_field_create(&c, v(0.0, 0.0, 0.0), v(1.0, 1.0, 1.0), &mut out),
            sdg_status::Ok
        );
        assert!(!out.is_null());
        sdg_field_destroy(out);
        sdg_field_destroy(f);
    }
}

#[test]
fn bad_cache_bytes_and_paths_are_errors_with_messages() {
    let f = field();
    let mut out = null_mut();
    // SAFETY: valid pointers; the buffer is freed with what `save_to_buffer` returned.
    unsafe {
        let (mut data, mut len) = (null_mut(), 0usize);
        assert_eq!(
            sdg_field_save_to_buffer(f, &mut data, &mut len),
            sdg_status::Ok
        );
        let bytes = std::slice::from_raw_parts_mut(data, len);
        assert_eq!(
            sdg_field_load_from_buffer(data, len, &mut out),
            sdg_status::Ok
        );
        sdg_field_destroy(out);
        out = null_mut();
        assert_eq!(
            sdg_field_load_from_buffer(data, len - 1, &mut out),
            sdg_status::Cache
        );
        assert!(last_error().contains("truncated"), "{}", last_error());
        bytes[0] = b'X';
        assert_eq!(
            sdg_field_load_from_buffer(data, len, &mut out),
            sdg_status::Cache
        );
        assert!(last_error().contains("magic"), "{}", last_error());
        assert!(out.is_null());
        sdg_buffer_free(data, len);

        let missing = CString::new("/nonexistent/dir/field.sdgc").unwrap();
        assert_eq!(sdg_field_load(missing.as_ptr(), &mut out), sdg_status::Io);
        assert_eq!(sdg_field_save(f, missing.as_ptr()), sdg_status::Io);
        assert!(!last_error().is_empty());
        sdg_field_destroy(f);
    }
}

#[test]
fn threads_record_and_query_while_another_refines() {
    let f = field() as usize; // handles cross threads as addresses
    std::thread::scope(|s| {
        for t in 0..4 {
            s.spawn(move || {
                let f = f as *const sdg_field;
                for i in 0..20_000 {
                    let u = ((i * 7 + t) % 1000) as f32 / 1000.0;
                    let (mut d, mut p) = (sdg_vec3::default(), 0.0f32);
                    // SAFETY: the field outlives the scope; pointers are valid.
                    unsafe {
                        assert_eq!(
                            sdg_field_sample(f, v(u, 0.5, 1.0 - u), u, 1.0 - u, &mut d, &mut p),
                            sdg_status::Ok
                        );
                        let sample = sdg_sample {
                            position: v(u, 0.5, 0.5),
                            direction: d,
                            value: d.z.max(0.0),
                            pdf: p,
                            ..Default::default()
                        };
                        assert_eq!(sdg_field_record(f, &sample), sdg_status::Ok);
                    }
                }
            });
        }
        s.spawn(move || {
            for _ in 0..5 {
                // SAFETY: valid handle; the lock makes refine exclusive.
                assert_eq!(
                    unsafe { sdg_field_refine(f as *mut sdg_field) },
                    sdg_status::Ok
                );
                std::thread::yield_now();
            }
        });
    });
    let mut stats = sdg_stats::default();
    // SAFETY: valid pointers; destroyed once.
    unsafe {
        assert_eq!(
            sdg_field_stats(f as *const sdg_field, &mut stats),
            sdg_status::Ok
        );
        assert_eq!(stats.samples_recorded_total, 80_000);
        sdg_field_destroy(f as *mut sdg_field);
    }
}

#[test]
fn a_thread_holding_a_distribution_keeps_working_while_a_refine_waits() {
    let f = field() as usize;
    let mut dist = null_mut();
    // SAFETY: valid pointers.
    assert_eq!(
        unsafe { sdg_field_distribution(f as *const sdg_field, v(0.5, 0.5, 0.5), &mut dist) },
        sdg_status::Ok
    );
    std::thread::scope(|s| {
        // SAFETY: valid handle; refine waits for the distribution.
        let refine = s.spawn(move || unsafe { sdg_field_refine(f as *mut sdg_field) });
        std::thread::sleep(std::time::Duration::from_millis(50));
        // With the refine waiting, this thread still records and queries (no deadlock)...
        let (mut d, mut p) = (sdg_vec3::default(), 0.0f32);
        // SAFETY: valid pointers.
        unsafe {
            let sample = sdg_sample {
                position: v(0.5, 0.5, 0.5),
                direction: v(0.0, 0.0, 1.0),
                value: 1.0,
                pdf: 0.1,
                ..Default::default()
            };
            assert_eq!(
                sdg_field_record(f as *const sdg_field, &sample),
                sdg_status::Ok
            );
            assert_eq!(
                sdg_field_sample(
                    f as *const sdg_field,
                    v(0.5, 0.5, 0.5),
                    0.3,
                    0.3,
                    &mut d,
                    &mut p
                ),
                sdg_status::Ok
            );
            assert_eq!(
                sdg_distribution_sample(dist, 0.3, 0.3, &mut d, &mut p),
                sdg_status::Ok
            );
            // ...and once it lets go of the distribution, the refine goes through.
            sdg_distribution_destroy(dist);
        }
        assert_eq!(refine.join().unwrap(), sdg_status::Ok);
    });
    let mut stats = sdg_stats::default();
    // SAFETY: valid pointers; destroyed once.
    unsafe {
        assert_eq!(
            sdg_field_stats(f as *const sdg_field, &mut stats),
            sdg_status::Ok
        );
        assert_eq!((stats.iteration, stats.samples_recorded_total), (1, 1));
        sdg_field_destroy(f as *mut sdg_field);
    }
}

/// A refine (and a merge) waiting for the lock blocks new readers: with four threads recording
/// and querying without pause, it completes after a bounded number of their operations. A lock
/// that lets readers overtake a waiting writer would let them run until they stop: each reader
/// performs up to `LIMIT` operations, and the refine must return long before all of them are
/// spent.
#[test]
fn a_waiting_refine_is_not_starved_by_readers_that_keep_arriving() {
    use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
    const READERS: u64 = 4;
    const LIMIT: u64 = 1_000_000;
    let f = field() as usize;
    let other = field() as usize;
    let done = AtomicU64::new(0);
    let stop = AtomicBool::new(false);
    let mut during = Vec::new();
    std::thread::scope(|s| {
        for t in 0..READERS {
            let (done, stop) = (&done, &stop);
            s.spawn(move || {
                let f = f as *const sdg_field;
                for i in 0..LIMIT {
                    if stop.load(Ordering::Relaxed) {
                        break;
                    }
                    let u = ((i * 7 + t) % 1000) as f32 / 1000.0;
                    let (mut d, mut p) = (sdg_vec3::default(), 0.0f32);
                    // SAFETY: the field outlives the scope; pointers are valid.
                    unsafe {
                        sdg_field_sample(f, v(u, 0.5, 1.0 - u), u, 1.0 - u, &mut d, &mut p);
                        let sample = sdg_sample {
                            position: v(u, 0.5, 0.5),
                            direction: d,
                            value: 1.0,
                            pdf: p,
                            ..Default::default()
                        };
                        sdg_field_record(f, &sample);
                    }
                    done.fetch_add(1, Ordering::Relaxed);
                }
            });
        }
        // Let the readers get going, then refine and merge a few times while they run.
        while done.load(Ordering::Relaxed) < 10_000 {
            std::thread::yield_now();
        }
        for _ in 0..3 {
            let before = done.load(Ordering::Relaxed);
            // SAFETY: valid handles.
            unsafe {
                assert_eq!(sdg_field_refine(f as *mut sdg_field), sdg_status::Ok);
                // The fields' trees differ once `f` has refined: the merge is refused, but
                // only after it has taken the lock, which is what is measured.
                let merged = sdg_field_merge(f as *mut sdg_field, other as *const sdg_field);
                assert!(
                    matches!(merged, sdg_status::Ok | sdg_status::Merge),
                    "{merged:?}"
                );
            }
            during.push(done.load(Ordering::Relaxed) - before);
        }
        stop.store(true, Ordering::Relaxed);
    });
    // Bounded: a writer that blocks new readers waits for the operations in flight (one per
    // reader) plus those that ran before it queued, which depends only on how long the
    // scheduler keeps this thread from queueing (the readers run about a million operations a
    // second on 2 cores; measured: 0 to 13,445). A tenth of the readers' budget is 400 ms of
    // that; a starved writer sees nearly all of it (3.1 million before the lock was fair).
    for &ops in &during {
        assert!(
            ops < READERS * LIMIT / 10,
            "a refine and a merge waited through {ops} reader operations ({during:?})"
        );
    }
    // SAFETY: destroyed once.
    unsafe {
        sdg_field_destroy(f as *mut sdg_field);
        sdg_field_destroy(other as *mut sdg_field);
    }
}

#[test]
fn a_distribution_with_a_normal_samples_the_product_with_the_cosine() {
    let f = field();
    let mut dist = null_mut();
    let (mut d, mut p, mut q) = (sdg_vec3::default(), 0.0f32, 0.0f32);
    // SAFETY: valid pointers throughout; the distribution is destroyed before the field.
    unsafe {
        assert_eq!(
            sdg_field_distribution(f, v(0.5, 0.5, 0.5), &mut dist),
            sdg_status::Ok
        );
        assert_eq!(
            sdg_distribution_set_normal(dist, v(0.0, 0.0, 2.0)),
            sdg_status::Ok
        );
        // Straight below the surface: almost nothing; every draw above it, with its own pdf.
        let mut up = 0.0f32;
        assert_eq!(
            sdg_distribution_pdf(dist, v(0.0, 0.0, 1.0), &mut up),
            sdg_status::Ok
        );
        assert_eq!(
            sdg_distribution_pdf(dist, v(0.0, 0.0, -1.0), &mut q),
            sdg_status::Ok
        );
        assert!(q < 1e-4 * up, "{q} vs {up}");
        for k in 0..64 {
            let u = (k as f32 + 0.5) / 64.0;
            assert_eq!(
                sdg_distribution_sample(dist, u, 1.0 - u, &mut d, &mut p),
                sdg_status::Ok
            );
            assert_eq!(sdg_distribution_pdf(dist, d, &mut q), sdg_status::Ok);
            assert!(
                d.z > 0.0 && p > 0.0 && p == q,
                "({}, {}, {}): {p} vs {q}",
                d.x,
                d.y,
                d.z
            );
        }
        // A non-finite normal is refused and changes nothing; a zero one restores the plain
        // distribution, which puts mass below.
        assert_eq!(
            sdg_distribution_set_normal(dist, v(f32::NAN, 0.0, 1.0)),
            sdg_status::InvalidArgument
        );
        assert!(last_error().contains("normal"), "{}", last_error());
        assert_eq!(
            sdg_distribution_pdf(dist, v(0.0, 0.0, -1.0), &mut q),
            sdg_status::Ok
        );
        assert!(q < 1e-4 * up, "{q} vs {up}");
        assert_eq!(
            sdg_distribution_set_normal(dist, v(0.0, 0.0, 0.0)),
            sdg_status::Ok
        );
        assert_eq!(
            sdg_distribution_pdf(dist, v(0.0, 0.0, -1.0), &mut q),
            sdg_status::Ok
        );
        assert!((q - 1.0 / (4.0 * std::f32::consts::PI)).abs() < 1e-6, "{q}");
        assert_eq!(
            sdg_distribution_set_normal(null_mut(), v(0.0, 0.0, 1.0)),
            sdg_status::NullPointer
        );
        sdg_distribution_destroy(dist);
        sdg_field_destroy(f);
    }
}

#[test]
fn continuations_are_recorded_and_give_a_splitting_factor() {
    let f = field();
    let policy = sdg_splitting {
        mode: SDG_SPLITTING_ROULETTE_AND_SPLITTING,
        relative_variance: 0.25,
        cost: 10.0,
        min_survival: 0.05,
        max_splits: 8.0,
    };
    let c = sdg_continuation {
        position: v(0.5, 0.5, 0.5),
        value: 2.0,
        cost: 2.5,
    };
    let mut q = -1.0f32;
    // SAFETY: valid pointers throughout; the field is destroyed last.
    unsafe {
        // Before any estimate: no factor (0).
        assert_eq!(
            sdg_field_splitting_factor(f, v(0.5, 0.5, 0.5), &policy, 1.0, 1.0, &mut q),
            sdg_status::Ok
        );
        assert_eq!(q, 0.0);
        for _ in 0..32 {
            assert_eq!(sdg_field_record_continuation(f, &c), sdg_status::Ok);
        }
        let bad = sdg_continuation {
            cost: f32::NAN,
            ..c
        };
        assert_eq!(
            sdg_field_record_continuation(f, &bad),
            sdg_status::SampleRejected
        );
        assert_eq!(
            sdg_field_record_continuation(null(), &c),
            sdg_status::NullPointer
        );
        assert_eq!(
            sdg_field_record_continuation(f, null()),
            sdg_status::NullPointer
        );
        // The 32 accepted continuations are counted, and the rejected one as rejected.
        let mut stats = sdg_stats::default();
        assert_eq!(sdg_field_stats(f, &mut stats), sdg_status::Ok);
        assert_eq!(stats.continuations_recorded, 32);
        assert_eq!(stats.rejected.iter().sum::<u64>(), 1);
        assert_eq!(sdg_field_refine(f), sdg_status::Ok);
        // Mean 2, second moment 4, cost 2.5: (T/P)·sqrt(M₂·C̄/(V̄·c)) = 0.05·2·4 = 0.4.
        assert_eq!(
            sdg_field_splitting_factor(f, v(0.5, 0.5, 0.5), &policy, 0.05, 1.0, &mut q),
            sdg_status::Ok
        );
        assert!((q - 0.4).abs() < 1e-6, "{q}");
        // An unknown mode, bounds out of range and null pointers are refused.
        let unknown = sdg_splitting { mode: 7, ..policy };
        assert_eq!(
            sdg_field_splitting_factor(f, v(0.5, 0.5, 0.5), &unknown, 1.0, 1.0, &mut q),
            sdg_status::InvalidArgument
        );
        let bounds = sdg_splitting {
            min_survival: 0.0,
            ..policy
        };
        assert_eq!(
            sdg_field_splitting_factor(f, v(0.5, 0.5, 0.5), &bounds, 1.0, 1.0, &mut q),
            sdg_status::InvalidArgument
        );
        assert!(last_error().contains("min_survival"), "{}", last_error());
        assert_eq!(
            sdg_field_splitting_factor(f, v(0.5, 0.5, 0.5), &policy, 1.0, 1.0, null_mut()),
            sdg_status::NullPointer
        );
        sdg_field_destroy(f);
    }
}

#[test]
fn optional_fields_are_read_only_with_their_flags() {
    let f = field();
    let good = sdg_sample {
        position: v(0.5, 0.5, 0.5),
        direction: v(0.0, 0.0, 1.0),
        value: 1.0,
        pdf: 0.5,
        ..Default::default()
    };
    // SAFETY: valid pointers throughout.
    unsafe {
        // Values that would reject the sample are not read without their flags.
        let unflagged = sdg_sample {
            integrand: 1.0,
            bsdf_pdf: -1.0,
            second_moment: -1.0,
            normal: v(f32::NAN, 0.0, 0.0),
            ..good
        };
        assert_eq!(sdg_field_record(f, &unflagged), sdg_status::Ok);
        for flag in [SDG_SAMPLE_MIXTURE, SDG_SAMPLE_SECOND_MOMENT] {
            let flagged = sdg_sample {
                flags: flag,
                ..unflagged
            };
            assert_eq!(sdg_field_record(f, &flagged), sdg_status::SampleRejected);
        }
        sdg_field_destroy(f);

        // The guide cost: absent by default and without its flag (whatever the number),
        // validated with it.
        let config = config();
        assert_eq!(config.flags & SDG_CONFIG_GUIDE_COST, 0);
        let mut out = null_mut();
        let absent = sdg_config {
            guide_cost: f32::NAN,
            flags: 0,
            ..config
        };
        let (lo, hi) = (v(0.0, 0.0, 0.0), v(1.0, 1.0, 1.0));
        assert_eq!(sdg_field_create(&absent, lo, hi, &mut out), sdg_status::Ok);
        sdg_field_destroy(out);
        let bad = sdg_config {
            guide_cost: f32::NAN,
            flags: config.flags | SDG_CONFIG_GUIDE_COST,
            ..config
        };
        assert_eq!(sdg_field_create(&bad, lo, hi, &mut out), sdg_status::Config);
        assert!(last_error().contains("guide_cost"), "{}", last_error());
    }
}

#[test]
fn batch_calls_are_the_one_vertex_calls_and_refuse_bad_lanes() {
    let f = field();
    let mut rng = Rng::new(31);
    let mut next = || rng.next_f32();
    // SAFETY: valid pointers throughout, arrays of the lengths passed.
    unsafe {
        // Train a little, so the distributions are not all uniform.
        for _ in 0..3 {
            for _ in 0..20_000 {
                let s = sdg_sample {
                    position: v(next(), next(), next()),
                    direction: v(next() - 0.5, next() - 0.5, 0.2),
                    value: 1.0,
                    pdf: 0.1,
                    ..Default::default()
                };
                sdg_field_record(f, &s);
            }
            assert_eq!(sdg_field_refine(f), sdg_status::Ok);
        }
        let n = 3000;
        let positions: Vec<sdg_vec3> = (0..n).map(|_| v(next(), next(), next())).collect();
        let normals: Vec<sdg_vec3> = (0..n).map(|i| v(0.0, (i % 2) as f32, 1.0)).collect();
        let u: Vec<f32> = (0..2 * n).map(|_| next()).collect();
        let (mut d, mut p) = (vec![sdg_vec3::default(); n], vec![0.0f32; n]);
        for normals in [null(), normals.as_ptr()] {
            let status = sdg_field_sample_batch(
                f,
                n,
                positions.as_ptr(),
                normals,
                u.as_ptr(),
                d.as_mut_ptr(),
                p.as_mut_ptr(),
            );
            assert_eq!(status, sdg_status::Ok);
            let mut back = vec![0.0f32; n];
            let status = sdg_field_pdf_batch(
                f,
                n,
                positions.as_ptr(),
                normals,
                d.as_ptr(),
                back.as_mut_ptr(),
            );
            assert_eq!(status, sdg_status::Ok);
            for i in (0..n).step_by(37) {
                let mut dist = null_mut();
                assert_eq!(
                    sdg_field_distribution(f, positions[i], &mut dist),
                    sdg_status::Ok
                );
                if !normals.is_null() {
                    sdg_distribution_set_normal(dist, *normals.add(i));
                }
                let (mut one_d, mut one_p, mut one_q) = (sdg_vec3::default(), 0.0, 0.0);
                sdg_distribution_sample(dist, u[2 * i], u[2 * i + 1], &mut one_d, &mut one_p);
                sdg_distribution_pdf(dist, one_d, &mut one_q);
                sdg_distribution_destroy(dist);
                assert_eq!((d[i], p[i].to_bits()), (one_d, one_p.to_bits()), "lane {i}");
                assert_eq!(back[i].to_bits(), one_q.to_bits(), "lane {i}");
            }
        }
        let mut a = vec![0.0f32; n];
        assert_eq!(
            sdg_field_guide_probability_batch(f, n, positions.as_ptr(), a.as_mut_ptr()),
            sdg_status::Ok
        );
        assert!(a.iter().all(|&a| (0.0..=1.0).contains(&a)));
        // A non-finite lane is refused, naming it, and nothing is written.
        let mut bad = positions.clone();
        bad[7].y = f32::NAN;
        p.fill(-1.0);
        assert_eq!(
            sdg_field_sample_batch(
                f,
                n,
                bad.as_ptr(),
                null(),
                u.as_ptr(),
                d.as_mut_ptr(),
                p.as_mut_ptr()
            ),
            sdg_status::InvalidArgument
        );
        assert!(last_error().contains("lane 7"), "{}", last_error());
        assert!(p.iter().all(|&p| p == -1.0));
        // Null arrays are refused unless there are no lanes.
        assert_eq!(
            sdg_field_pdf_batch(f, n, positions.as_ptr(), null(), null(), p.as_mut_ptr()),
            sdg_status::NullPointer
        );
        assert_eq!(
            sdg_field_pdf_batch(f, 0, null(), null(), null(), null_mut()),
            sdg_status::Ok
        );
        sdg_field_destroy(f);
    }
}

#[test]
fn the_path_recorder_records_a_path_and_refuses_bad_calls() {
    let f = field();
    let mut path = null_mut();
    // SAFETY: valid pointers throughout; null ones are the point of the checks.
    unsafe {
        assert_eq!(sdg_path_create(0, &mut path), sdg_status::Ok);
        assert_eq!(sdg_path_create(0, null_mut()), sdg_status::NullPointer);
        let mut camera = u32::MAX;
        assert_eq!(sdg_path_start(path, &mut camera), sdg_status::Ok);
        assert_eq!(camera, 0);
        // A floor vertex drawing up (f·cos 0.2, pdf 0.5), roulette 0.5 survived, a lamp of 1.
        let vertex = sdg_path_vertex {
            position: v(0.5, 0.1, 0.5),
            normal: v(0.0, 1.0, 0.0),
            direction: v(0.0, 1.0, 0.0),
            bsdf: v(0.2, 0.2, 0.2),
            pdf: 0.5,
            bsdf_pdf: 0.4,
            guide_pdf: 0.6,
            flags: SDG_SAMPLE_MIXTURE | SDG_SAMPLE_NORMAL,
        };
        let mut id = 0;
        assert_eq!(
            sdg_path_push(path, camera, &vertex, &mut id),
            sdg_status::Ok
        );
        assert_eq!(id, 1);
        assert_eq!(sdg_path_roulette(path, id, 0.5, 1), sdg_status::Ok);
        assert_eq!(
            sdg_path_add_radiance(path, id, v(1.0, 1.0, 1.0)),
            sdg_status::Ok
        );
        assert_eq!(
            sdg_path_add_radiance(path, id, v(f32::NAN, 1.0, 1.0)),
            sdg_status::Ok
        );
        assert_eq!(sdg_path_add_cost(path, id, 1.0), sdg_status::Ok);
        assert_eq!(sdg_path_split(path, 7, 2.0, 2), sdg_status::Ok); // an unknown handle
        let mut estimate = sdg_vec3::default();
        assert_eq!(sdg_path_finish(path, &mut estimate), sdg_status::Ok);
        assert!(
            (estimate.x - 0.2 / 0.5 * 1.0 / 0.5).abs() < 1e-6,
            "{estimate:?}"
        );
        let mut recorded = 0;
        assert_eq!(sdg_path_record(path, f, &mut recorded), sdg_status::Ok);
        assert_eq!(recorded, 1);
        assert_eq!(
            sdg_path_record(path, null(), &mut recorded),
            sdg_status::NullPointer
        );
        assert_eq!(
            sdg_path_push(path, 0, null(), &mut id),
            sdg_status::NullPointer
        );
        assert_eq!(
            sdg_path_finish(null_mut(), &mut estimate),
            sdg_status::NullPointer
        );
        assert_eq!(
            sdg_path_add_radiance(null_mut(), 0, v(1.0, 1.0, 1.0)),
            sdg_status::NullPointer
        );
        let mut stats = sdg_path_recorder_stats::default();
        assert_eq!(sdg_path_stats(path, &mut stats), sdg_status::Ok);
        assert_eq!(
            (stats.paths, stats.bad_values, stats.bad_vertices),
            (1, 2, 0)
        );
        let mut field_stats = sdg_stats::default();
        assert_eq!(sdg_field_stats(f, &mut field_stats), sdg_status::Ok);
        assert_eq!(
            (
                field_stats.samples_recorded,
                field_stats.continuations_recorded
            ),
            (1, 1)
        );
        sdg_path_destroy(path);
        sdg_path_destroy(null_mut());
        sdg_field_destroy(f);
    }
}
