//! Diagnostic views (the paper's Fig. 6 e–g): photons drawn as dots on the surfaces they lie
//! on, coloured by their trajectory parameters, by path length, or red where constrained.
//!
//! Each pixel sample looks (through the camera and any specular surfaces) at a diffuse point
//! and takes the colour of the nearest photon if it lies within the dot radius: a fixed
//! radius, or by default 0.4 × the local photon spacing sqrt(π r₈² / 8) (r₈ the distance to
//! the 8th nearest photon), so dots keep their relative size at any density, capped at four
//! typical dots so an isolated photon does not become a disc. Elsewhere the image is black.

use glam::Vec3;

use super::{PhotonLookup, RenderError, Scratch};
use crate::format::{DType, MapView, name};

/// Which property colours the photons.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Diagnostic {
    /// Trajectory parameters: (u, v) → (u, v, 1 − (u + v)/2), a direction ω → (ω + 1)/2,
    /// each component first normalised to [0, 1] over the map (Fig. 6e).
    Params,
    /// Path length from the emitter, min to max over the map on a blue–green–yellow–red ramp
    /// (Fig. 6f).
    PathLength,
    /// Red where the constraint factor |basis_v| is below the threshold, grey elsewhere
    /// (Fig. 6g).
    Constrained,
    /// Every photon white: where the photons are.
    Splat,
}

impl Diagnostic {
    /// The view's name on the command line (`--diagnostic`) and in image headers.
    pub fn name(self) -> &'static str {
        match self {
            Diagnostic::Params => "params",
            Diagnostic::PathLength => "path-length",
            Diagnostic::Constrained => "constrained",
            Diagnostic::Splat => "splat",
        }
    }
}

/// Neighbours used to measure the local photon spacing.
const SPACING_K: usize = 8;
/// Dot radius in units of the local photon spacing.
const DOT: f32 = 0.4;

/// A colour per photon and the dot size.
#[derive(Clone, Debug, PartialEq)]
pub struct Diagnostics {
    /// Colour of photon i (linear RGB).
    pub colours: Vec<Vec3>,
    /// Dot radius, metres; `None` for 0.4 × the local spacing.
    pub dot_radius: Option<f32>,
    /// Largest dot radius with the local spacing, metres ([`Self::bounded`]): an isolated
    /// photon, whose local spacing is the distance to photons far away, stays a dot.
    pub max_dot: Option<f32>,
}

/// The largest dot, in typical dots: [`Diagnostics::bounded`].
const MAX_DOT: f32 = 4.0;

/// Photons whose spacing is sampled for [`Diagnostics::bounded`].
const SPACING_SAMPLE: usize = 4096;

impl Diagnostics {
    /// Colours the photons of `map` by `which`; `threshold` is the constraint factor below
    /// which a photon counts as constrained.
    pub fn from_map(
        map: &MapView,
        which: Diagnostic,
        threshold: f32,
        dot_radius: Option<f32>,
    ) -> Result<Diagnostics, RenderError> {
        let file = map.file_name();
        let missing = |column: &str, hint: &str| {
            RenderError::Invalid(format!(
                "{file}: the map has no '{column}' column, which --diagnostic {} needs{hint}",
                which.name()
            ))
        };
        let n = map.len();
        let colours = match which {
            Diagnostic::Splat => vec![Vec3::ONE; n],
            Diagnostic::PathLength => {
                let len =
                    map.column::<f32>(name::PATH_LENGTH)?.ok_or_else(|| missing(name::PATH_LENGTH, ""))?;
                let (lo, hi) = range(len.iter().copied());
                len.iter().map(|&l| ramp((l - lo) / (hi - lo).max(f32::MIN_POSITIVE))).collect()
            }
            Diagnostic::Constrained => {
                let v = map
                    .column::<[f32; 3]>(name::BASIS_V)?
                    .ok_or_else(|| missing(name::BASIS_V, " (run `photonkit detect` first)"))?;
                v.iter()
                    .map(
                        |b| {
                            if Vec3::from_array(*b).length() < threshold { Vec3::X } else { Vec3::splat(0.6) }
                        },
                    )
                    .collect()
            }
            Diagnostic::Params => {
                let entry = map
                    .spec(name::PARAMS)
                    .ok_or_else(|| missing(name::PARAMS, " (trajectory parameters)"))?;
                let stride = entry.components as usize;
                if entry.dtype != DType::F32 || stride == 0 {
                    return Err(RenderError::Invalid(format!("{file}: the params column is not f32")));
                }
                let bytes = map.column_bytes(name::PARAMS).expect("listed column");
                let values: &[f32] = bytemuck::try_cast_slice(bytes)
                    .map_err(|e| RenderError::Invalid(format!("{file}: params column: {e}")))?;
                let dims = stride.min(3);
                let ranges: Vec<(f32, f32)> =
                    (0..dims).map(|c| range(values.chunks_exact(stride).map(|p| p[c]))).collect();
                values
                    .chunks_exact(stride)
                    .map(|p| {
                        let c: Vec<f32> = (0..dims)
                            .map(|d| {
                                (p[d] - ranges[d].0) / (ranges[d].1 - ranges[d].0).max(f32::MIN_POSITIVE)
                            })
                            .collect();
                        match dims {
                            1 => ramp(c[0]),
                            2 => Vec3::new(c[0], c[1], 1.0 - 0.5 * (c[0] + c[1])),
                            _ => Vec3::new(c[0], c[1], c[2]),
                        }
                    })
                    .collect()
            }
        };
        Ok(Diagnostics { colours, dot_radius, max_dot: None })
    }

