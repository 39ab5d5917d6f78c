//! The user's files survive every command: an output that is an input is refused, an
//! interrupted write leaves nothing behind, and an input truncated underneath is named.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};

use super::common::{photonkit, sample_path, stderr};

fn copy_sample(dir: &Path, name: &str) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::copy(sample_path("collimated-cusp.phm"), &p).unwrap();
    p
}

fn temp_files(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".tmp"))
        .collect()
}

/// Every command that reads a file and writes one refuses to write over its input, under any
/// name of the same file (`./x`, a symlink), and leaves the input byte for byte as it was.
#[test]
fn every_command_refuses_to_overwrite_its_input() {
    let dir = tempfile::tempdir().unwrap();
    let x = copy_sample(dir.path(), "x.phm");
    let original = std::fs::read(&x).unwrap();
    let link = dir.path().join("link.phm");
    std::os::unix::fs::symlink(&x, &link).unwrap();
    let xs = x.to_str().unwrap();
    let dotted = format!("{}/./x.phm", dir.path().display());
    let ls = link.to_str().unwrap();
    let csv = dir.path().join("l.csv");
    std::fs::write(&csv, "x,y,z,flux_r,flux_g,flux_b\n0,0,0,1,1,1\n1,0,0,1,1,1\n").unwrap();
    let csv_before = std::fs::read(&csv).unwrap();
    let cs = csv.to_str().unwrap();
    let cases: Vec<Vec<&str>> = vec![
        vec!["inspect", xs, "--sample", "10", "-o", &dotted],
        vec![
            "render",
            xs,
            "--plane",
            "z=0",
            "--rect",
            "-1,-1,1,1",
            "--width",
            "8",
            "--height",
            "8",
            "-o",
            ls,
        ],
        vec!["import", cs, "-o", cs],
        vec!["detect", xs, "-o", xs],
        vec!["relax", ls, "-o", xs],
        vec!["collapse", xs, "-o", ls],
        vec!["export", xs, "--to", "csv", "-o", xs],
        vec!["merge", xs, "-o", &dotted],
    ];
    for args in cases {
        let o = photonkit(&args);
        assert!(!o.status.success(), "{args:?} succeeded");
        assert!(stderr(&o).contains("refusing to overwrite"), "{args:?}: {}", stderr(&o));
        assert_eq!(std::fs::read(&x).unwrap(), original, "{args:?} changed the input");
        assert_eq!(std::fs::read(&csv).unwrap(), csv_before, "{args:?} changed the CSV");
        assert!(temp_files(dir.path()).is_empty(), "{args:?} left a temporary file");
    }
}

/// Runs `args` with a test pause of `ms` at `pause`, waits for the pause to begin, then calls `act`.
fn during_pause(args: &[&str], pause: &str, ms: u32, act: impl FnOnce(u32)) -> std::process::Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_photonkit"))
        .args(args)
        .env(format!("PHOTONKIT_TEST_PAUSE_{pause}"), ms.to_string())
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    let mut err = BufReader::new(child.stderr.take().unwrap());
    let mut seen = String::new();
    loop {
        let mut line = String::new();
        if err.read_line(&mut line).unwrap() == 0 {
            panic!("{args:?} ended before its pause: {seen}");
        }
        seen.push_str(&line);
        if line.contains("test pause") {
            break;
        }
    }
    act(child.id());
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut err, &mut rest).unwrap();
    let status = child.wait().unwrap();
    std::process::Output { status, stdout: Vec::new(), stderr: (seen + &rest).into_bytes() }
}

