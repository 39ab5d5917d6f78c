//! `photonkit detect --tile i/n`, `photonkit relax --tile i/n` and `photonkit merge --map`: the
//! parts of every tiling merge into the file `photonkit detect` (or `relax`) writes, byte for
//! byte; the local runner runs the same commands; bad tiles and bad parts are refused without
//! output (docs/tiles.md).

use std::path::Path;
use std::process::Command;

use photonkit::format::PhotonMap;

use super::common::*;

/// Runs photonkit with SOURCE_DATE_EPOCH set (reproducible records), asserting success.
fn run(args: &[&str]) {
    let o = Command::new(env!("CARGO_BIN_EXE_photonkit"))
        .arg("--quiet")
        .args(args)
        .env("SOURCE_DATE_EPOCH", "1700000000")
        .output()
        .unwrap();
    assert!(o.status.success(), "{args:?}: {}", stderr(&o));
}

/// The parts of `map` in `n` tiles, written into `dir`, with `extra` detect options.
fn parts(map: &str, n: usize, dir: &Path, extra: &[&str]) -> Vec<String> {
    stage_parts("detect", map, n, dir, extra)
}

/// The parts of `map` in `n` tiles of `stage`, written into `dir`, with `extra` options.
fn stage_parts(stage: &str, map: &str, n: usize, dir: &Path, extra: &[&str]) -> Vec<String> {
    (0..n)
        .map(|i| {
            let part = dir.join(format!("part-{i}-of-{n}.phm")).display().to_string();
            let tile = format!("{i}/{n}");
            let mut args = vec![stage, map, "--tile", &tile, "-o", &part];
            args.extend(extra);
            run(&args);
            part
        })
        .collect()
}

/// A uniform square and a wall: more than half the photons on the line x = 0 (a strip of
/// parameters folded onto it), so that the first column's cut is the box's low side and the
/// first column's tiles are empty; every other cut goes through a photon.
fn walled(dir: &Path) -> String {
    let full = photonkit::synthetic::uniform_square(3000, 5, 1.0);
    let mut m = photonkit::synthetic::SyntheticMap { emitters: full.emitters.clone(), ..Default::default() };
    let mut keep = |k: usize, x: [f32; 3], q: [f32; 2]| {
        m.position.push(x);
        m.params.extend_from_slice(&q);
        m.normal.push(full.normal[k]);
        m.flux.push(full.flux[k]);
        m.incident.push(full.incident[k]);
        m.emitter.push(0);
        m.path_length.push(full.path_length[k]);
        m.bounces.push(full.bounces[k]);
        m.emission_index.push(full.emission_index[k]);
    };
    for k in 0..full.len() {
        let x = full.position[k];
        keep(k, x, [x[0], x[1]]);
    }
    for k in 0..3200 {
        let x = full.position[k % full.len()];
        keep(k % full.len(), [0.0, x[1], x[2]], [-0.05 * x[0], x[1]]);
    }
    m.param_dims = 2;
    let path = dir.join("walled.phm");
    write_synthetic(&m, "walled", &path);
    path.display().to_string()
}

#[test]
fn merged_tile_parts_equal_the_untiled_detection_byte_for_byte() {
    let dir = tempfile::tempdir().unwrap();
    let walled = walled(dir.path());
    let maps = [
        sample_path("two-emitters.phm").display().to_string(),
        sample_path("point-ring.phm").display().to_string(),
        walled.clone(),
    ];
    for map in &maps {
        for (n, extra) in [(2, &[][..]), (4, &[][..]), (9, &["--kc", "20", "--growths", "0"][..])] {
            let whole = dir.path().join("whole.phm").display().to_string();
            let mut args = vec!["detect", map.as_str(), "-o", &whole];
            args.extend(extra);
            run(&args);
            let parts = parts(map, n, dir.path(), extra);
            let merged = dir.path().join("merged.phm").display().to_string();
            // Parts in any order.
            let mut args = vec!["merge", "--map", map.as_str(), "-o", &merged];
            args.extend(parts.iter().rev().map(String::as_str));
            run(&args);
            let (a, b) = (std::fs::read(&whole).unwrap(), std::fs::read(&merged).unwrap());
            assert!(a == b, "{map}, {n} tiles {extra:?}: the merged parts differ from the untiled run");
            if *map == walled {
                // The first column (tiles 0, nx, 2·nx, …) is empty, the others are not.
                let nx = if n == 9 { 3 } else { 2 };
                for (t, part) in parts.iter().enumerate() {
                    let len = PhotonMap::open(part).unwrap().len();
                    assert_eq!(len == 0, t % nx == 0, "{n} tiles: tile {t} holds {len}");
                }
            }
        }
    }
}

