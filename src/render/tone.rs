//! Tone mapping of the PNG preview (the EXR stays linear and untouched).
//!
//! 1. **Exposure**: by default automatic, from the image's own luminance: the log-average
//!    luminance of its lit pixels (Reinhard et al. 2002's "key") is exposed to mid-grey,
//!    [`MID_GREY`]. Lit means brighter than 10⁻⁴ of the 99th percentile, so a black surround
//!    does not darken the caustic; a log-average is not dragged far by a few pixels of a focus
//!    a thousand times brighter than the rest.
//!    A stop offset is added on request (`--exposure`).
//! 2. **Shoulder**: highlights are compressed by an extended Reinhard curve
//!    f(x) = x·(1 + x/W²)/(1 + x) ([`shoulder`]), slope 1 at black, reaching 1 at the white
//!    point W = [`WHITE`], about 90 times mid-grey: the caustic's bright lines keep their
//!    gradation instead of flattening to white. It is applied to each pixel's **largest channel** and the pixel scaled by
//!    f(m)/m, so every channel stays within [0, 1] and the ratios between channels, hence hue
//!    and saturation, are kept exactly: a saturated spectrum keeps its green instead of
//!    clipping channel by channel to yellow and white.
//! 3. The sRGB transfer curve ([`super::image::srgb8`]).

use glam::Vec3;

use super::image::Image;

/// Rec. 709 luminance weights of linear sRGB ([`crate::scene::material::LUMA`]).
const LUMA: Vec3 = {
    let w = crate::scene::material::LUMA;
    Vec3::new(w[0] as f32, w[1] as f32, w[2] as f32)
};

/// The exposed value of the lit pixels' log-average luminance.
pub const MID_GREY: f32 = 0.18;

/// The shoulder's white point: an exposed value this large maps to 1.
pub const WHITE: f32 = 16.0;

/// The automatic exposure in stops: log2([`MID_GREY`] / log-average luminance of the lit
/// pixels among those metered ([`Image::metered`]); 0 for an image without light.
pub fn auto_exposure(img: &Image) -> f32 {
    let metered = |i: usize| img.metered.as_ref().is_none_or(|m| m[i]);
    let mut luma: Vec<f32> = img
        .pixels
        .iter()
        .enumerate()
        .filter(|&(i, _)| metered(i))
        .map(|(_, p)| p.dot(LUMA))
        .filter(|l| l.is_finite() && *l > 0.0)
        .collect();
    if luma.is_empty() {
        return 0.0;
    }
    let at = ((luma.len() - 1) as f64 * 0.99).round() as usize;
    let p99 = *luma.select_nth_unstable_by(at, f32::total_cmp).1;
    let floor = p99 * 1e-4;
    let (sum, n) = luma
        .iter()
        .filter(|&&l| l >= floor)
        .fold((0.0f64, 0usize), |(s, n), &l| (s + (l as f64).ln(), n + 1));
    let log_average = (sum / n.max(1) as f64).exp();
    (MID_GREY as f64 / log_average).log2() as f32
}

/// The highlight shoulder, extended Reinhard: f(x) = x·(1 + x/W²)/(1 + x) for x ≥ 0, W =
/// [`WHITE`]; increasing, f(0) = 0, f'(0) = 1, f(W) = 1; 1 above W.
pub fn shoulder(x: f32) -> f32 {
    if x.is_nan() || x <= 0.0 {
        return 0.0;
    }
    if x >= WHITE {
        return 1.0;
    }
    x * (1.0 + x / (WHITE * WHITE)) / (1.0 + x)
}

