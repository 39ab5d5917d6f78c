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
