//! The distribution handle: a position's distribution — at a surface, with or without its
//! normal, or inside a medium, with or without its phase function — holding the field's lock
//! shared while it lives.

use crate::error::finite_u;
use crate::error::{arg, fail, finite, guard, put, sdg_status};
use crate::field::{destroy, sdg_field, write_sample};
use crate::lock::{HELD, reentrant};
use crate::types::sdg_vec3;
use glam::{Vec2, Vec3};
use parking_lot::RawRwLock;
use parking_lot::lock_api::ArcRwLockReadGuard;
use sdguide::GuidingField;

/// The distribution of one position (opaque), from `sdg_field_distribution`. It holds the
/// field's lock shared: destroy it with `sdg_distribution_destroy` before refining, or the
/// refine waits for it.
pub struct sdg_distribution {
    pub(crate) field: ArcRwLockReadGuard<RawRwLock, GuidingField>,
    position: Vec3,
    /// The surface normal set by `sdg_distribution_set_normal` (zero: none).
    normal: Vec3,
    /// From `sdg_field_volume_distribution`: the volume guide's.
    volume: bool,
    /// The direction of travel and `g` set by `sdg_distribution_set_phase` (zero: none).
    phase: (Vec3, f32),
    /// The thread that made it, whose count of held distributions it is in.
    owner: std::thread::ThreadId,
}

impl Drop for sdg_distribution {
    fn drop(&mut self) {
        // Destroyed on another thread, the owner's count stays up: its calls keep re-entering,
        // which can delay a writer but never deadlock.
        if std::thread::current().id() == self.owner {
            HELD.with(|h| h.set(h.get().saturating_sub(1)));
        }
    }
}

/// Takes the distribution at `position`, for several `sdg_distribution_sample` /
/// `sdg_distribution_pdf` calls. It holds the field's lock shared until destroyed.
///
/// # Safety
/// `field` must be null or valid; `out` must be null or valid for writing a pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_distribution(
    field: *const sdg_field,
    position: sdg_vec3,
    out: *mut *mut sdg_distribution,
) -> sdg_status {
    // SAFETY: the caller's contract.
    unsafe { take_distribution(field, position, false, out) }
}

/// Takes the distribution of the volume guide at `position`, for a vertex inside a
/// participating medium (see the Rust `GuidingField::volume_distribution`): sample it with
/// `sdg_distribution_set_phase` set, and mix it with phase-function sampling by
/// `sdg_distribution_guide_probability` (0 in a field without `SDG_CONFIG_VOLUMES`, whose
/// volume distribution is uniform). It holds the field's lock shared until destroyed.
///
/// # Safety
/// `field` must be null or valid; `out` must be null or valid for writing a pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_field_volume_distribution(
    field: *const sdg_field,
    position: sdg_vec3,
    out: *mut *mut sdg_distribution,
) -> sdg_status {
    // SAFETY: the caller's contract.
    unsafe { take_distribution(field, position, true, out) }
}

/// `sdg_field_distribution` (`volume` false) and `sdg_field_volume_distribution`.
///
/// # Safety
/// As theirs.
unsafe fn take_distribution(
    field: *const sdg_field,
    position: sdg_vec3,
    volume: bool,
    out: *mut *mut sdg_distribution,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let f = unsafe { arg(field, "field") }?;
        let position = finite(position.into(), "position")?;
        if out.is_null() {
            return fail(sdg_status::NullPointer, "`out` is null");
        }
        // A thread holding a distribution may take another while a refine waits.
        let field = if reentrant() {
            f.inner.read_arc_recursive()
        } else {
            f.inner.read_arc()
        };
        HELD.with(|h| h.set(h.get().saturating_add(1)));
        let dist = Box::new(sdg_distribution {
            field,
            position,
            normal: Vec3::ZERO,
            volume,
            phase: (Vec3::ZERO, 0.0),
            owner: std::thread::current().id(),
        });
        // SAFETY: non-null, valid for writes by the caller's contract.
        unsafe { out.write(Box::into_raw(dist)) };
        Ok(sdg_status::Ok)
    })
}

/// Makes the distribution its product with the clamped cosine `max(0, n·ω)` about the surface
/// normal `normal` (any length; it is normalized), for a vertex on a surface that only
/// reflects: later `sdg_distribution_sample` and `sdg_distribution_pdf` calls sample and
/// evaluate the product (see the Rust `DirectionalDistribution::at_surface`). A zero normal
/// restores the plain distribution; a non-finite one is refused (`SDG_STATUS_INVALID_ARGUMENT`)
/// and leaves the distribution as it was.
///
/// # Safety
/// `dist` must be null or a live distribution, not used by another thread during the call.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_distribution_set_normal(
    dist: *mut sdg_distribution,
    normal: sdg_vec3,
) -> sdg_status {
    guard(|| {
        if dist.is_null() {
            return fail(sdg_status::NullPointer, "`dist` is null");
        }
        let n = finite(normal.into(), "normal")?;
        // SAFETY: non-null, live and not shared during the call by the caller's contract.
        unsafe { (*dist).normal = n };
        Ok(sdg_status::Ok)
    })
}

