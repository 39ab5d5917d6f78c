//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use photonkit::format::{Output as Target, PhotonMap, write_map};
use photonkit::synthetic::SyntheticMap;

/// Makes one sample's photons.
pub type Generator = fn() -> SyntheticMap;

/// The sample files: (file name, generator).
pub const SAMPLES: &[(&str, Generator)] = &[
    ("collimated-cusp.phm", || photonkit::synthetic::collimated_cusp(2000, 11)),
    ("point-ring.phm", || photonkit::synthetic::point_ring(1500, 12)),
    ("two-emitters.phm", || photonkit::synthetic::two_emitters(1500, 13)),
];

/// The fixed history time stamped into sample files so they are reproducible.
pub const SAMPLE_TIME: &str = "2026-11-23T00:00:00Z";

pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

pub fn sample_path(name: &str) -> PathBuf {
    root().join("samples").join(name)
}

/// Writes a synthetic map to `path` the way the samples are written.
pub fn write_synthetic(m: &SyntheticMap, generator: &str, path: &Path) {
    write_map(Target::Path(path.to_path_buf()), m.info(generator, 0, SAMPLE_TIME), &m.columns()).unwrap();
}

/// Writes a synthetic map into memory (via a temporary file) and returns its bytes.
pub fn synthetic_bytes(m: &SyntheticMap) -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("m.phm");
    write_synthetic(m, "test", &p);
    std::fs::read(&p).unwrap()
}

pub fn open_bytes(bytes: &[u8]) -> PhotonMap {
    PhotonMap::from_bytes("test.phm", bytes).unwrap()
}

/// Runs the photonkit binary.
pub fn photonkit(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_photonkit")).args(args).output().unwrap()
}

pub fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// `bytes` (a PHM file whose column bytes were edited) with every column CRC-32 and the
/// metadata CRC-32 recomputed: a semantic corruption that the checksums no longer catch.
pub fn with_fixed_checksums(bytes: &[u8]) -> Vec<u8> {
    let mut out = bytes.to_vec();
    let meta_len = u64::from_le_bytes(bytes[16..24].try_into().unwrap()) as usize;
    let region = &bytes[32..32 + meta_len];
    let mut meta: serde_json::Value = serde_json::from_slice(region).unwrap();
    for c in meta["columns"].as_array_mut().unwrap() {
        let (offset, length) =
            (c["offset"].as_u64().unwrap() as usize, c["length"].as_u64().unwrap() as usize);
        c["crc32"] = crc32fast::hash(&bytes[offset..offset + length]).into();
    }
    let mut text = serde_json::to_vec(&meta).unwrap();
    assert!(text.len() < meta_len);
    text.resize(meta_len - 1, b' ');
    text.push(b'\n');
    out[32..32 + meta_len].copy_from_slice(&text);
    out[12..16].copy_from_slice(&crc32fast::hash(&text).to_le_bytes());
    out
}