/// SIGINT, SIGTERM and SIGHUP during the write remove the finished-but-unrenamed temporary
/// file and leave no output; the exit status is 128 + the signal.
#[test]
fn an_interrupted_write_leaves_no_temporary_file() {
    use std::os::unix::process::ExitStatusExt;
    for (sig, name) in [(libc::SIGINT, "INT"), (libc::SIGTERM, "TERM"), (libc::SIGHUP, "HUP")] {
        let dir = tempfile::tempdir().unwrap();
        let x = copy_sample(dir.path(), "x.phm");
        let out = dir.path().join("out.phm");
        let o = during_pause(
            &["inspect", x.to_str().unwrap(), "--sample", "100", "-o", out.to_str().unwrap()],
            "BEFORE_RENAME",
            20_000,
            |pid| {
                assert_eq!(temp_files(dir.path()).len(), 1, "the write is pending");
                // SAFETY: sending a signal to our own child.
                unsafe { libc::kill(pid as i32, sig) };
            },
        );
        assert_eq!(o.status.code(), Some(128 + sig), "SIG{name}: {:?} {}", o.status.signal(), stderr(&o));
        assert!(temp_files(dir.path()).is_empty(), "SIG{name} left {:?}", temp_files(dir.path()));
        assert!(!out.exists(), "SIG{name} left an output");
        assert!(stderr(&o).contains("removed 1 unfinished output file"), "{}", stderr(&o));
    }
}

/// An input truncated by another process while it is mapped is named in the error, instead
/// of a bare SIGBUS.
#[test]
fn an_input_truncated_underneath_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let x = copy_sample(dir.path(), "x.phm");
    for args in [vec!["inspect", "--dump"], vec!["detect"]] {
        let mut full = args.clone();
        full.push(x.to_str().unwrap());
        let out = dir.path().join("d.phm");
        if args[0] == "detect" {
            full.extend(["-o", out.to_str().unwrap()]);
        }
        // The pause only has to outlast one truncation.
        let o = during_pause(&full, "AFTER_MAP", 2_000, |_| {
            std::fs::OpenOptions::new().write(true).open(&x).unwrap().set_len(0).unwrap();
        });
        assert_eq!(o.status.code(), Some(74), "{args:?}: {}", stderr(&o));
        assert!(stderr(&o).contains("changed underneath") && stderr(&o).contains("x.phm"), "{}", stderr(&o));
        assert!(!out.exists());
        std::fs::copy(sample_path("collimated-cusp.phm"), &x).unwrap();
    }
}

