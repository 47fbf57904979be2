#![no_main]
//! Arbitrary configurations and sequences of record / refine / distribution / sample / pdf /
//! save / load / merge: never a panic, and the library's guarantees hold throughout.

use libfuzzer_sys::fuzz_target;

#[path = "../harness.rs"]
mod harness;

fuzz_target!(|data: &[u8]| harness::field_ops(data));
