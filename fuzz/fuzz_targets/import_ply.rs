//! Feeds arbitrary bytes to the PLY importer: it must return photons or an error, never
//! panic, and what it returns must be a writable, checkable map.
#![no_main]

use libfuzzer_sys::fuzz_target;
use photonkit::import::{Options, ply};

fuzz_target!(|data: &[u8]| {
    for flux_from_colour in [false, true] {
        let options = Options { flux_from_colour, ..Options::default() };
        if let Ok(m) = ply::read("fuzz.ply", data, &options) {
            assert!(m.columns.iter().any(|(s, _)| s.name == "position"));
        }
    }
});
