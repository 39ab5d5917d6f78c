//! `photonkit render` and `photonkit reference` from the command line.

use std::path::Path;

use photonkit::format::{PhotonMap, name};

use super::common::{photonkit, read_exr, stderr, with_fixed_checksums, write_synthetic};

fn files_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    v.sort();
    v
}

#[test]
fn renders_a_traced_map_to_exr_and_png() {
    let dir = tempfile::tempdir().unwrap();
    let map = dir.path().join("m.phm");
    let out = dir.path().join("img.exr");
    let o = photonkit(&["trace", "--photons", "20000", "-o", map.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = photonkit(&[
        "render",
        map.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--width",
        "24",
        "--height",
        "16",
        "--spp",
        "1",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("24×16"), "{}", stderr(&o));
    let (img, notes) = read_exr(&out);
    assert_eq!((img.width, img.height), (24, 16));
    assert!(img.pixels.iter().all(|p| p.is_finite() && p.min_element() >= 0.0));
    assert!(img.mean().x > 0.0);
    assert!(notes.iter().any(|(k, v)| k == "photonkit:units" && v.contains("W/(m^2 sr)")), "{notes:?}");
    assert!(notes.iter().any(|(k, v)| k == "photonkit:scene" && v.contains("default scene")), "{notes:?}");
    assert_eq!(files_in(dir.path()), ["img.exr", "img.png", "m.phm"]);

    // Diagnostics: the splat view works on any map; `constrained` needs `detect` first.
    let diag = dir.path().join("splat.exr");
    let o = photonkit(&[
        "render",
        map.to_str().unwrap(),
        "-o",
        diag.to_str().unwrap(),
        "--width",
        "16",
        "--spp",
        "1",
        "--diagnostic",
        "splat",
        "--no-png",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = photonkit(&["render", map.to_str().unwrap(), "-o", "c.exr", "--diagnostic", "constrained"]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("basis_v") && stderr(&o).contains("detect"), "{}", stderr(&o));
}

#[test]
fn plane_view_measures_the_irradiance_of_a_uniform_map() {
    // 3 W uniformly over the unit square of z = 0: E = 1 W/m² per channel.
    let dir = tempfile::tempdir().unwrap();
    let map = dir.path().join("u.phm");
    write_synthetic(&photonkit::synthetic::uniform_square(40_000, 3, 3.0), "uniform", &map);
    let out = dir.path().join("e.exr");
    // The plane view of the square's middle, 20 pixels wide, K = 50, and `extra` options.
    let render = |extra: &[&str]| {
        let mut argv = vec![
            "render",
            map.to_str().unwrap(),
            "--plane",
            "z=0",
            "--rect",
            "0.2,0.2,0.8,0.8",
            "-o",
            out.to_str().unwrap(),
            "--width",
            "20",
            "--spp",
            "4",
            "-k",
            "50",
        ];
        argv.extend_from_slice(extra);
        photonkit(&argv)
    };
    let o = render(&[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (img, notes) = read_exr(&out);
    assert_eq!((img.width, img.height), (20, 20));
    let m = img.mean();
    // Random photons, K = 50: each estimate has ≈ 14 % noise; the mean over 1600 lookups, ≈ 1 %.
    assert!((m.x - 1.0).abs() < 0.05 && (m.y - 1.0).abs() < 0.05, "{m}");
    assert!(notes.iter().any(|(k, v)| k == "photonkit:units" && v.starts_with("W/m^2")), "{notes:?}");
    // The variable kernel measures the same irradiance, and the header says which estimate.
    let o = render(&["--estimator", "variable"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (img, notes) = read_exr(&out);
    let m = img.mean();
    assert!((m.x - 1.0).abs() < 0.05 && (m.y - 1.0).abs() < 0.05, "{m}");
    assert!(
        notes.iter().any(|(k, v)| k == "photonkit:estimator" && v.starts_with("variable kernel")),
        "{notes:?}"
    );
    // A plane view is irradiance only.
    let o = photonkit(&["render", map.to_str().unwrap(), "--plane", "z=0", "--mode", "full", "-o", "x.exr"]);
    assert!(!o.status.success());
    // No photons near the plane.
    let o = photonkit(&["render", map.to_str().unwrap(), "--plane", "z=5", "-o", out.to_str().unwrap()]);
    assert!(!o.status.success() && stderr(&o).contains("no photon"), "{}", stderr(&o));
}

#[test]
fn bad_input_fails_cleanly_and_leaves_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.exr");
    let run = |map: &Path| {
        photonkit(&[
            "render",
            map.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--width",
            "8",
            "--spp",
            "1",
        ])
    };

    let o = run(&dir.path().join("missing.phm"));
    assert!(!o.status.success());
    assert!(stderr(&o).contains("missing.phm"), "{}", stderr(&o));

    let empty = dir.path().join("empty.phm");
    write_synthetic(&photonkit::synthetic::uniform_square(0, 1, 1.0), "empty", &empty);
    let o = run(&empty);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("no photons"), "{}", stderr(&o));

    // A NaN flux written into the column bytes (the writer itself refuses NaN).
    let nan = dir.path().join("nan.phm");
    write_synthetic(&photonkit::synthetic::uniform_square(100, 1, 1.0), "nan", &nan);
    let offset = PhotonMap::open_path(&nan).unwrap().meta().column(name::FLUX).unwrap().offset as usize;
    let mut bytes = std::fs::read(&nan).unwrap();
    bytes[offset + 12 * 7 + 4..offset + 12 * 7 + 8].copy_from_slice(&f32::NAN.to_le_bytes());
    std::fs::write(&nan, with_fixed_checksums(&bytes)).unwrap();
    let o = run(&nan);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("photon 7") && stderr(&o).contains("flux"), "{}", stderr(&o));
    assert!(!stderr(&o).contains("panicked"));

    let mut left = files_in(dir.path());
    left.retain(|f| !f.ends_with(".phm"));
    assert!(left.is_empty(), "{left:?}");
}

#[test]
fn reference_runs_saves_and_resumes() {
    // A 1 m × 1 m, 6 W collimated beam through an ideal slab: 2 W/m² per channel on the floor.
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("slab.toml");
    std::fs::write(
        &scene,
        "[camera]\nprojection = \"orthographic\"\neye = [0, 0, 3]\nlook_at = [0, 0, 0]\nup = [0, 1, 0]\nheight = 0.6\n\
         [materials.floor]\nkind = \"diffuse\"\n[materials.glass]\nkind = \"dielectric\"\nior = 1.5\nideal = true\n\
         [[emitters]]\nkind = \"collimated\"\ncenter = [0, 0, 2]\nsize = [1, 1]\ndirection = [0, 0, -1]\npower_w = 6\n\
         [[shapes]]\nkind = \"plane\"\nnormal = [0, 0, 1]\nmaterial = \"floor\"\n[[shapes]]\nkind = \"extrusion\"\n\
         outline = [[-2, -2], [2, -2], [2, 2], [-2, 2]]\nz_range = [0.5, 0.7]\nmaterial = \"glass\"\n",
    )
    .unwrap();
    let out = dir.path().join("ref.exr");
    let args = |passes: &str| {
        vec![
            "reference".to_string(),
            scene.to_str().unwrap().to_string(),
            "-o".into(),
            out.to_str().unwrap().to_string(),
            "--passes".into(),
            passes.into(),
            "--photons-per-pass".into(),
            "5000".into(),
            "--mode".into(),
            "irradiance".into(),
            "--width".into(),
            "12".into(),
            "--height".into(),
            "12".into(),
            "--spp".into(),
            "1".into(),
        ]
    };
    let run = |v: Vec<String>| photonkit(&v.iter().map(String::as_str).collect::<Vec<_>>());
    let o = run(args("3"));
    assert!(o.status.success(), "{}", stderr(&o));
    let (_, notes) = read_exr(&out);
    let state = |notes: &[(String, String)]| -> serde_json::Value {
        serde_json::from_str(&notes.iter().find(|(k, _)| k == "photonkit:reference_state").unwrap().1)
            .unwrap()
    };
    assert_eq!(state(&notes)["passes"], 3);
    let mut more = args("5");
    more.push("--resume".into());
    let o = run(more.clone());
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("passes 4..5"), "{}", stderr(&o));
    let (img, notes) = read_exr(&out);
    assert_eq!(state(&notes)["passes"], 5);
    assert!((img.mean().x - 2.0).abs() < 0.05, "{}", img.mean());
    // Resuming with other settings is refused and leaves the saved run alone.
    let mut other = more;
    other[15] = "2".into(); // --spp
    other[5] = "9".into(); // --passes
    let o = run(other);
    assert!(!o.status.success() && stderr(&o).contains("other settings"), "{}", stderr(&o));
    assert_eq!(read_exr(&out).0, img);

    // A radius that follows the photon density (--local-k): the same uniform 2 W/m²; a run
    // resumed after 3 passes (the first pass traced again for the radius) equals 5 straight.
    let local = |out: &std::path::Path, passes: &str, resume: bool| {
        let mut v = args(passes);
        v[3] = out.to_str().unwrap().to_string();
        v.extend(["--local-k".to_string(), "30".to_string()]);
        if resume {
            v.push("--resume".into());
        }
        run(v)
    };
    let (a, b) = (dir.path().join("a.exr"), dir.path().join("b.exr"));
    let o = local(&a, "5", false);
    assert!(o.status.success() && stderr(&o).contains("30-NN distance"), "{}", stderr(&o));
    assert!(local(&b, "3", false).status.success());
    let o = local(&b, "5", true);
    assert!(o.status.success() && stderr(&o).contains("passes 4..5"), "{}", stderr(&o));
    let (straight, resumed) = (read_exr(&a).0, read_exr(&b).0);
    assert!((straight.mean().x - 2.0).abs() < 0.05, "{}", straight.mean());
    assert_eq!(straight, resumed);
    let mut both = args("2");
    both.extend(["--local-k".to_string(), "30".to_string(), "--radius".to_string(), "0.1".to_string()]);
    assert!(!run(both).status.success(), "--local-k and --radius together are refused");
}

#[test]
fn the_scene_comes_from_the_maps_history() {
    // A map traced from a scene file is rendered with that file; without it, the user is told
    // to pass --scene.
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("spot.toml");
    std::fs::write(
        &scene,
        "[camera]\nprojection = \"pinhole\"\neye = [0, -3, 2]\nlook_at = [0, 0, 0]\n[materials.floor]\nkind = \"diffuse\"\n\
         [materials.metal]\nkind = \"mirror\"\n[[emitters]]\nkind = \"point\"\nposition = [0, 0, 1]\npower_w = 5\n\
         [[shapes]]\nkind = \"plane\"\nnormal = [0, 0, 1]\nmaterial = \"floor\"\n[[shapes]]\nkind = \"sphere\"\n\
         center = [0, 0, 2]\nradius = 0.5\nmaterial = \"metal\"\n",
    )
    .unwrap();
    let map = dir.path().join("m.phm");
    let out = dir.path().join("m.exr");
    let o = photonkit(&["trace", scene.to_str().unwrap(), "--photons", "20000", "-o", map.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let render = || {
        photonkit(&[
            "render",
            map.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--width",
            "8",
            "--spp",
            "1",
        ])
    };
    let o = render();
    assert!(o.status.success(), "{}", stderr(&o));
    let (img, notes) = read_exr(&out);
    assert!(notes.iter().any(|(k, v)| k == "photonkit:scene" && v.ends_with("spot.toml")), "{notes:?}");
    assert_eq!((img.width, img.height), (8, 8)); // the scene's camera is 600×600: the aspect is kept
    std::fs::remove_file(&scene).unwrap();
    std::fs::remove_file(&out).unwrap();
    let o = render();
    assert!(!o.status.success() && stderr(&o).contains("--scene"), "{}", stderr(&o));
    assert!(!out.exists());
}

/// Paths and notes outside Latin-1 (issue 31: a panic) or outside ASCII ("×" was written as
/// the single byte 0xD7, which OpenEXR's own readers refuse) are written as UTF-8.
#[test]
fn exr_header_text_is_utf8_for_any_path() {
    let dir = tempfile::tempdir().unwrap().keep();
    let sub = dir.join("caustiques→été");
    std::fs::create_dir(&sub).unwrap();
    let map = sub.join("a→b.phm");
    std::fs::copy(super::common::sample_path("collimated-cusp.phm"), &map).unwrap();
    let exr = sub.join("ø→x.exr");
    let o = photonkit(&[
        "render",
        map.to_str().unwrap(),
        "--plane",
        "z=0",
        "--rect",
        "-1,-1,1,1",
        "--width",
        "8",
        "--height",
        "8",
        "-o",
        exr.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    // (super::common::exr_header parses the header bytes independently of the exr crate.)
    let strings: Vec<(String, Vec<u8>)> = super::common::exr_header(&exr)
        .into_iter()
        .filter(|(_, kind, _)| kind == "string")
        .map(|(name, _, value)| (name, value))
        .collect();
    assert!(!strings.is_empty());
    for (name, value) in &strings {
        assert!(std::str::from_utf8(value).is_ok(), "attribute {name} is not UTF-8");
    }
    let all: String = strings.iter().map(|(_, v)| String::from_utf8_lossy(v).into_owned()).collect();
    assert!(all.contains("a→b.phm"), "the map's name survives: {all}");
    // And our own reader reads the text back as written.
    let (_, notes) = photonkit::render::image::read_exr(&exr).unwrap();
    assert!(notes.iter().any(|(_, v)| v.contains("a→b.phm")), "{notes:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A map traced from a scene named by a relative path still finds its scene when rendered
/// from another folder (issue 29): the trace records where the scene lies relative to the
/// map's folder.
#[test]
fn render_finds_the_scene_of_a_map_from_another_folder() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = tempfile::tempdir().unwrap();
    let map = dir.path().join("maps").join("ring.phm");
    std::fs::create_dir_all(map.parent().unwrap()).unwrap();
    let run = |cwd: &std::path::Path, args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_photonkit"))
            .current_dir(cwd)
            .args(args)
            .output()
            .unwrap()
    };
    let o =
        run(root, &["trace", "samples/scenes/ring.toml", "--photons", "20000", "-o", map.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let m = photonkit::format::PhotonMap::open_path(&map).unwrap();
    let rec = m.meta().history.iter().find(|r| r.stage == "trace").unwrap();
    let rel = rec.report["scene_from_map"].as_str().unwrap();
    assert!(rel.ends_with("samples/scenes/ring.toml") && !std::path::Path::new(rel).is_absolute(), "{rel}");
    let o = run(
        dir.path(),
        &["render", "maps/ring.phm", "-o", "ring.exr", "--width", "16", "--height", "16", "--spp", "1"],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stderr(&o).contains("not found"), "{}", stderr(&o));
}
