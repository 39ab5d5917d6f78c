//! The convex hull of a scene's closed convex mesh ([`crate::accel::hull`]) against the
//! scene's triangles; here because the tests read the scene's meshes and its hull.

use glam::Vec3;

use super::Scene;
use super::hull::Hull;
use super::shape::Ray;
use crate::scene::bvh::brute_force;
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// A glass extrusion of the regular `sides`-gon (radius 1, z from 1 to 1.7) over a floor.
fn extrusion(sides: usize) -> Scene {
    let outline: Vec<String> = (0..sides)
        .map(|k| {
            let a = std::f32::consts::TAU * k as f32 / sides as f32 + 0.3;
            format!("[{}, {}]", a.cos(), a.sin())
        })
        .collect();
    let src = format!(
        "[materials.floor]\nkind = \"diffuse\"\n[materials.glass]\nkind = \"dielectric\"\nior = 1.5\n\
         [[emitters]]\nkind = \"point\"\nposition = [0, 0, 3]\npower_w = 1\n\
         [[shapes]]\nkind = \"plane\"\nnormal = [0, 0, 1]\nmaterial = \"floor\"\n\
         [[shapes]]\nkind = \"extrusion\"\nmaterial = \"glass\"\noutline = [{}]\nz_range = [1, 1.7]\n",
        outline.join(", ")
    );
    Scene::parse(&src, "hull.toml", std::path::Path::new(".")).unwrap()
}

fn random_ray(rng: &mut Pcg64Mcg) -> Ray {
    let mut v = || Vec3::new(rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5);
    // Origins inside and around the body (|x|, |y| ≤ 1.5, z in 0.6..2.1).
    let o = v() * Vec3::new(3.0, 3.0, 1.5) + Vec3::new(0.0, 0.0, 1.35);
    Ray::new(o, v().try_normalize().unwrap_or(Vec3::Z))
}

/// Against every triangle tested in turn: where the triangles are met away from their
/// edges, the planes give the same distance (to rounding) and that triangle's normal; a
/// ray they miss, the planes miss too except through the cracks a triangle test leaves
/// at edges, which the planes do not have. Covers one group of planes (3, 4 and 6
/// sides: 5, 6 and 8 planes) and two (8 sides: 10 planes).
#[test]
fn the_planes_meet_what_the_triangles_meet() {
    for (sides, planes) in [(3, 5), (4, 6), (6, 8), (8, 10)] {
        let scene = extrusion(sides);
        let hull = scene.hull.as_ref().expect("a closed, flat, convex extrusion has a hull");
        assert_eq!(hull.planes(), planes, "{sides} sides: coplanar triangles share a plane");
        let mut rng = Pcg64Mcg::seed_from_u64(sides as u64);
        let (mut hits, mut cracks) = (0, 0);
        let n = 100_000;
        for _ in 0..n {
            let ray = random_ray(&mut rng);
            let got = hull.intersect(&ray, 0.0, f32::INFINITY, false);
            match brute_force(&scene.triangles, &ray, 0.0, f32::INFINITY) {
                Some(h) if h.b1.min(h.b2).min(1.0 - h.b1 - h.b2) > 1e-4 => {
                    hits += 1;
                    let (t, normal) = got.unwrap_or_else(|| panic!("{sides} sides: {ray:?} missed"));
                    assert!((t - h.t).abs() <= 1e-5 * (1.0 + h.t), "{sides} sides: t {t} against {}", h.t);
                    assert!(normal.dot(scene.tri_info[h.index as usize].normal) > 1.0 - 1e-6);
                    // A reach that ends short of the body (beyond rounding) meets nothing.
                    let short = h.t - 2e-5 * (1.0 + h.t);
                    if short > 0.0 {
                        assert_eq!(hull.intersect(&ray, 0.0, short, false), None);
                    }
                }
                Some(_) => {}
                None => cracks += got.is_some() as u32,
            }
        }
        assert!(hits > n / 10, "{sides} sides: {hits} hits");
        assert!(cracks <= n / 1000, "{sides} sides: {cracks} hits where no triangle is");
    }
}

