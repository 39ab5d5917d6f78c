//! The files in samples/ are what the generators write; `PHOTONKIT_BLESS=1` rewrites them.

use super::common::*;

#[test]
fn sample_files_match_their_generators() {
    let bless = std::env::var_os("PHOTONKIT_BLESS").is_some();
    let dir = tempfile::tempdir().unwrap();
    for (file, generate) in SAMPLES {
        let m = generate();
        let fresh = dir.path().join(file);
        write_synthetic(&m, file.trim_end_matches(".phm"), &fresh);
        if bless {
            std::fs::copy(&fresh, sample_path(file)).unwrap();
        }
        let committed = std::fs::read(sample_path(file)).expect("sample missing: run with PHOTONKIT_BLESS=1");
        assert!(committed == std::fs::read(&fresh).unwrap(), "{file} differs from its generator's output");
    }
}

/// samples/minimal.phm is the worked example of format-spec/phm-v1.md §10.
#[test]
fn minimal_sample_is_the_spec_example() {
    use photonkit::format::{ColumnSpec, MapInfo, Output, State, write_map};
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("minimal.phm");
    let (pos, flux) = ([[0.5f32, 0.25, 0.0]], [[0.01f32; 3]]);
    write_map(
        Output::Path(p.clone()),
        MapInfo::new(vec![], State::Traced),
        &[
            (ColumnSpec::of::<[f32; 3]>("position"), bytemuck::cast_slice(&pos)),
            (ColumnSpec::of::<[f32; 3]>("flux"), bytemuck::cast_slice(&flux)),
        ],
    )
    .unwrap();
    let fresh = std::fs::read(&p).unwrap();
    assert_eq!(fresh, std::fs::read(sample_path("minimal.phm")).unwrap());
    // The bytes the spec's table quotes.
    assert_eq!(fresh.len(), 960);
    assert_eq!(
        &fresh[0..32],
        &[
            0x89, 0x50, 0x48, 0x4D, 0x0D, 0x0A, 0x1A, 0x0A, 1, 0, 0, 0, 0xEB, 0xBE, 0x62, 0x1B, 0x20, 3, 0,
            0, 0, 0, 0, 0, 0xC0, 3, 0, 0, 0, 0, 0, 0
        ]
    );
    assert_eq!(&fresh[832..844], &[0, 0, 0, 0x3F, 0, 0, 0x80, 0x3E, 0, 0, 0, 0]);
    assert_eq!(&fresh[896..900], &[0x0A, 0xD7, 0x23, 0x3C]);
    assert_eq!(fresh[831], b'\n');
}
