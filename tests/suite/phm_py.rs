//! tools/phm.py, the independent reader written from format-spec/phm-v1.md alone, must agree
//! with `photonkit inspect --json` on every sample and refuse what the spec says to refuse.
//!
//! Needs `python3` on PATH; without it these tests print a note and pass, unless
//! `PHOTONKIT_REQUIRE_PYTHON` is set, in which case they fail.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;

use super::common::*;

/// Whether `python3` can be run. Without it: a note on stderr and `false`, or a panic when
/// `PHOTONKIT_REQUIRE_PYTHON` is set.
fn have_python() -> bool {
    match Command::new("python3").arg("--version").output() {
        Ok(o) if o.status.success() => true,
        other => {
            let why = match other {
                Ok(o) => format!("`python3 --version` exited with {}", o.status),
                Err(e) => format!("cannot run `python3`: {e}"),
            };
            if std::env::var_os("PHOTONKIT_REQUIRE_PYTHON").is_some() {
                panic!("{why} (PHOTONKIT_REQUIRE_PYTHON is set)");
            }
            eprintln!(
                "note: skipping the tools/phm.py tests: {why} (set PHOTONKIT_REQUIRE_PYTHON to make this an error)"
            );
            false
        }
    }
}

fn phm_py(args: &[&str]) -> Output {
    Command::new("python3").arg(root().join("tools").join("phm.py")).args(args).output().unwrap()
}

/// The sample files, sorted by name.
fn samples() -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(root().join("samples"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "phm"))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no samples/*.phm");
    files
}

fn parse(o: &Output, who: &str, file: &Path) -> Value {
    assert!(o.status.success(), "{who} failed on {}: {}", file.display(), stderr(o));
    serde_json::from_str(&stdout(o))
        .unwrap_or_else(|e| panic!("{who} printed invalid JSON for {}: {e}", file.display()))
}

/// Floats agree if they are the same f32 (Rust prints f32 quantities in their shortest f32 form,
/// Python the f64 widening) or within 1e-12 relative.
fn floats_agree(a: f64, b: f64) -> bool {
    a == b || (a as f32) == (b as f32) || (a - b).abs() <= 1e-12 * a.abs().max(b.abs())
}

/// Compares two JSON values: integers and strings exactly, floats with `floats_agree`.
/// Returns the path of the first difference.
fn compare(py: &Value, rs: &Value, at: &str) -> Result<(), String> {
    let differ = || Err(format!("{at}: phm.py has {py}, photonkit has {rs}"));
    match (py, rs) {
        (Value::Object(a), Value::Object(b)) => {
            // Key sets, not order: photonkit prints `state` before `units` (see the report on §6).
            let (mut ka, mut kb): (Vec<_>, Vec<_>) = (a.keys().collect(), b.keys().collect());
            ka.sort();
            kb.sort();
            if ka != kb {
                return Err(format!("{at}: phm.py has keys {ka:?}, photonkit has {kb:?}"));
            }
            a.iter().try_for_each(|(k, v)| compare(v, &b[k], &format!("{at}.{k}")))
        }
        (Value::Array(a), Value::Array(b)) if a.len() == b.len() => {
            a.iter().zip(b).enumerate().try_for_each(|(i, (x, y))| compare(x, y, &format!("{at}[{i}]")))
        }
        (Value::Number(a), Value::Number(b)) if a.is_f64() && b.is_f64() => {
            if floats_agree(a.as_f64().unwrap(), b.as_f64().unwrap()) { Ok(()) } else { differ() }
        }
        (Value::Number(a), Value::Number(b)) if !a.is_f64() && !b.is_f64() => {
            if a == b {
                Ok(())
            } else {
                differ()
            }
        }
        (Value::String(a), Value::String(b)) if a == b => Ok(()),
        (Value::Bool(a), Value::Bool(b)) if a == b => Ok(()),
        (Value::Null, Value::Null) => Ok(()),
        _ => differ(),
    }
}

#[test]
fn phm_py_summary_matches_inspect_json_on_every_sample() {
    if !have_python() {
        return;
    }
    for file in samples() {
        let path = file.to_str().unwrap();
        let py = parse(&phm_py(&["--check", path]), "tools/phm.py", &file);
        let rs = parse(&photonkit(&["inspect", "--json", path]), "photonkit inspect --json", &file);
        if let Err(e) = compare(&py, &rs, "") {
            panic!("{}: {e}", file.display());
        }
    }
}

#[test]
fn phm_py_float_comparison_is_not_vacuous() {
    assert!(floats_agree(0.9f32 as f64, 0.9));
    assert!(!floats_agree(0.9, 0.9000001));
    let a: Value = serde_json::json!({"x": [1, 2.5], "s": "a"});
    assert!(compare(&a, &serde_json::json!({"x": [1, 2.5], "s": "a"}), "").is_ok());
    assert!(compare(&a, &serde_json::json!({"x": [1.0, 2.5], "s": "a"}), "").is_err());
    assert!(compare(&a, &serde_json::json!({"x": [1, 2.5], "s": "b"}), "").is_err());
    assert!(compare(&a, &serde_json::json!({"x": [1, 2.5]}), "").is_err());
}

/// Writes `bytes` to a file in `dir` and runs phm.py on it; returns (exit status ok, stderr).
fn run_on(dir: &Path, name: &str, bytes: &[u8], args: &[&str]) -> (bool, String) {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    let mut all = args.to_vec();
    all.push(p.to_str().unwrap());
    let o = phm_py(&all);
    let err = stderr(&o);
    if !o.status.success() {
        assert!(
            err.starts_with(&format!("phm.py: {}: ", p.display())) && err.trim_end().lines().count() == 1,
            "not a one-line `phm.py: FILE: problem` message: {err:?}"
        );
    }
    (o.status.success(), err)
}

#[test]
fn phm_py_rejects_truncated_and_newer_major_version() {
    if !have_python() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(sample_path("two-emitters.phm")).unwrap();
    assert!(run_on(dir.path(), "intact.phm", &bytes, &[]).0);

    // Truncated: the preamble's file_len no longer matches; and shorter than the preamble.
    let (ok, err) = run_on(dir.path(), "truncated.phm", &bytes[..bytes.len() - 100], &[]);
    assert!(!ok && err.contains("truncated"), "{err}");
    let (ok, err) = run_on(dir.path(), "stub.phm", &bytes[..20], &[]);
    assert!(!ok && err.contains("truncated"), "{err}");

    // Major version 2 (u16 at offset 8): refused, naming both versions.
    let mut v2 = bytes.clone();
    v2[8..10].copy_from_slice(&2u16.to_le_bytes());
    let (ok, err) = run_on(dir.path(), "v2.phm", &v2, &[]);
    assert!(!ok && err.contains("version 2.0 is not supported") && err.contains("major version 1"), "{err}");

    // A newer minor version is read (§8).
    let mut v1_7 = bytes.clone();
    v1_7[10..12].copy_from_slice(&7u16.to_le_bytes());
    assert!(run_on(dir.path(), "v1_7.phm", &v1_7, &[]).0);
}

#[test]
fn phm_py_check_verifies_column_crcs() {
    if !have_python() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // samples/minimal.phm's position column starts at byte 832 (format-spec §10).
    let mut bytes = std::fs::read(sample_path("minimal.phm")).unwrap();
    bytes[833] ^= 0x01;
    assert!(run_on(dir.path(), "flipped.phm", &bytes, &[]).0, "column CRCs are only checked with --check");
    let (ok, err) = run_on(dir.path(), "flipped.phm", &bytes, &["--check"]);
    assert!(!ok && err.contains("CRC-32"), "{err}");
}
