//! The renderer against closed forms: uniform and direct light, framing, backgrounds.

use std::f32::consts::PI;
use std::path::Path;

use super::*;
use crate::scene::Projection;

/// A plane view frames its photons with a thousandth of their span to spare, and keeps
/// pixels square: 2 m × 1 m (padded) gives 600 × 301 by default, or follows a given side.
#[test]
fn a_plane_view_frames_its_photons_with_square_pixels() {
    let points = [[0.0, 0.0, 0.0], [2.0, 1.0, 0.0], [1.0, 0.5, 0.0]];
    let rect = PlaneView::frame(2, &points);
    assert_eq!(rect, [-0.002, -0.002, 2.002, 1.002]);
    assert_eq!(PlaneView::image_size(rect, None, None, 600), (600, 301));
    assert_eq!(PlaneView::image_size(rect, None, Some(100), 600), (200, 100));
    assert_eq!(PlaneView::image_size(rect, Some(50), Some(7), 600), (50, 7));
    // Coincident photons frame a tiny square around them, not a point.
    let r = PlaneView::frame(2, &[[1e-6, 1e-6, 0.0]; 3]);
    assert!(r[2] > r[0] && r[3] > r[1] && r[0] < 1e-6 && r[2] > 1e-6, "{r:?}");
}

/// A diffuse floor (albedo 0.5) at z = 0 and a 12 W point light 2 m above the origin.
fn floor_scene() -> Scene {
    let src = "[materials.floor]\nkind = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n[[shapes]]\nkind = \"plane\"\n\
               normal = [0, 0, 1]\nmaterial = \"floor\"\n[[emitters]]\nkind = \"point\"\nposition = [0, 0, 2]\n\
               power_w = 12\n";
    Scene::parse(src, "t.toml", Path::new(".")).unwrap()
}

/// Looking straight down at the 1 m × 1 m square around the origin.
fn top_down() -> Camera {
    Camera::look_at(
        Projection::Orthographic { height_m: 1.0 },
        Vec3::new(0.0, 0.0, 3.0),
        Vec3::ZERO,
        Vec3::Y,
        [1, 1],
    )
    .unwrap()
}

/// n photons on a jittered grid over [−1, 1]², `total` W in all: E = total/3/4 per channel.
fn grid_photons(side: usize, total: f32) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let mut rng = PhotonRng::new(5, 5);
    let cell = 2.0 / side as f32;
    let pos = (0..side * side)
        .map(|i| {
            let (x, y) = ((i % side) as f32 + rng.next_f32(), (i / side) as f32 + rng.next_f32());
            [-1.0 + x * cell, -1.0 + y * cell, 0.0]
        })
        .collect();
    (pos, vec![[total / 3.0 / (side * side) as f32; 3]; side * side])
}

fn opts(mode: Mode) -> RenderOptions {
    RenderOptions { width: 24, height: 24, spp: 4, mode, ..Default::default() }
}

#[test]
fn uniformly_lit_plane_renders_the_closed_form_radiance() {
    // 12 W over 4 m²: E = 1 W/m² per channel, L = ρE/π = 0.5/π. The photons are on a
    // jittered grid; the mean over the image is within 2 %, and the pixels scatter about it
    // by the estimator's noise (K = 15 photons per lookup, 4 lookups per pixel).
    let (pos, flux) = grid_photons(200, 12.0);
    let normals = vec![[0.0, 0.0, 1.0]; pos.len()];
    let photons =
        PhotonLookup::new("t", PhotonData { positions: &pos, flux: &flux, normals: Some(&normals) }).unwrap();
    let scene = floor_scene();
    let view = View::Scene { scene: &scene, camera: top_down() };
    let r = Renderer { view, photons: Some(&photons), diagnostic: None, opts: opts(Mode::Caustic) };
    let (img, stats) = r.render(&|_| {}).unwrap();
    assert_eq!(stats.samples, 24 * 24 * 4);
    assert_eq!(stats.lookups, stats.samples);
    let expected = 0.5 / PI;
    assert!((img.mean().x / expected - 1.0).abs() < 0.02, "{} vs {expected}", img.mean());
    let dev = img.pixels.iter().map(|p| (p.y / expected - 1.0).abs()).fold(0.0f32, f32::max);
    let rms = (img.pixels.iter().map(|p| (p.y / expected - 1.0).powi(2)).sum::<f32>()
        / img.pixels.len() as f32)
        .sqrt();
    assert!(rms < 0.08 && dev < 0.25, "pixels stray: rms {rms}, max {dev}");
    // Irradiance mode: E itself.
    let r = Renderer { opts: opts(Mode::Irradiance), ..r };
    let (img, _) = r.render(&|_| {}).unwrap();
    assert!((img.mean().z - 1.0).abs() < 0.02, "{}", img.mean());
    // The scene-less plane view of the same square gives the same irradiance.
    let plane = PlaneView::axis_aligned(2, 0.0, [-0.5, -0.5, 0.5, 0.5]);
    let r = Renderer { view: View::Plane(plane), ..r };
    let (flat, _) = r.render(&|_| {}).unwrap();
    assert!((flat.mean().z - 1.0).abs() < 0.02, "{}", flat.mean());
}

