//! Command-line misuse of detect, relax and render (issue 31, items 4, 6, 7, 10, 13 and 17):
//! each is refused with a message that names the problem, or run with a note, never a hang,
//! an abort or a panic.

use std::path::Path;
use std::time::Instant;

use photonkit::format::PhotonMap;

use super::common::*;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn float_options_must_be_finite() {
    let dir = tempfile::tempdir().unwrap();
    let map = dir.path().join("u.phm");
    write_synthetic(&photonkit::synthetic::uniform_square(200, 1, 1.0), "uniform", &map);
    let out = dir.path().join("o.exr");
    for bad in ["nan", "inf", "-inf", "NaN"] {
        let o = photonkit(&[
            "render",
            s(&map),
            "--plane",
            "z=0",
            "-o",
            s(&out),
            "--width",
            "4",
            &format!("--exposure={bad}"),
        ]);
        assert!(!o.status.success() && stderr(&o).contains("finite"), "{bad}: {}", stderr(&o));
    }
    let o = photonkit(&["detect", s(&map), "-o", s(&dir.path().join("d.phm")), "--beta", "nan"]);
    assert!(!o.status.success() && stderr(&o).contains("finite"), "{}", stderr(&o));
    let o = photonkit(&["relax", s(&map), "-o", s(&dir.path().join("r.phm")), "--epsilon", "inf"]);
    assert!(!o.status.success() && stderr(&o).contains("finite"), "{}", stderr(&o));
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}