/// Pixel `c` (linear) multiplied by `scale` and mapped through the shoulder by its largest
/// channel: every channel in [0, 1], the channels' ratios kept.
pub fn tone_map(c: Vec3, scale: f32) -> Vec3 {
    let c = (c * scale).max(Vec3::ZERO);
    let m = c.max_element();
    if !(m > 0.0 && m.is_finite()) {
        return Vec3::ZERO;
    }
    c * (shoulder(m) / m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::image::srgb8;

    #[test]
    fn the_shoulder_rises_from_black_to_white() {
        assert_eq!(shoulder(0.0), 0.0);
        assert_eq!(shoulder(-1.0), 0.0);
        assert_eq!(shoulder(f32::NAN), 0.0);
        assert!((shoulder(WHITE) - 1.0).abs() < 1e-6);
        assert_eq!(shoulder(1e30), 1.0);
        // Slope 1 at black: dark values pass nearly unchanged.
        assert!((shoulder(1e-3) / 1e-3 - 1.0).abs() < 2e-3);
        let mut last = 0.0;
        for i in 1..=20_000 {
            let y = shoulder(i as f32 * WHITE / 10_000.0);
            assert!(y >= last && y <= 1.0, "at step {i}: {y} after {last}");
            last = y;
        }
    }

    /// Hue is kept: saturated primaries and a bright spectral green keep their channel ratios
    /// (and so their hue) however bright, where clipping each channel at 1 turns a bright green
    /// with some red into yellow.
    #[test]
    fn tone_mapping_keeps_the_ratios_of_channels() {
        for c in [
            Vec3::new(40.0, 0.0, 0.0),
            Vec3::new(0.0, 40.0, 0.0),
            Vec3::new(0.0, 0.0, 40.0),
            Vec3::new(3.0, 9.0, 0.5),
            Vec3::new(0.02, 0.05, 0.01),
        ] {
            for scale in [0.1, 1.0, 10.0, 1000.0] {
                let t = tone_map(c, scale);
                assert!(t.max_element() <= 1.0 && t.min_element() >= 0.0, "{c} × {scale}: {t}");
                let k = t.max_element() / (c * scale).max_element();
                assert!((t - c * scale * k).abs().max_element() < 1e-6, "{c} × {scale}: {t}");
            }
        }
        // The green of a spectrum at 30× its exposure: tone-mapped it stays green-dominant with
        // red at a third; clipped per channel it would read (255, 255, 20), yellow.
        let g = Vec3::new(10.0, 30.0, 0.5);
        let clipped = g.to_array().map(srgb8);
        assert_eq!(clipped[0], clipped[1]);
        let t = tone_map(g, 1.0);
        assert!((t.x / t.y - 1.0 / 3.0).abs() < 1e-6 && t.y > 0.9, "{t}");
    }

    fn uniform(w: u32, h: u32, v: Vec3) -> Image {
        Image { width: w, height: h, pixels: vec![v; (w * h) as usize], metered: None, samples: None }
    }

    /// Mid-grey is where documented: a uniform image is exposed to 0.18, which the shoulder
    /// maps to 0.18·(1 + 0.18/W²)/1.18 and the sRGB curve to code 109. The exposure follows the
    /// image's scale (ten times brighter, log2 10 stops less), ignores a black surround and
    /// a few very bright pixels, and is 0 for a black image.
    #[test]
    fn automatic_exposure_puts_the_lit_log_average_at_mid_grey() {
        let img = uniform(8, 8, Vec3::splat(3.0));
        let e = auto_exposure(&img);
        assert!((e - (0.18f32 / 3.0).log2()).abs() < 1e-5, "{e}");
        let t = tone_map(img.pixels[0], e.exp2());
        assert!((t.x - 0.18 * (1.0 + 0.18 / (WHITE * WHITE)) / 1.18).abs() < 1e-6, "{t}");
        assert_eq!(srgb8(t.x), 109);
        let brighter = uniform(8, 8, Vec3::splat(30.0));
        assert!((auto_exposure(&brighter) - (e - 10f32.log2())).abs() < 1e-5);
        // Half the image black, and one pixel in 128 a focus 10⁴ times brighter.
        let mut img = uniform(16, 16, Vec3::ZERO);
        for (i, p) in img.pixels.iter_mut().enumerate() {
            if i % 2 == 0 {
                *p = Vec3::splat(3.0);
            }
            if i % 128 == 0 {
                *p = Vec3::splat(3e4);
            }
        }
        let mixed = auto_exposure(&img);
        // Lit: 126 pixels at 3 and 2 at 3·10⁴: log-average 3·10^(4·2/128).
        let want = (0.18f64 / (3.0 * 10f64.powf(4.0 * 2.0 / 128.0))).log2() as f32;
        assert!((mixed - want).abs() < 1e-4, "{mixed} against {want}");
        assert_eq!(auto_exposure(&uniform(4, 4, Vec3::ZERO)), 0.0);
    }
}