/// Makes a volume distribution its product with the Henyey–Greenstein phase function of
/// asymmetry `g` about `travel`, the direction the path travelled to reach the vertex (see the
/// Rust `DirectionalDistribution::with_phase`): later `sdg_distribution_sample` and
/// `sdg_distribution_pdf` calls sample and evaluate the product. `g` beyond ±0.999 is clamped
/// to it; `g = 0` or a zero `travel` restores the plain distribution; a non-finite `travel` or
/// `g` is refused (`SDG_STATUS_INVALID_ARGUMENT`), and so is a distribution from
/// `sdg_field_distribution` (a surface's), leaving the distribution as it was.
///
/// # Safety
/// `dist` must be null or a live distribution, not used by another thread during the call.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_distribution_set_phase(
    dist: *mut sdg_distribution,
    travel: sdg_vec3,
    g: f32,
) -> sdg_status {
    guard(|| {
        if dist.is_null() {
            return fail(sdg_status::NullPointer, "`dist` is null");
        }
        let travel = finite(travel.into(), "travel")?;
        if !g.is_finite() {
            return fail(sdg_status::InvalidArgument, "`g` is not finite");
        }
        // SAFETY: non-null, live and not shared during the call by the caller's contract.
        let d = unsafe { &mut *dist };
        if !d.volume {
            return fail(
                sdg_status::InvalidArgument,
                "a phase function on a surface distribution (take it with \
                 sdg_field_volume_distribution)",
            );
        }
        d.phase = (travel, g);
        Ok(sdg_status::Ok)
    })
}

impl sdg_distribution {
    /// `(direction, pdf)` of a draw from what the distribution samples: at a surface, the
    /// field's at its position, times the cosine if a normal is set; in a medium, the volume
    /// guide's, times the phase function if one is set.
    fn sample(&self, u: Vec2) -> (Vec3, f32) {
        if self.volume {
            let (travel, g) = self.phase;
            return self
                .field
                .volume_distribution(self.position)
                .with_phase(travel, g)
                .sample(u);
        }
        self.field
            .distribution(self.position)
            .at_surface(self.normal)
            .sample(u)
    }

    /// The pdf of `direction` under what the distribution samples.
    fn pdf(&self, direction: Vec3) -> f32 {
        if self.volume {
            let (travel, g) = self.phase;
            return self
                .field
                .volume_distribution(self.position)
                .with_phase(travel, g)
                .pdf(direction);
        }
        self.field
            .distribution(self.position)
            .at_surface(self.normal)
            .pdf(direction)
    }
}

/// Draws a direction from a distribution (see `sdg_field_sample`; with a normal set, from its
/// product with the cosine).
///
/// # Safety
/// `dist` must be null or a live distribution; `direction` and `pdf` null or valid for writes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_distribution_sample(
    dist: *const sdg_distribution,
    u0: f32,
    u1: f32,
    direction: *mut sdg_vec3,
    pdf: *mut f32,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let d = unsafe { arg(dist, "dist") }?;
        finite_u(u0, u1)?;
        let (dir, p) = d.sample(Vec2::new(u0, u1));
        // SAFETY: the caller's contract.
        unsafe { write_sample(direction, pdf, dir, p) }
    })
}

/// The solid-angle pdf of `direction` under a distribution (see `sdg_field_pdf`; with a
/// normal set, under its product with the cosine).
///
/// # Safety
/// `dist` must be null or a live distribution; `pdf` null or valid for writes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_distribution_pdf(
    dist: *const sdg_distribution,
    direction: sdg_vec3,
    pdf: *mut f32,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let d = unsafe { arg(dist, "dist") }?;
        let dir = finite(direction.into(), "direction")?;
        let p = d.pdf(dir);
        // SAFETY: the caller's contract.
        unsafe { put(pdf, "pdf", p) }?;
        Ok(sdg_status::Ok)
    })
}

/// The learned probability of sampling the guide rather than the BSDF (for a volume
/// distribution: the phase function) at the distribution's position, for the one-sample mixture `a·p_guide + (1 − a)·p_bsdf`: between 0.05 and the
/// configuration's `max_guide_probability`, 0.5 until learned from samples recorded with
/// mixture terms; 0 where the field turned the guide off (`guide_cost`): sample the BSDF
/// alone there, and skip the guide's pdf unless the pass records.
///
/// # Safety
/// `dist` must be null or a live distribution; `probability` null or valid for writes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_distribution_guide_probability(
    dist: *const sdg_distribution,
    probability: *mut f32,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let d = unsafe { arg(dist, "dist") }?;
        let a = if d.volume {
            d.field.volume_distribution(d.position).guide_probability()
        } else {
            d.field.distribution(d.position).guide_probability()
        };
        // SAFETY: the caller's contract.
        unsafe { put(probability, "probability", a) }?;
        Ok(sdg_status::Ok)
    })
}

/// Destroys a distribution, releasing its hold on the field. Null is ignored.
///
/// # Safety
/// `dist` must be null or a distribution from this library, not yet destroyed.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_distribution_destroy(dist: *mut sdg_distribution) {
    // SAFETY: created by `Box::into_raw` in `sdg_field_distribution`, destroyed once (the
    // caller's contract).
    unsafe { destroy(dist) }
}
