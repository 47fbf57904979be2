#![no_main]
//! Arbitrary bytes loaded as a cache: never a panic; what loads saves back identically.

use libfuzzer_sys::fuzz_target;

#[path = "../harness.rs"]
mod harness;

fuzz_target!(|data: &[u8]| harness::cache_load(data));
