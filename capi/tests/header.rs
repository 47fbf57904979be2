//! The checked-in header must be what cbindgen generates from the current API.
//! `SDGUIDE_UPDATE_HEADER=1 cargo test -p sdguide-capi --test header` rewrites it.

use std::path::Path;

#[test]
fn checked_in_header_is_up_to_date() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let config = cbindgen::Config::from_file(dir.join("cbindgen.toml")).unwrap();
    let mut generated = Vec::new();
    cbindgen::Builder::new()
        .with_crate(dir)
        .with_config(config)
        .generate()
        .expect("cbindgen parses the C API")
        .write(&mut generated);
    let generated = String::from_utf8(generated).unwrap();
    let path = dir.join("include/sdguide.h");
    if std::env::var_os("SDGUIDE_UPDATE_HEADER").is_some() {
        std::fs::write(&path, &generated).unwrap();
    }
    let checked_in = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        checked_in == generated,
        "{} is out of date: run `SDGUIDE_UPDATE_HEADER=1 cargo test -p sdguide-capi --test header`",
        path.display()
    );
}