/// `[background]` with an equirectangular EXR: an orthographic view along +x above the floor
/// meets nothing and sees the image at azimuth 0, polar angle 90°: with pixel (x, y) of an
/// 8 × 4 image holding (x, y, 1), the bilinear value between columns 3, 4 and rows 1, 2 is
/// (3.5, 1.5, 1), times the strength. A uniform colour is seen as it is, a sky's horizon
/// along the horizon; none shows in irradiance mode, which measures the photons only.
#[test]
fn a_background_is_seen_by_escaping_eye_rays() {
    let dir = tempfile::tempdir().unwrap();
    exr::prelude::write_rgb_file(dir.path().join("sky.exr"), 8, 4, |x, y| (x as f32, y as f32, 1.0f32))
        .unwrap();
    let floor = "[materials.floor]\nkind = \"diffuse\"\n[[shapes]]\nkind = \"plane\"\nnormal = [0, 0, 1]\n\
                 material = \"floor\"\n[[emitters]]\nkind = \"point\"\nposition = [0, 0, 2]\npower_w = 1\n";
    let along_x = Camera::look_at(
        Projection::Orthographic { height_m: 0.1 },
        Vec3::new(0.0, 0.0, 1.0),
        Vec3::new(10.0, 0.0, 1.0),
        Vec3::Z,
        [2, 2],
    )
    .unwrap();
    let render = |background: &str, mode: Mode| {
        let src = format!("{floor}[background]\n{background}\n");
        let scene = Scene::parse(&src, "t.toml", dir.path()).unwrap();
        let view = View::Scene { scene: &scene, camera: along_x.clone() };
        let r = Renderer {
            view,
            photons: None,
            diagnostic: None,
            opts: RenderOptions { width: 2, height: 2, spp: 1, ..opts(mode) },
        };
        r.render(&|_| {}).unwrap().0.mean()
    };
    let seen = render("image = \"sky.exr\"\nstrength = 2", Mode::Direct);
    assert!((seen - Vec3::new(7.0, 3.0, 2.0)).abs().max_element() < 1e-4, "{seen}");
    let seen = render("colour = [0.1, 0.2, 0.3]", Mode::Direct);
    assert!((seen - Vec3::new(0.1, 0.2, 0.3)).abs().max_element() < 1e-6, "{seen}");
    // Irradiance mode, top down over photons: the same image with and without a background.
    let (pos, flux) = grid_photons(40, 12.0);
    let photons = PhotonLookup::new("t", PhotonData { positions: &pos, flux: &flux, normals: None }).unwrap();
    let measured = |background: &str| {
        let scene = Scene::parse(&format!("{floor}{background}"), "t.toml", dir.path()).unwrap();
        let view = View::Scene { scene: &scene, camera: top_down() };
        let r = Renderer { view, photons: Some(&photons), diagnostic: None, opts: opts(Mode::Irradiance) };
        r.render(&|_| {}).unwrap().0.pixels
    };
    assert_eq!(measured(""), measured("[background]\ncolour = [5, 5, 5]\n"));
    let err = Scene::parse(&format!("{floor}[background]\nimage = \"none.exr\"\n"), "t.toml", dir.path());
    assert!(err.unwrap_err().to_string().contains("no such file"));
    let err = Scene::parse(
        &format!("{floor}[background]\ncolour = [1, 1, 1]\nimage = \"sky.exr\"\n"),
        "t.toml",
        dir.path(),
    );
    assert!(err.unwrap_err().to_string().contains("give one of colour"));
    // A sky: looking along the horizon sees `horizon` (times the strength).
    let seen = render("zenith = [0, 0, 1]\nhorizon = [0.5, 0.25, 0.125]\nstrength = 2", Mode::Direct);
    assert!((seen - Vec3::new(1.0, 0.5, 0.25)).abs().max_element() < 1e-6, "{seen}");
    for (sky, says) in [
        ("zenith = [0, 0, 1]\n", "needs both zenith and horizon"),
        ("zenith = [0, 0, 1]\nhorizon = [1, 1, 1]\ncolour = [1, 1, 1]\n", "takes no colour"),
        ("zenith = [0, 0, 1]\nhorizon = [1, -1, 1]\n", "background.horizon"),
    ] {
        let err = Scene::parse(&format!("{floor}[background]\n{sky}"), "t.toml", dir.path()).unwrap_err();
        assert!(err.to_string().contains(says), "{sky}: {err}");
    }
}

