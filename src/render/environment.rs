//! The scene's background as the renderer sees it: the radiance an escaping eye ray carries
//! back, a uniform colour or a lookup in an equirectangular image (docs/scene.md,
//! `[background]`).

use std::f32::consts::{PI, TAU};

use glam::Vec3;

use super::RenderError;
use super::image::{Image, read_exr};
use crate::scene::Background;

/// A loaded background.
#[derive(Clone, Debug)]
pub enum Environment {
    /// The same radiance in every direction, W/(m²·sr) per RGB channel.
    Uniform(Vec3),
    /// A sky gradient ([`Background::Sky`]).
    Sky {
        /// Radiance straight up.
        zenith: Vec3,
        /// Radiance along the horizon.
        horizon: Vec3,
        /// Radiance below the horizon.
        ground: Vec3,
    },
    /// An equirectangular image ([`Environment::radiance`] maps directions to pixels).
    Equirect {
        /// Radiance per pixel, already multiplied by the strength.
        image: Image,
        /// The rotation about z, radians.
        turn: f32,
    },
}

impl Environment {
    /// Loads `b` (reads its image, if any).
    pub fn load(b: &Background) -> Result<Environment, RenderError> {
        Ok(match b {
            Background::Uniform(c) => Environment::Uniform(*c),
            Background::Sky { zenith, horizon, ground } => {
                Environment::Sky { zenith: *zenith, horizon: *horizon, ground: *ground }
            }
            Background::Image { path, strength, rotate_deg } => {
                let (mut image, _) = read_exr(path)?;
                image.pixels.iter_mut().for_each(|p| *p *= *strength);
                Environment::Equirect { image, turn: rotate_deg.to_radians() }
            }
        })
    }

