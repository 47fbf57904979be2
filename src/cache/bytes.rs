//! Little-endian byte writing and bounds-checked reading: every read names the section it
//! is in, and no count is trusted before the bytes for it are there.

use super::*;

/// A little-endian byte writer.
pub(super) struct Out(pub(super) Vec<u8>);

impl Out {
    pub(super) fn u8(&mut self, v: u8) {
        self.0.push(v);
    }
    pub(super) fn u16(&mut self, v: u16) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(super) fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(super) fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(super) fn f32(&mut self, v: f32) {
        self.u32(v.to_bits());
    }
    pub(super) fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    pub(super) fn vec3(&mut self, v: Vec3) {
        for c in v.to_array() {
            self.f32(c);
        }
    }
    /// An exact sum: its units as a little-endian `u128`.
    pub(super) fn sum(&mut self, s: Sum) {
        self.0.extend_from_slice(&s.units().to_le_bytes());
    }
    /// A signed exact sum: its units in two's complement.
    pub(super) fn signed(&mut self, s: Signed) {
        self.0.extend_from_slice(&s.units().to_le_bytes());
    }
}

/// A little-endian reader over one section; reading past its end is corruption (the file's
/// length was already checked, so a short section means a wrong length in its table entry).
pub(super) struct In<'a> {
    pub(super) bytes: &'a [u8],
    pub(super) section: &'static str,
    /// Whether sums are stored as in 2.x: as `f64`, converted exactly or refused.
    pub(super) legacy: bool,
}

impl<'a> In<'a> {
    pub(super) fn new(bytes: &'a [u8], section: &'static str) -> Self {
        Self {
            bytes,
            section,
            legacy: false,
        }
    }
    /// A reader of sums written by format `major`.
    pub(super) fn with_sums(bytes: &'a [u8], section: &'static str, major: u16) -> Self {
        Self {
            legacy: major < FORMAT_MAJOR,
            ..Self::new(bytes, section)
        }
    }
    pub(super) fn take(&mut self, n: usize) -> Result<&'a [u8], CacheError> {
        if n > self.bytes.len() {
            return Err(corrupt(
                self.section,
                format!(
                    "ends early: {n} more bytes needed, {} left",
                    self.bytes.len()
                ),
            ));
        }
        let (head, tail) = self.bytes.split_at(n);
        self.bytes = tail;
        Ok(head)
    }
    pub(super) fn array<const N: usize>(&mut self) -> Result<[u8; N], CacheError> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N)?);
        Ok(a)
    }
    pub(super) fn u8(&mut self) -> Result<u8, CacheError> {
        Ok(self.array::<1>()?[0])
    }
    pub(super) fn u16(&mut self) -> Result<u16, CacheError> {
        Ok(u16::from_le_bytes(self.array()?))
    }
    pub(super) fn u32(&mut self) -> Result<u32, CacheError> {
        Ok(u32::from_le_bytes(self.array()?))
    }
    pub(super) fn u64(&mut self) -> Result<u64, CacheError> {
        Ok(u64::from_le_bytes(self.array()?))
    }
    pub(super) fn f32(&mut self) -> Result<f32, CacheError> {
        Ok(f32::from_bits(self.u32()?))
    }
    pub(super) fn f64(&mut self) -> Result<f64, CacheError> {
        Ok(f64::from_bits(self.u64()?))
    }
    pub(super) fn vec3(&mut self) -> Result<Vec3, CacheError> {
        Ok(Vec3::new(self.f32()?, self.f32()?, self.f32()?))
    }
    fn u128(&mut self) -> Result<u128, CacheError> {
        Ok(u128::from_le_bytes(self.array()?))
    }
    /// A 2.x sum, an `f64`: finite (and non-negative unless `signed`), then converted exactly.
    fn legacy_sum<T>(
        &mut self,
        signed: bool,
        exactly: fn(f64) -> Option<T>,
    ) -> Result<T, CacheError> {
        let x = self.f64()?;
        if !(x.is_finite() && (signed || x >= 0.0)) {
            return Err(corrupt(self.section, format!("sum {x}")));
        }
        exactly(x).ok_or(CacheError::Inexact {
            section: self.section,
            value: x,
        })
    }
    /// A non-negative exact sum (see [`Out::sum`]).
    pub(super) fn sum(&mut self) -> Result<Sum, CacheError> {
        if self.legacy {
            return self.legacy_sum(false, Sum::exactly);
        }
        let u = self.u128()?;
        Sum::checked(u)
            .ok_or_else(|| corrupt(self.section, format!("sum of {u} units, past the range")))
    }
    /// A signed exact sum (see [`Out::signed`]).
    pub(super) fn signed(&mut self) -> Result<Signed, CacheError> {
        if self.legacy {
            return self.legacy_sum(true, Signed::exactly);
        }
        Ok(Signed::from_units(self.u128()?))
    }
    /// A `u32` element count, checked against the bytes left before anyone allocates for it.
    pub(super) fn count(&mut self, element_len: usize, what: &str) -> Result<usize, CacheError> {
        let n = self.u32()? as usize;
        if n.saturating_mul(element_len) > self.bytes.len() {
            return Err(corrupt(
                self.section,
                format!("{n} {what} declared, only {} bytes left", self.bytes.len()),
            ));
        }
        Ok(n)
    }
}