#[test]
fn merged_relax_tile_parts_equal_the_untiled_relax_byte_for_byte_in_both_phases() {
    let dir = tempfile::tempdir().unwrap();
    let walled = walled(dir.path());
    let maps = [
        sample_path("two-emitters.phm").display().to_string(),
        sample_path("point-ring.phm").display().to_string(),
        walled,
    ];
    for (k, map) in maps.iter().enumerate() {
        let detected = dir.path().join(format!("detected-{k}.phm")).display().to_string();
        let collapsed = dir.path().join(format!("collapsed-{k}.phm")).display().to_string();
        run(&["detect", map, "-o", &detected]);
        run(&["collapse", &detected, "-o", &collapsed]);
        for phase in [&detected, &collapsed] {
            for (n, extra) in [(2, &[][..]), (4, &["--iterations", "4"][..]), (9, &["--kf", "10"][..])] {
                let whole = dir.path().join("whole.phm").display().to_string();
                let mut args = vec!["relax", phase.as_str(), "-o", &whole];
                args.extend(extra);
                run(&args);
                let parts = stage_parts("relax", phase, n, dir.path(), extra);
                let merged = dir.path().join("merged.phm").display().to_string();
                let mut args = vec!["merge", "--map", phase.as_str(), "-o", &merged];
                args.extend(parts.iter().rev().map(String::as_str));
                run(&args);
                let (a, b) = (std::fs::read(&whole).unwrap(), std::fs::read(&merged).unwrap());
                assert!(
                    a == b,
                    "{phase}, {n} tiles {extra:?}: the merged relax parts differ from the untiled run"
                );
            }
        }
    }
}

#[test]
fn the_local_runner_runs_the_tiles_in_parallel_and_merges_them() {
    let dir = tempfile::tempdir().unwrap();
    let map = sample_path("collimated-cusp.phm").display().to_string();
    let whole = dir.path().join("whole.phm").display().to_string();
    run(&["detect", &map, "--method", "world-pca", "-o", &whole]);
    let out = dir.path().join("tiled.phm").display().to_string();
    let o = Command::new("bash")
        .arg(root().join("tools/cluster/run-local.sh"))
        .args([&map, &out, "4", "2", "--", "--method", "world-pca"])
        .env("PHOTONKIT", env!("CARGO_BIN_EXE_photonkit"))
        .env("SOURCE_DATE_EPOCH", "1700000000")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        std::fs::read(&whole).unwrap() == std::fs::read(&out).unwrap(),
        "run-local.sh differs from detect"
    );
    // Its parts are gone; a bad tile count is refused.
    let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left.len(), 2, "{left:?}");
    // The same for relax, on the detected map.
    let relaxed = dir.path().join("relaxed.phm").display().to_string();
    run(&["relax", &whole, "-o", &relaxed]);
    let o = Command::new("bash")
        .arg(root().join("tools/cluster/run-local.sh"))
        .args([&whole, &out, "4", "2"])
        .env("PHOTONKIT", env!("CARGO_BIN_EXE_photonkit"))
        .env("SOURCE_DATE_EPOCH", "1700000000")
        .env("STAGE", "relax")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        std::fs::read(&relaxed).unwrap() == std::fs::read(&out).unwrap(),
        "run-local.sh differs from relax"
    );
    // And render: the image from the tile jobs' parts is the image.
    let image = ["--width", "32", "--height", "24", "--spp", "1"];
    let (whole_exr, tiled_exr) = (dir.path().join("whole.exr"), dir.path().join("tiled.exr"));
    let mut args = vec!["render", relaxed.as_str(), "-o", whole_exr.to_str().unwrap()];
    args.extend(image);
    run(&args);
    let o = Command::new("bash")
        .arg(root().join("tools/cluster/run-local.sh"))
        .args([&relaxed, tiled_exr.to_str().unwrap(), "4", "2", "--"])
        .args(image)
        .env("PHOTONKIT", env!("CARGO_BIN_EXE_photonkit"))
        .env("STAGE", "render")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        std::fs::read(&whole_exr).unwrap() == std::fs::read(&tiled_exr).unwrap(),
        "run-local.sh differs from render"
    );
    let o = Command::new("bash")
        .arg(root().join("tools/cluster/run-local.sh"))
        .args([&map, &out, "0"])
        .env("PHOTONKIT", env!("CARGO_BIN_EXE_photonkit"))
        .output()
        .unwrap();
    assert!(!o.status.success() && stderr(&o).contains("TILES"), "{}", stderr(&o));
}