/// NaN and infinite option values are refused by the argument parser (issue 31: `--exposure
/// nan` rendered a black PNG with exit 0).
#[test]
fn non_finite_option_values_are_refused() {
    let map = sample_path("collimated-cusp.phm");
    let m = map.to_str().unwrap();
    for args in [
        vec!["render", m, "--exposure", "nan", "-o", "/nonexistent/x.exr"],
        vec!["detect", m, "--beta", "inf", "-o", "/nonexistent/x.phm"],
        vec!["relax", m, "--step-limit=-inf", "-o", "/nonexistent/x.phm"],
    ] {
        let o = photonkit(&args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        assert!(stderr(&o).contains("not a finite number"), "{args:?}: {}", stderr(&o));
    }
}

/// A map whose column fails its CRC-32 is refused by every stage (issue 31: a stage used to
/// write it out again with fresh checksums that pass `--check`), and `inspect --check` names it.
#[test]
fn a_corrupt_column_is_refused_not_laundered() {
    let dir = tempfile::tempdir().unwrap();
    let x = copy_sample(dir.path(), "x.phm");
    let map = photonkit::format::PhotonMap::open_path(&x).unwrap();
    let flux = map.meta().columns.iter().find(|c| c.name == "flux").unwrap().offset as usize;
    drop(map);
    let mut bytes = std::fs::read(&x).unwrap();
    bytes[flux + 5] ^= 0x40;
    std::fs::write(&x, &bytes).unwrap();
    let xs = x.to_str().unwrap();
    let out = dir.path().join("out.phm");
    let os = out.to_str().unwrap();
    for args in [
        vec!["detect", xs, "-o", os],
        vec!["relax", xs, "-o", os],
        vec!["collapse", xs, "-o", os],
        vec!["inspect", xs, "--sample", "5", "-o", os],
        vec!["export", xs, "--to", "csv", "-o", os],
        vec![
            "render",
            xs,
            "--plane",
            "z=0",
            "--rect",
            "-1,-1,1,1",
            "--width",
            "4",
            "--height",
            "4",
            "-o",
            os,
        ],
    ] {
        let o = photonkit(&args);
        assert!(!o.status.success(), "{args:?} accepted a corrupt map");
        assert!(stderr(&o).contains("fails its checksum"), "{args:?}: {}", stderr(&o));
        assert!(!out.exists() && temp_files(dir.path()).is_empty(), "{args:?} wrote something");
    }
    let o = photonkit(&["inspect", "--check", xs]);
    assert!(!o.status.success());
    assert!(super::common::stdout(&o).contains("flux") || stderr(&o).contains("flux"));
}

/// The writer refuses what the reader would refuse (issue 31: `relax -R 110000` wrote 26.7 MB
/// of history, over the reader's 16 MiB metadata limit, with exit 0), and relax keeps at most
/// 1000 per-iteration records, the last iteration among them.
#[test]
fn the_writer_enforces_the_readers_limits() {
    use photonkit::format::{MapInfo, write_map};
    let dir = tempfile::tempdir().unwrap();
    let m = photonkit::synthetic::uniform_square(3, 1, 1.0);
    let mut info: MapInfo = m.info("test", 0, "2026-12-04T00:00:00Z");
    info.extra.insert("huge".into(), serde_json::Value::String("x".repeat(17 << 20)));
    let p = dir.path().join("big.phm");
    let e = write_map(photonkit::format::Output::Path(p.clone()), info, &m.columns()).unwrap_err();
    assert!(e.to_string().contains("exceeds the limit"), "{e}");
    assert!(!p.exists() && temp_files(dir.path()).is_empty());

    let small = dir.path().join("s.phm");
    super::common::write_synthetic(&m, "test", &small);
    let out = dir.path().join("r.phm");
    let o = photonkit(&["relax", small.to_str().unwrap(), "-R", "2500", "-o", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let map = photonkit::format::PhotonMap::open_path(&out).unwrap();
    let rec = map.meta().history.iter().rev().find(|r| r.stage == "relax").unwrap();
    let its = rec.report["iterations"].as_array().unwrap();
    assert!(its.len() <= 1000 && its.len() >= 800, "{} records", its.len());
    let last = its.last().unwrap()["iteration"].as_u64().unwrap();
    assert!(last >= 2499, "the last iteration is kept (last record: {last})");
}

/// With `SOURCE_DATE_EPOCH` set, every stage writes the same bytes on every run (issue 31:
/// detect, relax and collapse stamped the wall-clock time and their run time).
#[test]
fn every_stage_is_byte_reproducible_under_source_date_epoch() {
    let dir = tempfile::tempdir().unwrap();
    let x = copy_sample(dir.path(), "x.phm");
    let run = |args: &[&str]| {
        let o = Command::new(env!("CARGO_BIN_EXE_photonkit"))
            .args(args)
            .env("SOURCE_DATE_EPOCH", "1700000000")
            .output()
            .unwrap();
        assert!(o.status.success(), "{args:?}: {}", String::from_utf8_lossy(&o.stderr));
    };
    let p = |n: &str| dir.path().join(n).to_str().unwrap().to_string();
    for round in ["a", "b"] {
        run(&["detect", x.to_str().unwrap(), "-o", &p(&format!("d{round}.phm"))]);
        run(&["relax", &p(&format!("d{round}.phm")), "-R", "5", "-o", &p(&format!("r{round}.phm"))]);
        run(&["collapse", &p(&format!("r{round}.phm")), "-o", &p(&format!("c{round}.phm"))]);
    }
    for stage in ["d", "r", "c"] {
        let (a, b) = (
            std::fs::read(p(&format!("{stage}a.phm"))).unwrap(),
            std::fs::read(p(&format!("{stage}b.phm"))).unwrap(),
        );
        assert!(a == b, "{stage}: two runs differ");
        assert!(String::from_utf8_lossy(&a).contains("2023-11-14T22:13:20Z"), "{stage}: the record's time");
    }
}
