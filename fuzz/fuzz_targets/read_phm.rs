//! Feeds arbitrary bytes to the PHM reader. A file that opens must also survive everything
//! `photonkit inspect` does with it: checksum verification, the summary and the invariant check.
//!
//! Almost every mutation of a valid file breaks the metadata CRC-32 or the file length, which
//! the reader checks first; so each input is also tried with those two preamble fields
//! repaired, to let the fuzzer reach the JSON, the column table and `inspect`.
#![no_main]

use libfuzzer_sys::fuzz_target;
use photonkit::format::PhotonMap;
use photonkit::format::preamble::{MAGIC, PREAMBLE_LEN};

fn exercise(data: &[u8]) {
    if let Ok(map) = PhotonMap::from_bytes("fuzz.phm", data) {
        let _ = map.verify_checksums();
        let summary = photonkit::inspect::summarize(&map);
        assert_eq!(summary.photon_count as usize, map.len());
        let _ = photonkit::inspect::check(&map);
    }
}

/// The input with `file_len` set to its length and `metadata_crc32` to the CRC of the region
/// `metadata_len` describes (when that region lies inside the input).
fn repaired(data: &[u8]) -> Option<Vec<u8>> {
    if data.len() < PREAMBLE_LEN || data[..8] != MAGIC {
        return None;
    }
    let mut fixed = data.to_vec();
    fixed[24..32].copy_from_slice(&(data.len() as u64).to_le_bytes());
    let len = u64::from_le_bytes(data[16..24].try_into().unwrap());
    if let Some(end) = len.checked_add(PREAMBLE_LEN as u64).filter(|&e| e <= data.len() as u64) {
        let crc = crc32fast::hash(&data[PREAMBLE_LEN..end as usize]);
        fixed[12..16].copy_from_slice(&crc.to_le_bytes());
    }
    (fixed != data).then_some(fixed)
}

fuzz_target!(|data: &[u8]| {
    exercise(data);
    if let Some(fixed) = repaired(data) {
        exercise(&fixed);
    }
});