#[test]
fn huge_neighbour_counts_are_capped_at_the_photon_count() {
    let dir = tempfile::tempdir().unwrap();
    let map = dir.path().join("u.phm");
    write_synthetic(&photonkit::synthetic::uniform_square(300, 2, 1.0), "uniform", &map);
    let (det, rel) = (dir.path().join("d.phm"), dir.path().join("r.phm"));
    let t = Instant::now();
    let o = photonkit(&["detect", s(&map), "-o", s(&det), "--method", "world-pca", "--kc", "100000000"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("--kc 100000000 exceeds") && stderr(&o).contains("Kc = 300"),
        "{}",
        stderr(&o)
    );
    let o = photonkit(&["relax", s(&det), "-o", s(&rel), "--kf", "100000000", "-R", "2"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("Kf = 299"), "{}", stderr(&o));
    assert!(t.elapsed().as_secs() < 20, "{:?}", t.elapsed());
    assert!(PhotonMap::open_path(&rel).unwrap().positions().iter().flatten().all(|x| x.is_finite()));
}

#[test]
fn absurd_iteration_counts_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let map = dir.path().join("u.phm");
    write_synthetic(&photonkit::synthetic::uniform_square(50, 3, 1.0), "uniform", &map);
    let out = dir.path().join("r.phm");
    let o = photonkit(&["relax", s(&map), "-o", s(&out), "-R", "1000000000"]);
    assert!(!o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("1000000000 iterations") && stderr(&o).contains("at most"), "{}", stderr(&o));
    assert!(!stderr(&o).contains("panicked") && !stderr(&o).contains("memory allocation"));
    assert!(!out.exists());
}

#[test]
fn relax_handles_coordinates_near_1e30_and_names_the_file_of_a_nan() {
    let dir = tempfile::tempdir().unwrap();
    for scale in [1e30f32, 1e-30] {
        let mut m = photonkit::synthetic::uniform_square(400, 4, 1.0);
        m.position.iter_mut().flatten().for_each(|x| *x *= scale);
        let map = dir.path().join("big.phm");
        write_synthetic(&m, "uniform", &map);
        let out = dir.path().join("r.phm");
        let o = photonkit(&["relax", s(&map), "-o", s(&out), "-R", "3"]);
        assert!(o.status.success(), "{scale}: {}", stderr(&o));
        let relaxed = PhotonMap::open_path(&out).unwrap();
        let p = relaxed.positions();
        assert!(p.iter().flatten().all(|x| x.is_finite()), "{scale}");
        // The photons moved, by a fraction of their spacing (≈ scale / 20), and stayed in z = 0.
        let moved = p.iter().zip(&m.position).filter(|(a, b)| a != b).count();
        assert!(moved > 300, "{scale}: {moved} moved");
        assert!(p.iter().zip(&m.position).all(|(a, b)| (a[0] - b[0]).abs() < 0.2 * scale && a[2] == 0.0));
    }
    // A NaN position: the message names the file and the photon.
    let map = dir.path().join("nan.phm");
    write_synthetic(&photonkit::synthetic::uniform_square(100, 5, 1.0), "uniform", &map);
    let offset = PhotonMap::open_path(&map).unwrap().meta().column("position").unwrap().offset as usize;
    let mut bytes = std::fs::read(&map).unwrap();
    bytes[offset + 12 * 5..offset + 12 * 5 + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    std::fs::write(&map, with_fixed_checksums(&bytes)).unwrap();
    let out = dir.path().join("n2.phm");
    for args in [
        vec!["relax", s(&map), "-o", s(&out)],
        vec!["detect", s(&map), "-o", s(&out), "--method", "world-pca"],
    ] {
        let o = photonkit(&args);
        assert!(!o.status.success());
        assert!(
            stderr(&o).contains("nan.phm") && stderr(&o).contains("photon 5"),
            "{args:?}: {}",
            stderr(&o)
        );
    }
}

#[test]
fn every_exr_has_a_utf8_header_whatever_the_paths() {
    // Issue 31, items 10 and 13: "×" in the plane view's description was written as Latin-1,
    // and a path outside Latin-1 panicked in the EXR writer.
    let dir = tempfile::tempdir().unwrap();
    let map = dir.path().join("a→b 日本.phm");
    let o = photonkit(&["trace", "--photons", "3000", "-o", s(&map)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let views: [&[&str]; 3] = [
        &["--plane", "z=0", "--rect", "-1,-1,1,1"],
        &["--spp", "1"],
        &["--spp", "1", "--diagnostic", "splat"],
    ];
    for (i, view) in views.iter().enumerate() {
        let out = dir.path().join(format!("é→{i}.exr"));
        let mut args = vec!["render", s(&map), "-o", s(&out), "--width", "8"];
        args.extend_from_slice(view);
        let o = photonkit(&args);
        assert!(o.status.success(), "{view:?}: {}", stderr(&o));
        let (_, notes) = read_exr(&out);
        assert!(notes.iter().any(|(_, v)| v.contains("a→b 日本.phm")), "{view:?}: {notes:?}");
    }
    // `reference` with a scene file at such a path.
    let scene = dir.path().join("scène→.toml");
    std::fs::write(
        &scene,
        "[camera]\nprojection = \"orthographic\"\neye = [0, 0, 3]\nlook_at = [0, 0, 0]\nup = [0, 1, 0]\nheight = 0.6\n\
         [materials.floor]\nkind = \"diffuse\"\n[[emitters]]\nkind = \"collimated\"\ncenter = [0, 0, 2]\n\
         size = [1, 1]\ndirection = [0, 0, -1]\npower_w = 6\n[[shapes]]\nkind = \"plane\"\nnormal = [0, 0, 1]\n\
         material = \"floor\"\n",
    )
    .unwrap();
    let out = dir.path().join("réf→.exr");
    let o = photonkit(&[
        "reference",
        s(&scene),
        "-o",
        s(&out),
        "--passes",
        "1",
        "--photons-per-pass",
        "2000",
        "--radius",
        "0.05",
        "--mode",
        "irradiance",
        "--width",
        "6",
        "--height",
        "6",
        "--spp",
        "1",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    read_exr(&out);
}

/// Issue 29 item 5: `--quiet` leaves standard error empty on success (every stage of the
/// pipeline, whose notes and timings otherwise fill it) while errors still print; and
/// `completions SHELL` prints a script that names the subcommands.
#[test]
fn quiet_silences_notes_and_completions_name_the_subcommands() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let args =
        ["pipeline", "--photons", "20000", "--out-dir", s(&out), "--", "--width", "16", "--height", "16"];
    let loud = photonkit(&args);
    assert!(loud.status.success() && !stderr(&loud).is_empty(), "{}", stderr(&loud));
    let quiet = photonkit(&[&["--quiet"], &args[..]].concat());
    assert!(quiet.status.success(), "{}", stderr(&quiet));
    assert_eq!(stderr(&quiet), "", "--quiet printed to standard error");
    let failed = photonkit(&["-q", "inspect", s(&dir.path().join("missing.phm"))]);
    assert!(!failed.status.success() && stderr(&failed).contains("error"), "{}", stderr(&failed));
    for shell in ["bash", "zsh", "fish"] {
        let o = photonkit(&["completions", shell]);
        assert!(o.status.success(), "{}", stderr(&o));
        let script = stdout(&o);
        assert!(
            ["pipeline", "detect", "relax", "render", "spectral-scale"].iter().all(|w| script.contains(w)),
            "{shell}"
        );
    }
}

/// Issue 29 item 5: `--json` prints the history record each photon-map stage adds, one JSON
/// line on standard output (the same record the file holds); a map on standard output is
/// refused with it; `pipeline --json` prints one line per map it writes.
#[test]
fn json_prints_each_stages_history_record() {
    let dir = tempfile::tempdir().unwrap();
    let t = dir.path().join("t.phm");
    let o = photonkit(&["--json", "trace", "--photons", "5000", "-o", s(&t)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let line: serde_json::Value = serde_json::from_str(stdout(&o).trim()).unwrap();
    assert_eq!(line["stage"], "trace");
    let map = photonkit::format::PhotonMap::open_path(&t).unwrap();
    assert_eq!(line, serde_json::to_value(map.meta().history.last().unwrap()).unwrap());
    let o = photonkit(&["--json", "detect", s(&t), "-o", "-"]);
    assert!(!o.status.success() && stderr(&o).contains("--json"), "{}", stderr(&o));
    let out = dir.path().join("p");
    let o = photonkit(&[
        "--json",
        "-q",
        "pipeline",
        "--photons",
        "20000",
        "--out-dir",
        s(&out),
        "--",
        "--width",
        "8",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let stages: Vec<String> = stdout(&o)
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap()["stage"].as_str().unwrap().to_string())
        .collect();
    assert_eq!(stages, ["trace", "detect", "relax", "collapse", "relax"]);
}