#[test]
fn bad_tiles_and_bad_parts_are_refused_without_output() {
    let dir = tempfile::tempdir().unwrap();
    let map = sample_path("two-emitters.phm").display().to_string();
    let out = dir.path().join("out.phm");
    let outs = out.display().to_string();
    for (tile, why) in [("3/2", "numbered 0 to 1"), ("0/0", "at least 1"), ("1", "i/n"), ("x/2", "index")] {
        let o = photonkit(&["detect", &map, "--tile", tile, "-o", &outs]);
        assert!(!o.status.success() && stderr(&o).contains(why), "{tile}: {}", stderr(&o));
        assert!(!out.exists(), "{tile}");
    }
    // A part written over its map is refused.
    let copy = dir.path().join("copy.phm");
    std::fs::copy(&map, &copy).unwrap();
    let copy = copy.display().to_string();
    let o = photonkit(&["detect", &copy, "--tile", "0/2", "-o", &copy]);
    assert!(!o.status.success(), "{}", stderr(&o));
    assert_eq!(std::fs::read(&copy).unwrap(), std::fs::read(&map).unwrap());

    let parts_in = |sub: &str, map: &str, n: usize, extra: &[&str]| {
        let d = dir.path().join(sub);
        std::fs::create_dir(&d).unwrap();
        parts(map, n, &d, extra)
    };
    let p2 = parts_in("two", &map, 2, &[]);
    let other = parts_in("other", &sample_path("point-ring.phm").display().to_string(), 2, &[]);
    let kc = parts_in("kc", &map, 2, &["--kc", "20"]);
    let p3 = parts_in("three", &map, 3, &[]);
    let merge = |list: &[&str]| {
        let mut args = vec!["merge", "--map", map.as_str(), "-o", outs.as_str()];
        args.extend(list);
        photonkit(&args)
    };
    for (list, why) in [
        (vec![p2[0].as_str()], "tile 1/2 is missing"),
        (vec![p2[0].as_str(), p2[0].as_str()], "also in"),
        (vec![p2[0].as_str(), other[1].as_str()], "another map"),
        (vec![p2[0].as_str(), kc[1].as_str()], "other parameters"),
        (vec![p2[0].as_str(), p3[1].as_str()], "other parameters or tile count"),
        (vec![map.as_str(), p2[1].as_str()], "not a tile part"),
    ] {
        let o = merge(&list);
        assert!(!o.status.success() && stderr(&o).contains(why), "{list:?}: {}", stderr(&o));
        assert!(!out.exists(), "{list:?}");
    }
    // The merge never writes over its map or a part.
    let o = photonkit(&["merge", "--map", &copy, &p2[0], &p2[1], "-o", &copy]);
    assert!(!o.status.success());
    let o = photonkit(&["merge", "--map", &map, &p2[0], &p2[1], "-o", &p2[1]]);
    assert!(!o.status.success());
    assert!(merge(&[&p2[1], &p2[0]]).status.success());
}

/// `detect --memory` and `relax --memory` with a budget the whole map exceeds run tile by tile
/// in one process and write the untiled file byte for byte; a budget below what the map alone
/// needs is refused without output.
/// What a `photonkit STAGE` process holds before its own work on `map`, as its refusal of a
/// budget of one kilobyte states it ("… and the 7.20 MiB the process holds already").
fn held_bytes(stage: &str, map: &str) -> u64 {
    let o = photonkit(&[stage, map, "--memory", "1K", "-o", "-"]);
    let e = stderr(&o);
    let before = e.split(" the process holds already").next().unwrap();
    let mut words = before.rsplit(' ');
    let (unit, value) = (words.next().unwrap(), words.next().unwrap());
    let scale = match unit {
        "B" => 1.0,
        "KiB" => 1024.0,
        "MiB" => 1024.0 * 1024.0,
        "GiB" => 1024.0 * 1024.0 * 1024.0,
        _ => panic!("no size in {e}"),
    };
    (value.parse::<f64>().unwrap() * scale) as u64
}

