//! `photonkit compare` end to end on a small run of the default scene.

use super::common::*;

/// Reads report.csv into (method, setting, columns by name).
fn rows(csv: &str) -> Vec<std::collections::HashMap<String, String>> {
    let mut lines = csv.lines();
    let head: Vec<String> = lines.next().unwrap().split(',').map(str::to_string).collect();
    lines
        .map(|l| {
            // Quoted fields hold no commas in these runs except inside the setting: split
            // outside quotes.
            let mut fields = Vec::new();
            let (mut cur, mut quoted) = (String::new(), false);
            for ch in l.chars() {
                match ch {
                    '"' => quoted = !quoted,
                    ',' if !quoted => fields.push(std::mem::take(&mut cur)),
                    c => cur.push(c),
                }
            }
            fields.push(cur);
            assert_eq!(fields.len(), head.len(), "{l}");
            head.iter().cloned().zip(fields).collect()
        })
        .collect()
}

// Long because one run of `compare` (the slow part) is checked for every file and figure it
// writes.
#[test]
fn compare_runs_every_method_and_relaxation_beats_raw_photon_mapping_on_the_same_photons() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("cmp");
    let o = photonkit(&[
        "compare",
        "--photons",
        "40000",
        "--cells",
        "32",
        "--spp",
        "1",
        "--seeds",
        "2",
        "--pm-k",
        "15,50",
        "--diffusion-k",
        "60",
        "--ppm-passes",
        "1,8",
        "--ppm-photons",
        "10000",
        "--fast-truth",
        "--out-dir",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    for f in ["report.md", "report.csv", "grid.png", "error-vs-time.png"] {
        let p = out.join(f);
        assert!(p.is_file() && std::fs::metadata(&p).unwrap().len() > 100, "{f} missing");
    }
    // The truth and every image as EXR, the view in the header (read by the file layout alone).
    for f in ["truth", "pm-k-15", "ours-param-pca-7-7-iterations-k-15"] {
        let p = out.join("images").join(format!("{f}.exr"));
        let header = exr_header(&p);
        let text = |name: &str| {
            header.iter().find(|(n, _, _)| n == name).map(|(_, _, v)| String::from_utf8_lossy(v).to_string())
        };
        assert!(text("photonkit:grid").is_some_and(|g| g.contains("32 columns")), "{f}: {header:?}");
        assert!(text("photonkit:unit").is_some_and(|u| u.contains("W/m²")), "{f}");
    }
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    for row in [
        "Photon cast t",
        "Feature detect t",
        "Relaxation t",
        "Render t",
        "Total t",
        "NRMSE",
        "SSIM",
        "At equal time",
        "Time to error",
        "One view and ten",
    ] {
        assert!(md.contains(row), "report.md lacks '{row}'");
    }
    let csv = std::fs::read_to_string(out.join("report.csv")).unwrap();
    let all = rows(&csv);
    // One line per method for the whole image, then one per region class.
    let r: Vec<_> = all.iter().filter(|x| x["region"] == "all").cloned().collect();
    let methods: Vec<&str> = r.iter().map(|x| x["method"].as_str()).collect();
    assert_eq!(methods, ["pm", "pm", "relax2009", "diffusion", "ours", "ppm", "ppm"]);
    let pm_k: Vec<&str> =
        r.iter().filter(|x| x["method"] == "pm").map(|x| x["radiance_k"].as_str()).collect();
    assert_eq!(pm_k, ["15", "50"]);
    let num = |row: &std::collections::HashMap<String, String>, k: &str| row[k].parse::<f64>().unwrap();
    for row in &r {
        for k in ["total_s", "rmse", "nrmse", "rel_mse", "ssim", "edge_nrmse"] {
            let v = num(row, k);
            assert!(v.is_finite() && v >= 0.0, "{} {k} = {v}", row["method"]);
        }
        assert!(num(row, "ssim") <= 1.0 + 1e-9);
    }
    // Per region, over the two seeds: NRMSE² = bias² + variance, and the relaxed map trades
    // noise for blur: less variance than the raw photons in the smooth region.
    let regions: Vec<&str> =
        all.iter().filter(|x| x["method"] == "ours").map(|x| x["region"].as_str()).collect();
    assert_eq!(regions, ["all", "core", "edge", "smooth", "dark"]);
    let region = |m: &str, g: &str| all.iter().find(|x| x["method"] == m && x["region"] == g).unwrap();
    for m in ["pm", "ours"] {
        for g in ["all", "smooth"] {
            let x = region(m, g);
            let (e, b, v) = (num(x, "nrmse"), num(x, "bias2"), num(x, "variance"));
            assert!((e * e - (b + v)).abs() <= 1e-6 * e * e, "{m} {g}: {e}² against {b} + {v}");
            assert!(v > 0.0 && num(x, "p90_rel") >= num(x, "median_rel"), "{m} {g}");
        }
    }
    assert!(
        num(region("ours", "smooth"), "variance") < num(region("pm", "smooth"), "variance"),
        "ours {} against standard PM {}",
        num(region("ours", "smooth"), "variance"),
        num(region("pm", "smooth"), "variance")
    );
    for row in ["smooth NRMSE (bias², variance)", "dark median / p90 rel. error", "seeds"] {
        assert!(md.contains(row), "report.md lacks '{row}'");
    }
    // Relaxation removes the noise of the same photons: its relative error is well below the
    // raw estimate's (0.51× in this run; the threshold leaves room for rounding elsewhere).
    let by = |m: &str| r.iter().find(|x| x["method"] == m).unwrap();
    assert!(
        num(by("ours"), "rel_mse") < 0.7 * num(by("pm"), "rel_mse"),
        "ours {} against standard PM {}",
        num(by("ours"), "rel_mse"),
        num(by("pm"), "rel_mse")
    );
    // Progressive photon mapping converges: 8 passes beat 1.
    let ppm: Vec<f64> = r.iter().filter(|x| x["method"] == "ppm").map(|x| num(x, "rmse")).collect();
    assert!(ppm[1] < ppm[0], "PPM error {ppm:?} did not fall with passes");
    // Only the photons the truth accounts for are compared: fewer than were traced.
    let stored = num(by("pm"), "photons");
    assert!(stored > 1000.0 && stored < 40000.0);
}

/// `--estimator variable` renders standard PM and the relaxed maps with the variable kernel
/// and says so in each row's setting; the per-region numbers stay consistent.
#[test]
fn compare_renders_the_fixed_k_methods_with_the_variable_kernel_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("cmp");
    let o = photonkit(&[
        "compare",
        "--photons",
        "40000",
        "--cells",
        "32",
        "--spp",
        "1",
        "--seeds",
        "1",
        "--methods",
        "pm,ours",
        "--pm-k",
        "15",
        "--estimator",
        "variable",
        "--fast-truth",
        "--out-dir",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let all = rows(&std::fs::read_to_string(out.join("report.csv")).unwrap());
    let r: Vec<_> = all.iter().filter(|x| x["region"] == "all").collect();
    assert_eq!(r.len(), 2);
    for row in r {
        assert!(row["setting"].ends_with("K = 15, variable kernel"), "{}", row["setting"]);
        let e: f64 = row["nrmse"].parse().unwrap();
        assert!(e.is_finite() && e > 0.0, "{} nrmse {e}", row["method"]);
    }
}

#[test]
fn compare_refuses_bad_options_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("cmp");
    let o = photonkit(&["compare", "--methods", "pm,magic", "--out-dir", out.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("unknown method 'magic'"), "{}", stderr(&o));
    let o = photonkit(&["compare", "--sweep", "colour=1,2", "--out-dir", out.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("unknown setting 'colour'"), "{}", stderr(&o));
    let o = photonkit(&["compare", "--photons", "0", "--out-dir", out.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(!out.join("report.md").exists(), "no report from a failed run");
}
