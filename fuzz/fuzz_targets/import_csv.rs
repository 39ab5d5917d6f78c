//! Feeds arbitrary bytes to the CSV/TSV importer: photons or an error, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use photonkit::import::{Options, csv};

fuzz_target!(|data: &[u8]| {
    if let Ok(m) = csv::read("fuzz.csv", data, &Options::default()) {
        assert!(m.columns.iter().any(|(s, _)| s.name == "flux"));
    }
});