#[test]
fn a_memory_budget_runs_tile_by_tile_with_the_untiled_result() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).display().to_string();
    let (traced, walled) = (path("traced.phm"), walled(dir.path()));
    run(&["trace", "--photons", "20000", "-o", &traced]);
    for map in [&traced, &walled] {
        let (whole, budgeted) = (path("whole.phm"), path("budgeted.phm"));
        run(&["detect", map, "-o", &whole]);
        // Room for what the process holds already and a few tiles, not for the whole map.
        let budget = (held_bytes("detect", map) + 2_300_000).to_string();
        let o = Command::new(env!("CARGO_BIN_EXE_photonkit"))
            .args(["detect", map, "--memory", &budget, "-o", &budgeted])
            .env("SOURCE_DATE_EPOCH", "1700000000")
            .output()
            .unwrap();
        assert!(o.status.success() && stderr(&o).contains(" tiles ("), "{map}: {}", stderr(&o));
        assert!(std::fs::read(&whole).unwrap() == std::fs::read(&budgeted).unwrap(), "{map}: detect");
        let detected = path("detected.phm");
        std::fs::rename(&whole, &detected).unwrap();
        for extra in [&[][..], &["--iterations", "3", "--kf", "10"][..]] {
            let mut args = vec!["relax", detected.as_str(), "-o", &whole];
            args.extend(extra);
            run(&args);
            let budget = (held_bytes("relax", &detected) + 2_300_000).to_string();
            let mut args = vec!["relax", detected.as_str(), "--memory", &budget, "-o", &budgeted];
            args.extend(extra);
            let o = Command::new(env!("CARGO_BIN_EXE_photonkit"))
                .args(&args)
                .env("SOURCE_DATE_EPOCH", "1700000000")
                .output()
                .unwrap();
            assert!(o.status.success() && stderr(&o).contains(" tiles ("), "{map}: {}", stderr(&o));
            assert!(
                std::fs::read(&whole).unwrap() == std::fs::read(&budgeted).unwrap(),
                "{map} {extra:?}: relax"
            );
            // The default scene's sparse surround: a tile's moves reach the whole map, beyond
            // what the tiling allowed for, and the user is told the budget may not hold.
            if map == &traced {
                assert!(stderr(&o).contains("so the peak may exceed --memory"), "{}", stderr(&o));
            }
        }
        let refused = path("refused.phm");
        for stage in ["detect", "relax"] {
            let input = if stage == "detect" { map.as_str() } else { detected.as_str() };
            let o = photonkit(&[stage, input, "--memory", "20K", "-o", &refused]);
            assert!(!o.status.success() && stderr(&o).contains("--memory"), "{stage}: {}", stderr(&o));
            assert!(!Path::new(&refused).exists(), "{stage}");
        }
    }
}

#[test]
fn render_under_a_memory_budget_streams_the_map_into_the_same_image() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).display().to_string();
    let map = path("traced.phm");
    run(&["trace", "--photons", "1000000", "-o", &map]);
    let image = ["--width", "48", "--height", "32", "--spp", "2"];
    let (whole, budgeted) = (path("whole.exr"), path("budgeted.exr"));
    let mut args = vec!["render", map.as_str(), "-o", &whole];
    args.extend(image);
    run(&args);
    // Room for the program (10–20 MB) and a few tiles of the map's 700 000 photons (60 MB
    // whole), not for all of them.
    let budget = "40M";
    let mut args = vec!["render", map.as_str(), "-o", &budgeted, "--memory", budget];
    args.extend(image);
    let o = photonkit(&args);
    assert!(o.status.success() && stderr(&o).contains("streamed the map in"), "{}", stderr(&o));
    assert!(std::fs::read(&whole).unwrap() == std::fs::read(&budgeted).unwrap(), "EXR");
    assert!(std::fs::read(path("whole.png")).unwrap() == std::fs::read(path("budgeted.png")).unwrap(), "PNG");
    // Tiles as jobs of their own: every part, in any order, makes the same image.
    let parts: Vec<String> = (0..4).map(|i| path(&format!("part-{i}.phm"))).collect();
    for (i, part) in parts.iter().enumerate() {
        let tile = format!("{i}/4");
        let mut args = vec!["render", map.as_str(), "--tile", &tile, "-o", part];
        args.extend(image);
        run(&args);
    }
    let from_parts = path("parts.exr");
    let mut args = vec![
        "render",
        map.as_str(),
        "-o",
        &from_parts,
        "--parts",
        &parts[2],
        &parts[0],
        &parts[3],
        &parts[1],
    ];
    args.extend(image);
    run(&args);
    assert!(std::fs::read(&whole).unwrap() == std::fs::read(&from_parts).unwrap(), "EXR from parts");
    assert!(
        std::fs::read(path("whole.png")).unwrap() == std::fs::read(path("parts.png")).unwrap(),
        "PNG from parts"
    );
    let refused = path("refused.exr");
    let missing = ["--parts", &parts[0], &parts[1], &parts[2]];
    let twice = ["--parts", &parts[0], &parts[1], &parts[2], &parts[2]];
    let other = ["--parts", &parts[0], &parts[1], &parts[2], &parts[3]];
    for (extra, says) in
        [(&missing[..], "missing"), (&twice[..], "twice"), (&other[..], "other render options")]
    {
        let mut args = vec!["render", map.as_str(), "-o", &refused];
        args.extend(if says == "other render options" { &["--width", "40"][..] } else { &image[..] });
        args.extend(extra);
        let o = photonkit(&args);
        assert!(!o.status.success() && stderr(&o).contains(says), "{says}: {}", stderr(&o));
        assert!(!Path::new(&refused).exists(), "{says}");
    }
    for (budget, says) in [("5M", "needs at least"), ("1G", "")] {
        let mut args = vec!["render", map.as_str(), "-o", &refused, "--memory", budget];
        args.extend(image);
        if budget == "1G" {
            args.extend(["--estimator", "diffusion"]);
        }
        let o = photonkit(&args);
        assert!(!o.status.success() && stderr(&o).contains("--memory"), "{budget}: {}", stderr(&o));
        assert!(stderr(&o).contains(says), "{}", stderr(&o));
        assert!(!Path::new(&refused).exists(), "{budget}");
    }
}

