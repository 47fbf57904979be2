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
}

/// A little-endian reader over one section; reading past its end is corruption (the file's
/// length was already checked, so a short section means a wrong length in its table entry).
pub(super) struct In<'a> {
    pub(super) bytes: &'a [u8],
    pub(super) section: &'static str,
}

impl<'a> In<'a> {
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
