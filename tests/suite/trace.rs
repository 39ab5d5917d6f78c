//! The tracer against closed forms: focal distances, energy, parameter round trips; and the
//! command line: determinism across threads, shards and merge, scene-file errors.

use std::path::Path;

use glam::Vec3;
use photonkit::format::PhotonMap;
use photonkit::scene::material::{reflect, refract};
use photonkit::scene::{Material, Ray, Scene, SceneError};
use photonkit::trace::{self, Budget, StorePolicy, TraceOptions, Traced};

use super::common::{photonkit, root, stderr};

fn scene(src: &str) -> Scene {
    Scene::parse(src, "test.toml", Path::new(".")).unwrap()
}

fn run(s: &Scene, n: u64) -> Traced {
    trace::trace(s, &TraceOptions { budget: Budget::Emitted(n), ..Default::default() }, &|_, _| {}).unwrap()
}

fn total_flux(p: &trace::Photons) -> f64 {
    p.flux.iter().flatten().map(|&f| f as f64).sum()
}

#[test]
fn ideal_ball_lens_focuses_paraxial_rays_at_the_closed_form_distance() {
    // Ball lens: paraxial focus f = nR / (2(n − 1)) from the centre.
    let (n, r, cz) = (1.5f32, 0.5f32, 1.0f32);
    let src = format!(
        r#"
[materials.floor]
kind = "diffuse"
[materials.glass]
kind = "dielectric"
ior = {n}
ideal = true
[[emitters]]
kind = "collimated"
center = [0, 0, 2]
size = [0.02, 0.02]
direction = [0, 0, -1]
power_w = 1
[[shapes]]
kind = "plane"
normal = [0, 0, 1]
material = "floor"
[[shapes]]
kind = "sphere"
center = [0, 0, {cz}]
radius = {r}
material = "glass"
"#
    );
    let p = run(&scene(&src), 4000).photons().unwrap();
    assert_eq!(p.len(), 4000, "no Fresnel reflection: every photon reaches the floor");
    assert!(p.bounces.iter().all(|&b| b == 2));
    let f = n * r / (2.0 * (n - 1.0));
    let mut sum = 0.0f64;
    let mut used = 0;
    for (q, d) in p.position.iter().zip(&p.incident) {
        let (q, d) = (Vec3::from_array(*q), Vec3::from_array(*d));
        let h = (q.x * q.x + q.y * q.y).sqrt();
        if h < 1e-3 {
            continue; // the central ray carries no direction information
        }
        // Where the ray crosses the axis.
        let s = -(q.x * d.x + q.y * d.y) / (d.x * d.x + d.y * d.y);
        sum += (q.z + s * d.z) as f64;
        used += 1;
    }
    let z_focus = sum / used as f64;
    // Spherical aberration for a beam of half-width 1 cm (ρ = 0.028) is below 0.1 % of f.
    assert!(
        ((cz - f) as f64 - z_focus).abs() < 1e-3 * f as f64,
        "focus at z = {z_focus}, expected {}",
        cz - f
    );
}

#[test]
fn lossless_closed_scene_stores_exactly_the_emitted_power() {
    // A point light at the centre of a glass ball inside a diffuse sphere: every photon
    // crosses the glass (with or without Fresnel reflections) and lands on the sphere.
    for ideal in [true, false] {
        let src = format!(
            r#"
[materials.wall]
kind = "diffuse"
[materials.glass]
kind = "dielectric"
ior = 1.5
ideal = {ideal}
[[emitters]]
kind = "point"
position = [0.01, -0.02, 0.015]
power_w = 7
colour = [1, 2, 3]
[[shapes]]
kind = "sphere"
radius = 2
material = "wall"
[[shapes]]
kind = "sphere"
radius = 0.5
material = "glass"
"#
        );
        let t = run(&scene(&src), 20_000);
        let p = t.photons().unwrap();
        assert_eq!(p.len(), 20_000);
        let total = total_flux(&p);
        assert!((total - 7.0).abs() < 1e-4, "ideal = {ideal}: {total} W stored of 7 W");
        // Colour split 1 : 2 : 3.
        let red: f64 = p.flux.iter().map(|f| f[0] as f64).sum();
        assert!((red - 7.0 / 6.0).abs() < 1e-4);
        if !ideal {
            assert!(p.bounces.iter().any(|&b| b > 2), "Fresnel reflections happen");
        }
        assert_eq!(t.bounce_limited, 0);
    }
}