    /// Caps the dots sized by the local spacing at four times the typical dot, 0.4 × the
    /// median, over up to 4096 photons spread through the map, of each one's own spacing.
    pub fn bounded(mut self, photons: &PhotonLookup) -> Self {
        let positions = photons.data.positions;
        let step = positions.len().div_ceil(SPACING_SAMPLE).max(1);
        let mut s = Scratch::default();
        let mut spacing: Vec<f32> = positions
            .iter()
            .step_by(step)
            .filter_map(|&x| {
                // The photon itself and its SPACING_K neighbours.
                photons.nearest(Vec3::from(x), SPACING_K + 1, f32::INFINITY, &mut s.nb);
                let last = s.nb.last()?;
                let k = s.nb.len().saturating_sub(1).max(1) as f32;
                Some((std::f32::consts::PI * last.dist2 / k).sqrt()).filter(|d| d.is_finite() && *d > 0.0)
            })
            .collect();
        if !spacing.is_empty() {
            let mid = spacing.len() / 2;
            let median = *spacing.select_nth_unstable_by(mid, f32::total_cmp).1;
            self.max_dot = Some(MAX_DOT * DOT * median);
        }
        self
    }

    /// The colour at `p`: the nearest photon's if it lies within the dot radius, else black.
    pub fn colour(&self, photons: &PhotonLookup, p: Vec3, s: &mut Scratch) -> Vec3 {
        let k = if self.dot_radius.is_some() { 1 } else { SPACING_K };
        let nb = &mut s.nb;
        photons.nearest(p, k, f32::INFINITY, nb);
        let (Some(first), Some(last)) = (nb.as_slice().first(), nb.last()) else { return Vec3::ZERO };
        let r2 = match self.dot_radius {
            Some(r) => r * r,
            // Spacing² = π r_k² / k; the dot radius is DOT times the spacing.
            None => {
                let r2 = DOT * DOT * std::f32::consts::PI * last.dist2 / nb.len() as f32;
                self.max_dot.map_or(r2, |m| r2.min(m * m))
            }
        };
        if first.dist2 <= r2 { self.colours[first.index as usize] } else { Vec3::ZERO }
    }
}

/// (min, max) of the finite values, (0, 1) if there are none.
fn range(values: impl Iterator<Item = f32>) -> (f32, f32) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
    if lo <= hi { (lo, hi) } else { (0.0, 1.0) }
}

