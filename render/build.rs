//! With the `openpgl` feature: builds the vendored Intel Open PGL (CMake, oneTBB) into the build
//! directory under `target/` and links the demo against it. Without the feature: nothing.
//!
//! Open PGL is built with its experimental radiance caches (`OPENPGL_EF_RADIANCE_CACHES`), which
//! its guided Russian roulette takes its adjoint from; they change the layout of the sample
//! data the demo passes, so an installed Open PGL without them is refused. Its image-space
//! guiding buffer (`OPENPGL_EF_IMAGE_SPACE_GUIDING_BUFFER`) is left off: it needs Intel Open
//! Image Denoise 2.2 or later, which no registry this project builds from carries.
//!
//! Where the source comes from, in order: `OPENPGL_DIR`, an Open PGL already installed there
//! (nothing is built); `OPENPGL_TARBALL`, a release tarball; else the tarball vendored next to
//! the project, `../shared/vendor/openpgl-0.7.1.tar.gz` from the workspace root.

fn main() {
    #[cfg(feature = "openpgl")]
    openpgl::build();
}

#[cfg(feature = "openpgl")]
mod openpgl {
    use std::path::{Path, PathBuf};
    use std::process::Command;

    const TARBALL: &str = "openpgl-0.7.1.tar.gz";

    pub fn build() {
        println!("cargo:rerun-if-env-changed=OPENPGL_DIR");
        println!("cargo:rerun-if-env-changed=OPENPGL_TARBALL");
        let prefix = match std::env::var_os("OPENPGL_DIR") {
            Some(dir) => PathBuf::from(dir),
            None => build_vendored(),
        };
        let lib = ["lib", "lib64"]
            .iter()
            .map(|d| prefix.join(d))
            .find(|d| d.join("libopenpgl.so").exists())
            .unwrap_or_else(|| panic!("no libopenpgl.so under {}", prefix.display()));
        let version = version(&prefix.join("include/openpgl/version.h"));
        radiance_caches(&prefix.join("include/openpgl/defines.h"));
        println!("cargo:rustc-env=OPENPGL_VERSION={version}");
        println!("cargo:rustc-link-search=native={}", lib.display());
        println!("cargo:rustc-link-lib=dylib=openpgl");
        // The binary, tests and examples find the library where it was built, without
        // LD_LIBRARY_PATH.
        println!("cargo:rustc-link-arg=-Wl,-rpath,{}", lib.display());
    }

    fn build_vendored() -> PathBuf {
        let manifest = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").unwrap());
        let tarball = std::env::var_os("OPENPGL_TARBALL")
            .map(PathBuf::from)
            .unwrap_or_else(|| manifest.join("../../shared/vendor").join(TARBALL));
        assert!(
            tarball.exists(),
            "the openpgl feature needs the Open PGL source: {} is missing (set OPENPGL_TARBALL \
             to a release tarball, or OPENPGL_DIR to an installed Open PGL)",
            tarball.display()
        );
        println!("cargo:rerun-if-changed={}", tarball.display());
        let out = PathBuf::from(std::env::var_os("OUT_DIR").unwrap());
        let source = out.join("source");
        let _ = std::fs::remove_dir_all(&source);
        std::fs::create_dir_all(&source).unwrap();
        let status = Command::new("tar")
            .arg("xzf")
            .arg(&tarball)
            .arg("-C")
            .arg(&source)
            .status()
            .expect("tar runs");
        assert!(status.success(), "cannot unpack {}", tarball.display());
        let root = std::fs::read_dir(&source)
            .unwrap()
            .filter_map(Result::ok)
            .map(|e| e.path())
            .find(|p| p.join("CMakeLists.txt").exists())
            .expect("the tarball holds one source folder");
        // Release whatever cargo's profile: a debug Open PGL (asserts, no optimisation) would
        // not be the peer users run.
        cmake::Config::new(&root)
            .profile("Release")
            .define("OPENPGL_BUILD_STATIC", "OFF")
            .define("OPENPGL_BUILD_TOOLS", "OFF")
            .define("OPENPGL_EF_RADIANCE_CACHES", "ON")
            .build()
    }

    /// Panics unless the Open PGL under `defines.h` was built with its radiance caches: the
    /// demo's sample layout has their fields.
    fn radiance_caches(defines: &Path) {
        let text = std::fs::read_to_string(defines)
            .unwrap_or_else(|e| panic!("cannot read {}: {e}", defines.display()));
        assert!(
            text.lines()
                .any(|l| l.trim() == "#define OPENPGL_RADIANCE_CACHES"),
            "the Open PGL at {} was built without OPENPGL_EF_RADIANCE_CACHES, which the demo \
             needs (its guided Russian roulette, and the sample layout it passes)",
            defines.display()
        );
    }

    fn version(header: &Path) -> String {
        let text = std::fs::read_to_string(header)
            .unwrap_or_else(|e| panic!("cannot read {}: {e}", header.display()));
        text.lines()
            .find_map(|l| l.strip_prefix("#define OPENPGL_VERSION \""))
            .and_then(|rest| rest.split('"').next())
            .expect("version.h names the version")
            .to_string()
    }
}