#[test]
fn parabolic_mirror_focuses_a_collimated_beam_onto_a_small_receiver() {
    let src = r#"
[materials.receiver]
kind = "diffuse"
[materials.mirror]
kind = "mirror"
[[emitters]]
kind = "collimated"
center = [0, 0, 1]
size = [0.8, 0.8]
direction = [0, 0, -1]
power_w = 10
[[shapes]]
kind = "paraboloid"
focal_length = 0.5
radius = 0.3
rings = 96
segments = 192
material = "mirror"
[[shapes]]
kind = "disc"
center = [0, 0, 0.5]
normal = [0, 0, -1]
radius = 0.01
material = "receiver"
"#;
    let s = scene(src);
    let p = run(&s, 60_000).photons().unwrap();
    for q in &p.position {
        let q = Vec3::from_array(*q);
        assert!((q - Vec3::new(0.0, 0.0, 0.5)).length() < 0.0101);
    }
    // Every photon that meets the mirror outside the receiver's shadow is focused onto it:
    // the stored share of the beam is the mirror's area minus the shadow, over the beam's.
    let segs = 192.0f64;
    let mirror = 0.5 * segs * 0.09 * (std::f64::consts::TAU / segs).sin();
    let expected = 10.0 * (mirror - std::f64::consts::PI * 1e-4) / 0.64;
    let total = total_flux(&p);
    assert!((total - expected).abs() < 0.01 * expected, "{total} W on the receiver, expected {expected}");
}

/// Follows a photon through ideal dielectrics and mirrors (no random choices) from an
/// emission ray to the first diffuse surface: an independent re-tracing for the round trip.
/// Continuing rays start as the tracer's do: exactly on an analytic surface (its own hits
/// nearer than the ray offset skipped), a ray offset off a mesh.
fn retrace(s: &Scene, mut ray: Ray) -> Option<Vec3> {
    let mut leaving: Option<u32> = None;
    for _ in 0..64 {
        let h = match leaving {
            Some(id) => s.intersect_leaving(&ray, photonkit::scene::Reach::All, id, f32::INFINITY),
            None => s.intersect(&ray, 0.0, f32::INFINITY),
        }?;
        let p = ray.at(h.t);
        let front = ray.dir.dot(h.normal) < 0.0;
        let n = if front { h.normal } else { -h.normal };
        leaving = s.is_analytic(h.shape).then_some(h.shape);
        let off = if leaving.is_some() { 0.0 } else { s.ray_offset() };
        match s.material(h.shape) {
            Material::Diffuse { .. } => return Some(p),
            Material::Mirror { .. } => ray = Ray::new(p + n * off, reflect(ray.dir, n)),
            Material::Dielectric(d) => {
                let eta = if front { 1.0 / d.ior } else { d.ior };
                ray = match refract(ray.dir, n, eta) {
                    Some(t) => Ray::new(p - n * off, t),
                    None => Ray::new(p + n * off, reflect(ray.dir, n)),
                };
            }
            _ => return None,
        }
    }
    None
}