    /// Radiance seen looking along the unit direction `d`. The image's pixel (x, y) covers
    /// azimuth φ = 2π((x + ½)/W − ½) + turn (φ = atan2(d_y, d_x)) and polar angle
    /// θ = π(y + ½)/H from +z; values between pixel centres are bilinear, wrapping in φ.
    pub fn radiance(&self, d: Vec3) -> Vec3 {
        match self {
            Environment::Uniform(c) => *c,
            Environment::Sky { zenith, horizon, ground } => match d.z {
                z if z >= 0.0 => horizon.lerp(*zenith, z.min(1.0)),
                _ => *ground,
            },
            Environment::Equirect { image, turn } => {
                let (w, h) = (image.width as usize, image.height as usize);
                let phi = d.y.atan2(d.x) - turn;
                let theta = d.z.clamp(-1.0, 1.0).acos();
                // Continuous pixel coordinates, pixel centres at integers.
                let u = ((phi / TAU + 0.5).rem_euclid(1.0)) * w as f32 - 0.5;
                let v = (theta / PI) * h as f32 - 0.5;
                let (x0, fx) = (u.floor(), u - u.floor());
                let (y0, fy) = (v.floor(), v - v.floor());
                let px = |x: f32| (x as isize).rem_euclid(w as isize) as usize;
                let py = |y: f32| (y.max(0.0) as usize).min(h - 1);
                let at = |x: f32, y: f32| image.pixels[py(y) * w + px(x)];
                let top = at(x0, y0).lerp(at(x0 + 1.0, y0), fx);
                let bottom = at(x0, y0 + 1.0).lerp(at(x0 + 1.0, y0 + 1.0), fx);
                top.lerp(bottom, fy)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 8×4 image whose pixel (x, y) holds (x, y, 1): looking at a pixel centre's direction
    /// reads that pixel exactly.
    fn ramp() -> Image {
        let mut img = Image::new(8, 4);
        for y in 0..4 {
            for x in 0..8 {
                img.pixels[y * 8 + x] = Vec3::new(x as f32, y as f32, 1.0);
            }
        }
        img
    }

    fn direction(phi: f32, theta: f32) -> Vec3 {
        Vec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos())
    }

    #[test]
    fn pixel_centres_map_to_their_directions() {
        let env = Environment::Equirect { image: ramp(), turn: 0.0 };
        for y in 0..4 {
            for x in 0..8 {
                let phi = TAU * ((x as f32 + 0.5) / 8.0 - 0.5);
                let theta = PI * (y as f32 + 0.5) / 4.0;
                let got = env.radiance(direction(phi, theta));
                assert!(
                    (got - Vec3::new(x as f32, y as f32, 1.0)).abs().max_element() < 1e-3,
                    "({x}, {y}): {got}"
                );
            }
        }
        // Halfway between two pixel centres in φ: their mean; across the seam, wrapping.
        let mid = env.radiance(direction(TAU * (4.0 / 8.0 - 0.5), PI * 1.5 / 4.0));
        assert!((mid.x - 3.5).abs() < 1e-3, "{mid}");
        let seam = env.radiance(direction(PI, PI * 1.5 / 4.0));
        assert!((seam.x - 3.5).abs() < 1e-3, "seam between x = 7 and x = 0: {seam}");
    }

    #[test]
    fn the_sky_blends_horizon_into_zenith_with_the_sine_of_the_elevation() {
        let (zenith, horizon, ground) =
            (Vec3::new(0.1, 0.2, 0.8), Vec3::new(0.9, 0.6, 0.4), Vec3::splat(0.05));
        let sky = Environment::Sky { zenith, horizon, ground };
        let close = |a: Vec3, b: Vec3| (a - b).abs().max_element() < 1e-6;
        assert!(close(sky.radiance(Vec3::Z), zenith));
        assert!(close(sky.radiance(Vec3::X), horizon));
        // 30° above the horizon: sin = ½, halfway.
        let up30 = Vec3::new(30f32.to_radians().cos(), 0.0, 0.5);
        assert!(close(sky.radiance(up30), (zenith + horizon) / 2.0), "{}", sky.radiance(up30));
        assert!(close(sky.radiance(Vec3::new(0.6, 0.0, -0.8)), ground));
        assert!(close(sky.radiance(-Vec3::Z), ground));
    }

    #[test]
    fn a_turn_moves_the_image_about_z() {
        let env = Environment::Equirect { image: ramp(), turn: TAU / 8.0 };
        // Turned by one pixel's width, pixel 4 is seen one pixel further anticlockwise.
        let phi = TAU * ((4.0 + 0.5) / 8.0 - 0.5) + TAU / 8.0;
        let got = env.radiance(direction(phi, PI * 2.5 / 4.0));
        assert!((got - Vec3::new(4.0, 2.0, 1.0)).abs().max_element() < 1e-3, "{got}");
    }

    /// Issue 29's check: the background seen through an ideal glass sphere (R = 1, n = 1.5),
    /// looking along +x. An image whose value is its column (so the value seen gives the
    /// azimuth φ of the ray that left: bilinear lookups of a linear ramp are exact) shows the
    /// ray through the centre undeviated (φ = 0) and the ray at height b bent towards the axis
    /// by D = 2(θi − θt), sin θi = b, sin θt = b/n (two refractions): φ = −D.
    #[test]
    fn a_glass_sphere_bends_the_background_by_the_refraction_closed_form() {
        use crate::render::shade::{EyeOptions, eye_path};
        use crate::sampling::halton::PhotonRng;
        use crate::scene::{Ray, Scene};
        let w = 720;
        let mut image = Image::new(w, 4);
        for (i, p) in image.pixels.iter_mut().enumerate() {
            *p = Vec3::splat((i % w as usize) as f32);
        }
        let env = Environment::Equirect { image, turn: 0.0 };
        let src = "[materials.glass]\nkind = \"dielectric\"\nior = 1.5\nideal = true\n[[shapes]]\nkind = \"sphere\"\n\
                   center = [0, 0, 0]\nradius = 1\nmaterial = \"glass\"\n[[emitters]]\nkind = \"point\"\n\
                   position = [0, 0, 9]\npower_w = 1\n";
        let scene = Scene::parse(src, "t.toml", std::path::Path::new(".")).unwrap();
        let seen_azimuth = |b: f32| {
            let mut rng = PhotonRng::new(1, 1);
            let mut hits = Vec::new();
            let ray = Ray::new(Vec3::new(-5.0, b, 0.0), Vec3::X);
            let v = eye_path(&scene, ray, &EyeOptions::default(), Some(&env), &mut rng, &mut hits);
            assert!(hits.is_empty());
            TAU * ((v.x + 0.5) / w as f32 - 0.5)
        };
        assert!(seen_azimuth(0.0).abs() < 1e-4, "through the centre: {}", seen_azimuth(0.0));
        for b in [0.3f32, 0.6] {
            let (ti, tt) = (b.asin(), (b / 1.5).asin());
            let want = -2.0 * (ti - tt);
            let got = seen_azimuth(b);
            assert!((got - want).abs() < 1e-3, "b = {b}: azimuth {got}, closed form {want}");
        }
    }
}