/// The AVX build of the plane test gives exactly the portable one's hits.
#[test]
fn the_avx_planes_give_the_portable_hits() {
    if !crate::scene::bvh::avx_available() {
        return;
    }
    for sides in [3, 8] {
        let scene = extrusion(sides);
        let hull = scene.hull.as_ref().unwrap();
        let mut rng = Pcg64Mcg::seed_from_u64(7);
        for _ in 0..50_000 {
            let ray = random_ray(&mut rng);
            let t_min = if rng.random::<bool>() { 0.0 } else { rng.random::<f32>() };
            assert_eq!(
                hull.intersect(&ray, t_min, f32::INFINITY, true),
                hull.intersect(&ray, t_min, f32::INFINITY, false)
            );
        }
        // Axis-aligned rays run parallel to the caps and sides: inside or outside them.
        for o in [Vec3::new(0.0, 0.0, 1.3), Vec3::new(0.0, 0.0, 2.0), Vec3::new(5.0, 0.0, 1.3)] {
            for d in [Vec3::X, Vec3::NEG_X, Vec3::Y, Vec3::Z, Vec3::NEG_Z] {
                let ray = Ray::new(o, d);
                assert_eq!(hull.intersect(&ray, 0.0, 9.0, true), hull.intersect(&ray, 0.0, 9.0, false));
            }
        }
    }
}

/// Rays along the axis: the caps' distances in closed form, from outside, from inside,
/// and none from above the top looking up or beside the body.
#[test]
fn axis_rays_meet_the_caps_at_their_heights() {
    let scene = extrusion(6);
    let hull = scene.hull.as_ref().unwrap();
    let close = |a: Option<(f32, Vec3)>, t: f32, n: Vec3| {
        let (at, an) = a.expect("a hit");
        assert!((at - t).abs() < 1e-6 && an.dot(n) > 1.0 - 1e-6, "{a:?} against {t}, {n}");
    };
    for avx in [false, crate::scene::bvh::avx_available()] {
        close(hull.intersect(&Ray::new(Vec3::new(0.1, 0.0, 3.0), Vec3::NEG_Z), 0.0, 9.0, avx), 1.3, Vec3::Z);
        close(
            hull.intersect(&Ray::new(Vec3::new(0.1, 0.0, 1.2), Vec3::NEG_Z), 0.0, 9.0, avx),
            0.2,
            Vec3::NEG_Z,
        );
        close(hull.intersect(&Ray::new(Vec3::new(0.1, 0.0, 1.2), Vec3::Z), 0.0, 9.0, avx), 0.5, Vec3::Z);
        assert_eq!(hull.intersect(&Ray::new(Vec3::new(0.1, 0.0, 3.0), Vec3::Z), 0.0, 9.0, avx), None);
        assert_eq!(hull.intersect(&Ray::new(Vec3::new(3.0, 0.0, 3.0), Vec3::NEG_Z), 0.0, 9.0, avx), None);
        // The entry beyond the reach: nothing.
        assert_eq!(hull.intersect(&Ray::new(Vec3::new(0.1, 0.0, 3.0), Vec3::NEG_Z), 0.0, 1.0, avx), None);
    }
}

/// The prism sample (the tracer's benchmark) goes through its planes, at any scale.
#[test]
fn the_prism_sample_has_a_hull() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/scenes/prism.toml");
    let prism = Scene::load(&path).unwrap();
    assert_eq!(prism.hull.as_ref().map(Hull::planes), Some(5));
    assert_eq!(prism.scaled(1000.0).hull.as_ref().map(Hull::planes), Some(5));
}

/// Only a closed mesh of non-degenerate triangles has a hull.
#[test]
fn an_open_mesh_has_no_hull() {
    let scene = extrusion(4);
    let normals: Vec<Vec3> = scene.tri_info.iter().map(|t| t.normal).collect();
    assert!(Hull::new(&scene.triangles, &normals, 1e-6).is_some());
    let n = scene.triangles.len();
    assert!(Hull::new(&scene.triangles[..n - 1], &normals[..n - 1], 1e-6).is_none(), "a face missing");
    let mut flat = normals.clone();
    flat[0] = Vec3::ZERO;
    assert!(Hull::new(&scene.triangles, &flat, 1e-6).is_none(), "a degenerate triangle");
    assert!(Hull::new(&[], &[], 1e-6).is_none());
}
