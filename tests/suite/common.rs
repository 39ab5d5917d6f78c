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
    ("dispersed-beam.phm", || photonkit::synthetic::dispersed_beam(1500, 14)),
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

/// Every attribute of an EXR file's (single-part) header as (name, type, value bytes), parsed
/// from the bytes by the OpenEXR file layout alone, independently of the `exr` crate: magic
/// 76 2f 31 01, a 4-byte version, then `name\0type\0` + little-endian i32 size + value, until
/// an empty name.
pub fn exr_header(path: &Path) -> Vec<(String, String, Vec<u8>)> {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(bytes[..4], [0x76, 0x2f, 0x31, 0x01], "{}: not an EXR file", path.display());
    assert_eq!(bytes[4], 2, "{}: EXR version 2", path.display());
    let mut at = 8;
    let mut attrs = Vec::new();
    let cstr = |at: &mut usize| {
        let end = *at + bytes[*at..].iter().position(|&b| b == 0).expect("a NUL-terminated name");
        let s = std::str::from_utf8(&bytes[*at..end]).expect("an attribute name in UTF-8").to_string();
        *at = end + 1;
        s
    };
    loop {
        let name = cstr(&mut at);
        if name.is_empty() {
            return attrs;
        }
        let kind = cstr(&mut at);
        let size = i32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
        assert!(size >= 0, "{}: attribute {name} has size {size}", path.display());
        let value = bytes[at + 4..at + 4 + size as usize].to_vec();
        at += 4 + size as usize;
        attrs.push((name, kind, value));
    }
}

/// [`photonkit::render::image::read_exr`], after checking with [`exr_header`] that the header
/// holds the attributes every EXR reader requires and that each text attribute is UTF-8
/// (OpenEXR's own bindings refuse anything else; issue 31, items 10 and 13).
pub fn read_exr(path: &Path) -> (photonkit::render::Image, Vec<(String, String)>) {
    let attrs = exr_header(path);
    for required in
        ["channels", "compression", "dataWindow", "displayWindow", "lineOrder", "pixelAspectRatio"]
    {
        assert!(attrs.iter().any(|(n, _, _)| n == required), "{}: no {required}", path.display());
    }
    for (name, kind, value) in &attrs {
        if kind == "string" {
            assert!(std::str::from_utf8(value).is_ok(), "{}: attribute {name} is not UTF-8", path.display());
        }
    }
    photonkit::render::image::read_exr(path).unwrap()
}