#[test]
fn trajectory_parameters_recreate_each_photons_path() {
    // A collimated emitter over a mirror ring and a point light over an ideal glass ball.
    let src = r#"
[materials.floor]
kind = "diffuse"
[materials.metal]
kind = "mirror"
[materials.glass]
kind = "dielectric"
ior = 1.5
ideal = true
[[emitters]]
kind = "collimated"
center = [1.5, 0, 1.0]
size = [1.2, 1.2]
direction = [-0.866025, 0, -0.5]
power_w = 5
[[emitters]]
kind = "point"
position = [3, 0, 2]
power_w = 5
[[shapes]]
kind = "plane"
normal = [0, 0, 1]
material = "floor"
[[shapes]]
kind = "cylinder"
radius = 0.5
height = 0.3
material = "metal"
[[shapes]]
kind = "sphere"
center = [3, 0, 0.8]
radius = 0.4
material = "glass"
"#;
    let s = scene(src);
    let t = run(&s, 40_000);
    assert_eq!(t.param_dims, 3);
    assert!(t.emitter_column);
    let p = t.photons().unwrap();
    let mut per_emitter = [0; 2];
    for i in 0..p.len() {
        let e = p.emitter[i] as usize;
        per_emitter[e] += 1;
        let params = &p.params[3 * i..3 * i + 3];
        if e == 0 {
            assert_eq!(params[2], 0.0, "unused trailing parameter is zero");
        }
        let ray = s.emitters()[e].ray_from_params(params).unwrap();
        let q = retrace(&s, ray).unwrap();
        let d = (q - Vec3::from_array(p.position[i])).length();
        assert!(d < 1e-3, "photon {i} (emitter {e}) re-traced {d} m away");
    }
    assert!(per_emitter.iter().all(|&c| c > 500), "{per_emitter:?}");
}

#[test]
fn bvh_agrees_with_brute_force_on_the_water_scene() {
    let s = Scene::load(&root().join("samples/scenes/water.toml")).unwrap();
    assert!(s.triangle_count() > 100_000);
    let mut k = 0u32;
    let mut hits = 0;
    for i in 0..40 {
        for j in 0..10 {
            k += 1;
            let o = Vec3::new(-0.6 + 0.03 * i as f32, -0.6 + 0.12 * j as f32, 1.0);
            let d =
                Vec3::new(0.3 * ((k as f32) * 0.7).sin(), 0.3 * ((k as f32) * 1.3).cos(), -1.0).normalize();
            let r = Ray::new(o, d);
            let (a, b) =
                (s.intersect(&r, 0.0, f32::INFINITY), s.intersect_brute_force(&r, 0.0, f32::INFINITY));
            assert_eq!(a.map(|h| (h.shape, h.t)), b.map(|h| (h.shape, h.t)), "ray {k}");
            hits += a.is_some_and(|h| h.shape == 1) as u32;
        }
    }
    assert!(hits > 300);
}

#[test]
fn every_sample_scene_stores_caustic_photons_and_no_more_than_its_power() {
    let dir = root().join("samples/scenes");
    let mut n = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "toml") {
            continue;
        }
        n += 1;
        let s = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
        assert!(s.camera().is_some(), "{} has no camera", path.display());
        let t = run(&s, 20_000);
        let p = t.photons().unwrap();
        assert!(p.len() > 20, "{}: only {} photons stored", path.display(), p.len());
        assert!(p.bounces.iter().all(|&b| b > 0));
        let power: f64 = s.emitters().iter().map(|e| e.power_w).sum();
        // Dispersion weights average 1 per channel, so allow their noise on top.
        assert!(total_flux(&p) <= power * 1.01, "{}", path.display());
        for n in &p.normal {
            assert!((Vec3::from_array(*n).length() - 1.0).abs() < 1e-4);
        }
    }
    assert!(n >= 6, "{n} sample scenes");
}

#[test]
fn direct_photons_join_with_store_direct() {
    let s = Scene::default_scene();
    let opts = TraceOptions { budget: Budget::Emitted(10_000), ..Default::default() };
    let c = trace::trace(&s, &opts, &|_, _| {}).unwrap();
    let d = trace::trace(&s, &TraceOptions { store: StorePolicy::Direct, ..opts }, &|_, _| {}).unwrap();
    assert!(d.stored > c.stored);
    let direct = d.photons().unwrap().bounces.iter().filter(|&&b| b == 0).count() as u64;
    assert_eq!(d.stored - direct, c.stored);
}