#[test]
fn the_pipeline_under_a_memory_budget_makes_the_maps_and_image_it_makes_in_memory() {
    let dir = tempfile::tempdir().unwrap();
    let (whole, budgeted) = (dir.path().join("whole"), dir.path().join("budgeted"));
    let image = ["--", "--width", "48", "--height", "32", "--spp", "1"];
    let mut args = vec!["pipeline", "--photons", "60000", "--out-dir", whole.to_str().unwrap()];
    args.extend(image);
    run(&args);
    let mut args =
        vec!["pipeline", "--photons", "60000", "--memory", "25M", "--out-dir", budgeted.to_str().unwrap()];
    args.extend(image);
    let o = photonkit(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    // Detect and relax ran tile by tile, each stage in its own process.
    assert!(stderr(&o).contains("detecting in ") && stderr(&o).contains("relaxing in "), "{}", stderr(&o));
    for stage in ["trace", "detect", "relax (params)", "collapse", "relax (world)", "render", "total"] {
        assert!(stderr(&o).lines().any(|l| l.starts_with(stage)), "no '{stage}' line in {}", stderr(&o));
    }
    for name in ["traced.phm", "detected.phm", "relaxed-params.phm", "collapsed.phm", "relaxed.phm"] {
        let (a, b) = (
            PhotonMap::open_path(&whole.join(name)).unwrap(),
            PhotonMap::open_path(&budgeted.join(name)).unwrap(),
        );
        assert_eq!(a.meta().state, b.meta().state, "{name}");
        let columns = |m: &PhotonMap| -> Vec<(String, u32)> {
            m.meta().columns.iter().map(|c| (c.name.clone(), c.crc32)).collect()
        };
        assert_eq!(columns(&a), columns(&b), "{name}: every column the same");
    }
    let png = |d: &Path| std::fs::read(d.join("render.png")).unwrap();
    assert!(png(&whole) == png(&budgeted), "the same image");
    let o = photonkit(&[
        "pipeline",
        "--photons",
        "60000",
        "--memory",
        "1M",
        "--out-dir",
        budgeted.to_str().unwrap(),
    ]);
    assert!(!o.status.success() && stderr(&o).contains("--memory"), "{}", stderr(&o));
}

/// A relax run under a budget tells of the moves refused on a curved receiver as the whole
/// map's run does: the count is of the map's photons' moves, not of every tile's halo as
/// well. The reflector's caustic lands on curved surfaces, where some moves are refused.
#[test]
fn a_budgeted_relax_counts_the_refused_moves_the_whole_map_refuses() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).display().to_string();
    let (traced, detected) = (path("traced.phm"), path("detected.phm"));
    let scene = sample_path("scenes/reflector.toml").display().to_string();
    run(&["trace", &scene, "--photons", "50000", "-o", &traced]);
    run(&["detect", &traced, "-o", &detected]);
    let refused = |extra: &[&str]| {
        let mut args = vec!["relax", detected.as_str(), "-o"];
        let out = path("relaxed.phm");
        args.push(&out);
        args.extend(extra);
        let o = photonkit(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        let note = stderr(&o).lines().find(|l| l.contains("moves were refused")).map(str::to_string);
        (note, stderr(&o).contains(" tiles ("))
    };
    let (whole, tiled) =
        (refused(&[]), refused(&["--memory", &(held_bytes("relax", &detected) + 4_000_000).to_string()]));
    assert!(whole.0.is_some() && !whole.1, "{whole:?}");
    assert!(tiled.1, "{tiled:?}");
    assert_eq!(whole.0, tiled.0);
}