/// t ∈ [0, 1] on a dark-blue, blue, green, yellow, red ramp.
pub fn ramp(t: f32) -> Vec3 {
    const STOPS: [[f32; 3]; 5] =
        [[0.05, 0.05, 0.4], [0.1, 0.4, 1.0], [0.2, 0.9, 0.3], [1.0, 0.9, 0.1], [0.9, 0.1, 0.05]];
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) } * (STOPS.len() - 1) as f32;
    let i = (t as usize).min(STOPS.len() - 2);
    let f = t - i as f32;
    Vec3::from_array(STOPS[i]).lerp(Vec3::from_array(STOPS[i + 1]), f)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::PhotonData;

    #[test]
    fn ramp_end_points_and_monotone_red() {
        assert_eq!(ramp(0.0), Vec3::new(0.05, 0.05, 0.4));
        assert_eq!(ramp(1.0), Vec3::new(0.9, 0.1, 0.05));
        assert_eq!(ramp(2.0), ramp(1.0));
        assert_eq!(ramp(f32::NAN), ramp(0.0));
    }

    #[test]
    fn dots_take_the_nearest_photons_colour_within_their_radius() {
        // A 10 × 10 grid of photons 0.1 m apart: the spacing is 0.1 and dots have radius ≈ 0.04.
        let pos: Vec<[f32; 3]> =
            (0..100).map(|i| [(i % 10) as f32 * 0.1, (i / 10) as f32 * 0.1, 0.0]).collect();
        let flux = vec![[1.0; 3]; 100];
        let l = PhotonLookup::new("t", PhotonData { positions: &pos, flux: &flux, normals: None }).unwrap();
        let d = Diagnostics {
            colours: (0..100).map(|i| Vec3::splat(i as f32)).collect(),
            dot_radius: None,
            max_dot: None,
        };
        let mut s = Scratch::default();
        assert_eq!(d.colour(&l, Vec3::new(0.51, 0.3, 0.0), &mut s), Vec3::splat(35.0));
        assert_eq!(d.colour(&l, Vec3::new(0.55, 0.35, 0.0), &mut s), Vec3::ZERO);
        let fixed = Diagnostics { dot_radius: Some(0.08), ..d };
        assert_eq!(fixed.colour(&l, Vec3::new(0.55, 0.35, 0.0), &mut s), Vec3::splat(35.0));
    }

    /// Issue 29: a photon 10 m from a 10 × 10 grid of photons 0.1 m apart has a local spacing
    /// of metres, and drew a disc of that size; bounded, its dot is at most 4 typical dots
    /// (4 × 0.4 × 0.1 m spacing, measured at the photons: the grid's own median).
    #[test]
    fn an_isolated_photon_stays_a_dot() {
        let mut pos: Vec<[f32; 3]> =
            (0..100).map(|i| [(i % 10) as f32 * 0.1, (i / 10) as f32 * 0.1, 0.0]).collect();
        pos.push([10.0, 0.0, 0.0]);
        let flux = vec![[1.0; 3]; pos.len()];
        let l = PhotonLookup::new("t", PhotonData { positions: &pos, flux: &flux, normals: None }).unwrap();
        let colours: Vec<Vec3> = (0..pos.len()).map(|i| Vec3::splat(i as f32 + 1.0)).collect();
        let free = Diagnostics { colours, dot_radius: None, max_dot: None };
        let mut s = Scratch::default();
        let far = Vec3::new(10.5, 0.0, 0.0);
        assert_eq!(free.colour(&l, far, &mut s), Vec3::splat(101.0), "unbounded: a disc metres wide");
        let bounded = free.bounded(&l);
        let m = bounded.max_dot.unwrap();
        // The grid's spacing at its photons: sqrt(π r₈²/8) with r₈ between 0.1·√2 and 0.2.
        assert!(m > 4.0 * 0.4 * 0.08 && m < 4.0 * 0.4 * 0.2, "{m}");
        assert_eq!(bounded.colour(&l, far, &mut s), Vec3::ZERO);
        assert_eq!(bounded.colour(&l, Vec3::new(10.0 + 0.5 * m, 0.0, 0.0), &mut s), Vec3::splat(101.0));
        // Inside the grid nothing changes.
        assert_eq!(bounded.colour(&l, Vec3::new(0.51, 0.3, 0.0), &mut s), Vec3::splat(36.0));
    }
}

#[cfg(test)]
mod map_tests {
    use super::*;
    use crate::format::{ColumnSpec, Output, PhotonMap, State, write_map};

    /// A map of `uniform_square` photons with a basis_v column whose length is i/n for photon i.
    fn map_with_basis(n: usize) -> (tempfile::TempDir, PhotonMap, crate::synthetic::SyntheticMap) {
        let m = crate::synthetic::uniform_square(n, 5, 1.0);
        let basis: Vec<[f32; 3]> = (0..n).map(|i| [0.0, i as f32 / n as f32, 0.0]).collect();
        let mut cols = m.columns();
        cols.push((ColumnSpec::of::<[f32; 3]>(name::BASIS_V), bytemuck::cast_slice(&basis)));
        let mut info = m.info("test", 0, "2026-01-01T00:00:00Z");
        info.state = State::Detected;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.phm");
        write_map(Output::Path(path.clone()), info, &cols).unwrap();
        let map = PhotonMap::open_path(&path).unwrap();
        (dir, map, m)
    }

    #[test]
    fn photons_are_coloured_by_their_columns() {
        let (_dir, map, m) = map_with_basis(1000);
        // Constrained: red below the threshold (|basis_v| = i/n < 0.3), grey above.
        let d = Diagnostics::from_map(&map.view(), Diagnostic::Constrained, 0.3, None).unwrap();
        for (i, c) in d.colours.iter().enumerate() {
            assert_eq!(*c == Vec3::X, (i as f32 / 1000.0) < 0.3, "photon {i}: {c}");
        }
        // Params: (u, v) normalised over the map to (u', v', 1 − (u' + v')/2).
        let d = Diagnostics::from_map(&map.view(), Diagnostic::Params, 0.5, None).unwrap();
        let (lo, hi) = range(m.params.chunks(2).map(|p| p[0]));
        for (c, p) in d.colours.iter().zip(m.params.chunks(2)) {
            let u = (p[0] - lo) / (hi - lo);
            assert!((c.x - u).abs() < 1e-5 && (c.z - (1.0 - 0.5 * (c.x + c.y))).abs() < 1e-6);
        }
        // Path length: constant here, so every photon takes the ramp's first colour.
        let d = Diagnostics::from_map(&map.view(), Diagnostic::PathLength, 0.5, None).unwrap();
        assert!(d.colours.iter().all(|c| *c == ramp(0.0)));
    }
}