fn scene_file(dir: &Path, name: &str, text: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p.display().to_string()
}

#[test]
fn cli_output_is_identical_on_one_and_two_threads() {
    let dir = tempfile::tempdir().unwrap();
    let out = |name: &str, threads: &str| {
        let p = dir.path().join(name);
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_photonkit"))
            .args(["trace", "--photons", "50000", "--seed", "7", "--threads", threads, "-o"])
            .arg(&p)
            .env("SOURCE_DATE_EPOCH", "1700000000")
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", stderr(&o));
        std::fs::read(p).unwrap()
    };
    let (a, b) = (out("a.phm", "1"), out("b.phm", "2"));
    assert!(a.len() > 10_000);
    assert!(a == b, "the files differ");
    let map = PhotonMap::from_bytes("a.phm", &a).unwrap();
    assert_eq!(map.meta().history[0].time, "2023-11-14T22:13:20Z");
}

#[test]
fn merged_shards_equal_a_single_run_byte_for_byte() {
    let dir = tempfile::tempdir().unwrap();
    let scene = root().join("samples/scenes/ring.toml").display().to_string();
    let trace = |out: &Path, shard: Option<&str>| {
        let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_photonkit"));
        c.args(["trace", &scene, "--photons", "30001", "--seed", "3", "-o"]).arg(out);
        if let Some(s) = shard {
            c.args(["--shard", s]);
        }
        let o = c.env("SOURCE_DATE_EPOCH", "1700000000").output().unwrap();
        assert!(o.status.success(), "{}", stderr(&o));
    };
    let single = dir.path().join("single.phm");
    trace(&single, None);
    let shards: Vec<String> = (0..3)
        .map(|i| {
            let p = dir.path().join(format!("s{i}.phm"));
            trace(&p, Some(&format!("{i}/3")));
            p.display().to_string()
        })
        .collect();
    let merged = dir.path().join("merged.phm").display().to_string();
    // Shards in any order.
    let o = photonkit(&["merge", &shards[2], &shards[0], &shards[1], "-o", &merged]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (a, b) = (std::fs::read(&single).unwrap(), std::fs::read(&merged).unwrap());
    assert!(PhotonMap::from_bytes("single", &a).unwrap().len() > 1000);
    assert!(a == b, "merged shards differ from the single run");

    // A missing shard or a shard given twice is refused, and nothing is written.
    let bad = dir.path().join("bad.phm");
    let o = photonkit(&["merge", &shards[0], &shards[1], "-o", &bad.display().to_string()]);
    assert!(!o.status.success() && stderr(&o).contains("shard 2/3 is missing"), "{}", stderr(&o));
    let o = photonkit(&["merge", &shards[0], &shards[1], &shards[1], "-o", &bad.display().to_string()]);
    assert!(!o.status.success() && stderr(&o).contains("given twice"), "{}", stderr(&o));
    // A single run is not a shard.
    let o = photonkit(&["merge", &single.display().to_string(), "-o", &bad.display().to_string()]);
    assert!(!o.status.success());
    assert!(!bad.exists());
}

#[test]
fn bad_scene_files_name_line_and_field_and_leave_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let good = std::fs::read_to_string(root().join("samples/scenes/glass-sphere.toml")).unwrap();
    let line_of = |text: &str, needle: &str| text.lines().position(|l| l.contains(needle)).unwrap() + 1;
    let cases = [
        (good.replace("radius = 0.5", "radius = -0.5"), "radius = -0.5", "shapes[1].radius"),
        (
            good.replace("material = \"glass\"", "material = \"crystal\""),
            "material = \"crystal\"",
            "shapes[1].material",
        ),
        (good.replace("power_w = 10.0", "power_w = \"ten\""), "power_w = \"ten\"", "power_w"),
        (good.replace("fov_deg = 35", "fov_degrees = 35"), "fov_degrees = 35", "fov_degrees"),
    ];
    for (k, (text, needle, field)) in cases.iter().enumerate() {
        let path = scene_file(dir.path(), &format!("bad{k}.toml"), text);
        let out = dir.path().join(format!("out{k}.phm"));
        let o = photonkit(&["trace", &path, "--photons", "1000", "-o", &out.display().to_string()]);
        assert!(!o.status.success());
        let msg = stderr(&o);
        let line = line_of(text, needle);
        assert!(msg.contains(&format!("{path}:{line}:")), "case {k}: no line {line} in: {msg}");
        assert!(msg.contains(field), "case {k}: no field {field} in: {msg}");
        assert!(!out.exists(), "case {k}: an output file was left");
    }
    // The library error carries the same facts.
    match Scene::parse(&cases[0].0, "x.toml", Path::new(".")) {
        Err(SceneError::Invalid { line, field, .. }) => {
            assert_eq!((line, field.as_str()), (line_of(&cases[0].0, cases[0].1), "shapes[1].radius"));
        }
        other => panic!("{other:?}"),
    }
    // A missing OBJ file names its field too.
    let text = format!("{good}\n[[shapes]]\nkind = \"obj\"\nfile = \"nowhere.obj\"\nmaterial = \"glass\"\n");
    let path = scene_file(dir.path(), "obj.toml", &text);
    let o = photonkit(&["trace", &path, "-o", &dir.path().join("o.phm").display().to_string()]);
    assert!(!o.status.success() && stderr(&o).contains("shapes[2].file"), "{}", stderr(&o));
}