#[test]
fn direct_light_image_matches_the_inverse_square_cosine_law() {
    // Pixel (x, y) of the top-down view sees floor point q; L = ρ/π · P/3/(4π) · h/|q − s|³.
    let scene = floor_scene();
    let r = Renderer {
        view: View::Scene { scene: &scene, camera: top_down() },
        photons: None,
        diagnostic: None,
        opts: RenderOptions { spp: 1, ..opts(Mode::Direct) },
    };
    let (img, _) = r.render(&|_| {}).unwrap();
    let cam = Camera { resolution: [24, 24], ..top_down() };
    for (x, y) in [(0, 0), (12, 12), (5, 17), (23, 3)] {
        // With one sample per pixel the jittered point is not known here: compare with the
        // closed form at the pixel's corners (the value lies between them).
        let e = |px: f32, py: f32| {
            let q = cam.ray(px, py).at(3.0);
            let d2 = q.x * q.x + q.y * q.y + 4.0;
            0.5 / PI * 4.0 / (4.0 * PI) * 2.0 / d2.powf(1.5)
        };
        let corners = [
            e(x as f32, y as f32),
            e(x as f32 + 1.0, y as f32),
            e(x as f32, y as f32 + 1.0),
            e(x as f32 + 1.0, y as f32 + 1.0),
        ];
        let (lo, hi) = corners.iter().fold((f32::MAX, 0.0f32), |(a, b), &c| (a.min(c), b.max(c)));
        let v = img.get(x, y).x;
        assert!(v >= lo * 0.9999 && v <= hi * 1.0001, "pixel ({x}, {y}): {v} not in [{lo}, {hi}]");
    }
}

/// A pinhole camera looking down at the origin from the side.
fn oblique() -> Camera {
    Camera::look_at(
        Projection::Pinhole { fov_y_rad: 0.8 },
        Vec3::new(0.3, -2.0, 1.5),
        Vec3::ZERO,
        Vec3::Z,
        [1, 1],
    )
    .unwrap()
}

#[test]
fn images_do_not_depend_on_the_thread_count() {
    // Jitter comes from each pixel's own stream, and lookups are exact whatever the
    // order of queries on a thread.
    let (pos, flux) = grid_photons(60, 12.0);
    let photons = PhotonLookup::new("t", PhotonData { positions: &pos, flux: &flux, normals: None }).unwrap();
    let scene = floor_scene();
    let camera = oblique();
    let r = Renderer {
        view: View::Scene { scene: &scene, camera },
        photons: Some(&photons),
        diagnostic: None,
        opts: RenderOptions { width: 40, height: 30, spp: 3, ..opts(Mode::Full) },
    };
    let pool = |n| rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
    let a = pool(1).install(|| r.render(&|_| {})).unwrap();
    let b = pool(2).install(|| r.render(&|_| {})).unwrap();
    assert_eq!(a, b);
    assert!(a.0.mean().x > 0.0);
}

#[test]
fn bad_requests_are_refused() {
    let scene = floor_scene();
    let r = Renderer {
        view: View::Scene { scene: &scene, camera: top_down() },
        photons: None,
        diagnostic: None,
        opts: opts(Mode::Full),
    };
    assert!(matches!(r.render(&|_| {}), Err(RenderError::Invalid(_))));
    let r = Renderer { opts: RenderOptions { width: 0, ..opts(Mode::Direct) }, ..r };
    assert!(matches!(r.render(&|_| {}), Err(RenderError::Invalid(_))));
}

/// Supersampled pixels take their own count of samples, each pixel from its own jitter
/// stream: a flagged pixel is bit for bit the pixel of an image rendered with that count
/// everywhere, and the others the image's own.
#[test]
fn supersampled_pixels_are_those_of_an_image_sampled_as_densely() {
    let (pos, flux) = grid_photons(60, 12.0);
    let photons = PhotonLookup::new("t", PhotonData { positions: &pos, flux: &flux, normals: None }).unwrap();
    let scene = floor_scene();
    let camera = oblique();
    let (w, h) = (40u32, 30u32);
    let with = |spp: u32, supersample: Option<Supersample>| Renderer {
        view: View::Scene { scene: &scene, camera: camera.clone() },
        photons: Some(&photons),
        diagnostic: None,
        opts: RenderOptions { width: w, height: h, spp, supersample, ..opts(Mode::Full) },
    };
    let flags: Vec<bool> = (0..w * h).map(|i| i % 7 == 3 || (i / w) == 17).collect();
    let (sparse, _) = with(4, None).render(&|_| {}).unwrap();
    let (dense, _) = with(25, None).render(&|_| {}).unwrap();
    let (mixed, stats) =
        with(4, Some(Supersample { spp: 25, pixels: flags.clone().into() })).render(&|_| {}).unwrap();
    let flagged = flags.iter().filter(|&&f| f).count() as u64;
    assert_eq!(stats.samples, 25 * flagged + 4 * (w * h) as u64 - 4 * flagged);
    for (i, &f) in flags.iter().enumerate() {
        let want = if f { dense.pixels[i] } else { sparse.pixels[i] };
        assert_eq!(mixed.pixels[i], want, "pixel {i} (flagged: {f})");
    }
    assert_ne!(sparse.pixels, dense.pixels, "the two sample counts must give different images");
    // A plan that does not cover the image is refused.
    let short = with(4, Some(Supersample { spp: 25, pixels: vec![true; 5].into() }));
    assert!(matches!(short.render(&|_| {}), Err(RenderError::Invalid(_))));
}
