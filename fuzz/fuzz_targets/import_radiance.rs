//! Feeds arbitrary bytes to the Radiance photon-map importer (the in-core kd-tree layout):
//! photons or an error, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use photonkit::import::{Options, radiance};

fuzz_target!(|data: &[u8]| {
    let _ = radiance::read(std::path::Path::new("fuzz.pm"), data, &Options::default());
});