#[test]
fn stored_budget_from_the_cli_writes_that_many_photons() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("m.phm");
    let o = photonkit(&["trace", "--stored", "3000", "-o", &out.display().to_string()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let map = PhotonMap::open(&out.display().to_string()).unwrap();
    assert_eq!(map.len(), 3000);
    let rec = &map.meta().history[0];
    assert_eq!(rec.stage, "trace");
    let emitted = rec.report["emitted"].as_u64().unwrap();
    let idx = map.column::<u64>("emission_index").unwrap().unwrap();
    assert_eq!(emitted, idx[2999] + 1);
    // Total flux is the stored share of the 10 W beam.
    let total: f64 = map.flux().iter().flatten().map(|&f| f as f64).sum();
    assert!((total - 10.0 * 3000.0 / emitted as f64).abs() < 1e-3);
    let e = &map.meta().emitters[0];
    assert_eq!((e.param_dims, e.param_measure), (2, Some(1.0)));
    assert!(map.column_bytes("surface").is_some() && map.column_bytes("emitter").is_none());
}

/// A glass sphere resting on the floor: photons that leave it next to the contact point land
/// beside it (issue 30: a ray offset used to start them below the floor, and the 12.5 mm disc
/// around the contact point received 0.6 % of its flux). Against the closed-form caustic.
#[test]
fn a_sphere_touching_the_floor_loses_no_photons_at_the_contact_point() {
    use photonkit::eval::truth::SphereCaustic;
    for gap in [0.0f64, 0.001] {
        let src = format!(
            r#"
[materials.floor]
kind = "diffuse"
[materials.glass]
kind = "dielectric"
ior = 1.5
ideal = true
[[emitters]]
kind = "collimated"
center = [0, 0, 3]
size = [0.1, 0.1]
direction = [0, 0, -1]
power_w = 1
[[shapes]]
kind = "rectangle"
origin = [-2, -2, 0]
edge_u = [4, 0, 0]
edge_v = [0, 4, 0]
material = "floor"
[[shapes]]
kind = "sphere"
center = [0, 0, {}]
radius = 1
material = "glass"
"#,
            1.0 + gap
        );
        let p = run(&scene(&src), 40_000).photons().unwrap();
        let radius = 0.0125f64;
        let traced: f64 = p
            .position
            .iter()
            .zip(&p.flux)
            .filter(|(x, _)| (x[0] as f64).hypot(x[1] as f64) < radius && x[2].abs() < 1e-3)
            .map(|(_, f)| f.iter().map(|&c| c as f64).sum::<f64>())
            .sum();
        let truth = SphereCaustic {
            radius: 1.0,
            centre_height: 1.0 + gap,
            ior: 1.5,
            beam_irradiance: 1.0 / 0.01,
            fresnel: false,
        };
        // The flux of the impact parameters the beam covers (b < 5 cm, the square's inscribed
        // disc; b ≥ 5 cm lands beyond 16 mm) that land within `radius` of the axis.
        let steps = 100_000;
        let db = 0.05 / steps as f64;
        let expected: f64 = (0..steps)
            .map(|k| (k as f64 + 0.5) * db)
            .filter_map(|b| truth.landing(b).map(|(rho, t)| (b, rho, t)))
            .filter(|(_, rho, _)| rho.abs() < radius)
            .map(|(b, _, t)| truth.beam_irradiance * t * 2.0 * std::f64::consts::PI * b * db)
            .sum();
        assert!(expected > 0.3, "the disc receives a good part of the beam ({expected} W)");
        assert!(
            (traced / expected - 1.0).abs() < 0.03,
            "gap {gap}: {traced} W traced, {expected} W expected"
        );
    }
}

/// Every stored direction and normal is unit length after any number of bounces on every
/// sample scene (issue 31: refraction compounded rounding to 3.4e-3 after 8–10 bounces).
#[test]
fn stored_directions_are_unit_on_every_sample_scene() {
    for entry in std::fs::read_dir(root().join("samples/scenes")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "toml") {
            continue;
        }
        let s = Scene::load(&path).unwrap();
        let p = run(&s, 30_000).photons().unwrap();
        for (i, d) in p.incident.iter().enumerate() {
            let len = Vec3::from(*d).length();
            assert!((len - 1.0).abs() < 2e-6, "{}: photon {i} incident length {len}", path.display());
        }
    }
}

/// Requests the machine cannot hold are refused with a message, not an allocation abort or a
/// full disk (issue 31: `--photons 1e12` aborted with a backtrace, `--stored 1e12` grew without
/// bound). `trace` spools photons beyond `--memory` to disk, so its limits are the memory it
/// is allowed and the free space beside the output.
#[test]
fn counts_beyond_memory_or_disk_are_refused_not_aborted() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t.phm");
    let os = out.to_str().unwrap();
    let run = |args: &[&str], env: Option<(&str, &str)>| {
        let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_photonkit"));
        c.args(args);
        if let Some((k, v)) = env {
            c.env(k, v);
        }
        c.output().unwrap()
    };
    // A stored count is checked before anything is traced; an emitted count after one batch
    // (here with the free space, or the memory, lowered to 1 MB, which 1 M photons of this
    // scene outgrow).
    let disk = Some(("PHOTONKIT_TEST_DISK_BUDGET", "1000000"));
    let memory = Some(("PHOTONKIT_TEST_MEMORY_BUDGET", "1000000"));
    for (args, env, want) in [
        (vec!["trace", "--stored", "1e12", "-o", os], None, "GB of disk for the stored photons"),
        (vec!["trace", "--photons", "1000000", "-o", os], disk, "GB free in"),
        (vec!["trace", "--photons", "1000000", "-o", os], memory, "GB of memory available"),
    ] {
        let o = run(&args, env);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {}", stderr(&o));
        assert!(stderr(&o).contains(want), "{args:?}: {}", stderr(&o));
        assert!(!stderr(&o).contains("backtrace"));
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "{args:?} left a file");
    }
    let o = run(&["trace", "--photons", "100000", "-o", os], None);
    assert!(o.status.success(), "{}", stderr(&o));
}

/// `trace --memory` bounds the photons held in memory; beyond it they are spooled beside the
/// output and the map is written from there: the file is the same byte for byte and no spool
/// file is left behind (BENCHMARKS.md measures the memory saved).
#[test]
fn trace_memory_limit_spools_to_the_same_file() {
    let dir = tempfile::tempdir().unwrap();
    let trace = |memory: &str, name: &str| {
        let out = dir.path().join(name);
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_photonkit"))
            .args(["trace", "--photons", "400000", "--memory", memory, "-o", out.to_str().unwrap()])
            .env("SOURCE_DATE_EPOCH", "1700000000")
            .output()
            .unwrap();
        assert!(o.status.success(), "--memory {memory}: {}", stderr(&o));
        std::fs::read(out).unwrap()
    };
    let held = trace("1G", "held.phm");
    let spooled = trace("64KiB", "spooled.phm");
    assert!(held.len() > 4_000_000, "enough photons to spool: {} bytes", held.len());
    assert!(held == spooled, "the spooled run wrote a different file");
    let mut names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    names.sort();
    assert_eq!(names, ["held.phm", "spooled.phm"]);
    for bad in ["0", "lots", "5 parsecs"] {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_photonkit"))
            .args(["trace", "--memory", bad, "-o", dir.path().join("x.phm").to_str().unwrap()])
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "--memory {bad}");
        assert!(stderr(&o).contains("--memory"), "--memory {bad}: {}", stderr(&o));
    }
}

/// Scene mistakes are named by their full field path and refused before tracing (issue 31):
/// a wrong type, an array of the wrong length, a power f32 flux cannot hold, and OBJ vertices
/// that are not finite or faces of two vertices.
#[test]
fn scene_mistakes_name_their_field() {
    let dir = tempfile::tempdir().unwrap();
    let base = "[materials.floor]\nkind = \"diffuse\"\n[[emitters]]\nkind = \"collimated\"\ncenter = [0, 0, 2]\n\
                size = [1, 1]\ndirection = [0, 0, -1]\npower_w = 1\n[[shapes]]\nkind = \"plane\"\nnormal = [0, 0, 1]\n\
                material = \"floor\"\n[[shapes]]\nkind = \"sphere\"\ncenter = [0, 0, 1]\nradius = 0.5\nmaterial = \"floor\"\n";
    assert!(Scene::parse(base, "t.toml", dir.path()).is_ok());
    for (from, to, want) in [
        ("radius = 0.5", "radius = \"big\"", "t.toml:16:10: shapes[1].radius: invalid type"),
        ("size = [1, 1]", "size = [1, 1, 1]", "t.toml:6:1: emitters[0].size: expected 2 numbers, found 3"),
        ("power_w = 1\n", "power_w = 1e308\n", "emitters[0].power_w: 1e308 W is beyond"),
    ] {
        let e = Scene::parse(&base.replace(from, to), "t.toml", dir.path()).unwrap_err().to_string();
        assert!(e.contains(want), "{to}: {e}");
    }
    for (obj, want) in [
        ("v nan 0 1\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "line 1: vertex coordinate 'nan'"),
        ("v 0 0 1e308\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "line 1: vertex coordinate '1e308'"),
        ("v 0 0 1\nv 1 0 0\nv 0 1 0\nf 1 2\nf 1 2 3\n", "line 4: a face needs at least three vertices"),
    ] {
        std::fs::write(dir.path().join("m.obj"), obj).unwrap();
        let src = base.replace(
            "kind = \"sphere\"\ncenter = [0, 0, 1]\nradius = 0.5",
            "kind = \"obj\"\nfile = \"m.obj\"",
        );
        let e = Scene::parse(&src, "t.toml", dir.path()).unwrap_err().to_string();
        assert!(e.contains("shapes[1].file") && e.contains(want), "{obj:?}: {e}");
    }
}

/// A missing scene file is reported before a missing `--output` (issue 29: the user fixed the
/// option only to learn the scene did not exist); without `--output` the exit status is the
/// usage error's, 2.
#[test]
fn trace_reports_a_missing_scene_before_a_missing_output() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nonexist.toml");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_photonkit"))
        .args(["trace", missing.to_str().unwrap()])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("nonexist.toml") && !stderr(&o).contains("--output"), "{}", stderr(&o));
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_photonkit")).args(["trace"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--output FILE is required"), "{}", stderr(&o));
}

/// Issue 23: a scene that disperses gives its photons their wavelength as a trajectory
/// parameter (format 1.1, `rect_uv_spectral`, the wavelength in nm within the visible range,
/// `wavelength` in the text form, and `inspect --check` passes); a scene that does not keeps
/// format 1.0 and the emitter record of earlier builds (no `dimensions`).
#[test]
fn a_dispersive_scene_carries_the_wavelength_and_others_stay_version_1_0() {
    use photonkit::format::Parameterisation;
    let dir = tempfile::tempdir().unwrap();
    let prism = dir.path().join("prism.phm");
    let sphere = dir.path().join("sphere.phm");
    let scenes = root().join("samples/scenes");
    for (scene, out) in [("prism.toml", &prism), ("glass-sphere.toml", &sphere)] {
        let o = photonkit(&[
            "trace",
            scenes.join(scene).to_str().unwrap(),
            "--photons",
            "20000",
            "-o",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let o = photonkit(&["inspect", "--check", out.to_str().unwrap()]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let m = PhotonMap::open_path(&sphere).unwrap();
    assert_eq!(m.version(), (1, 0));
    let e = &m.meta().emitters[0];
    assert_eq!((e.parameterisation, e.param_dims, e.dimensions.len()), (Parameterisation::RectUv, 2, 0));

    let m = PhotonMap::open_path(&prism).unwrap();
    assert_eq!(m.version(), (1, 1));
    let e = &m.meta().emitters[0];
    assert_eq!((e.parameterisation, e.param_dims), (Parameterisation::RectUvSpectral, 3));
    assert_eq!(e.dimensions[2].name, "wavelength");
    assert_eq!(e.dimensions[2].unit.as_deref(), Some("nm"));
    let params: &[f32] = bytemuck::cast_slice(m.column_bytes("params").unwrap());
    let l: Vec<f32> = params.chunks_exact(3).map(|q| q[2]).collect();
    assert!(l.iter().all(|l| (380.0..=720.0).contains(l)), "wavelengths in the visible range");
    // Drawn uniformly: the mean is the range's middle within a few standard errors.
    let mean = l.iter().map(|&x| x as f64).sum::<f64>() / l.len() as f64;
    assert!((mean - 550.0).abs() < 5.0, "mean wavelength {mean}");
    let o = photonkit(&["inspect", "--dump", prism.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(String::from_utf8_lossy(&o.stdout).lines().next().unwrap().contains("param_1\twavelength"));

    // A point-lit prism: (x, y, z, λ), four parameter dimensions through every stage.
    let out = dir.path().join("point");
    let o = photonkit(&[
        "pipeline",
        scenes.join("prism-point.toml").to_str().unwrap(),
        "--photons",
        "100000",
        "--out-dir",
        out.to_str().unwrap(),
        "--",
        "--width",
        "32",
        "--height",
        "32",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let m = PhotonMap::open_path(&out.join("detected.phm")).unwrap();
    let e = &m.meta().emitters[0];
    assert_eq!((e.parameterisation, e.param_dims), (Parameterisation::DirectionSpectral, 4));
    assert!(e.dimensions[3].scale.is_some_and(|s| s > 0.0), "detect records the wavelength's scale");
    let o = photonkit(&["inspect", "--check", out.join("relaxed.phm").to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
}
