//! Synthetic photon maps with known structure, for tests, samples and benchmarks.
//!
//! They stand in for traced photons: each generator maps seeded random trajectory parameters
//! through a closed-form "optical" map onto the floor plane z = 0, so the caustic structure
//! (folds, overlapping filaments) is known exactly.

use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

use crate::format::{ColumnSpec, Emitter, EmitterKind, MapInfo, Parameterisation, StageRecord, State, name};

/// Photons held as columns in memory, ready for [`crate::format::write_map`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SyntheticMap {
    /// Where each photon lies, metres.
    pub position: Vec<[f32; 3]>,
    /// The unit surface normal there.
    pub normal: Vec<[f32; 3]>,
    /// RGB flux, watts.
    pub flux: Vec<[f32; 3]>,
    /// Unit direction of travel when it arrived.
    pub incident: Vec<[f32; 3]>,
    /// Index of its emitter in [`Self::emitters`].
    pub emitter: Vec<u16>,
    /// Trajectory parameters, `param_dims` per photon.
    pub params: Vec<f32>,
    /// Components of `params` per photon.
    pub param_dims: u32,
    /// Length of the path from the emitter, metres.
    pub path_length: Vec<f32>,
    /// Specular interactions on the path.
    pub bounces: Vec<u8>,
    /// The photon's number in the emission sequence.
    pub emission_index: Vec<u64>,
    /// The emitters, as the map's metadata lists them.
    pub emitters: Vec<Emitter>,
}

impl SyntheticMap {
    /// Number of photons.
    pub fn len(&self) -> usize {
        self.position.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.position.is_empty()
    }

    /// The columns a tracer would write (emitter column only when there are several emitters).
    pub fn columns(&self) -> Vec<(ColumnSpec, &[u8])> {
        let mut c: Vec<(ColumnSpec, &[u8])> = vec![
            (ColumnSpec::of::<[f32; 3]>(name::POSITION), bytemuck::cast_slice(&self.position)),
            (ColumnSpec::of::<[f32; 3]>(name::NORMAL), bytemuck::cast_slice(&self.normal)),
            (ColumnSpec::of::<[f32; 3]>(name::FLUX), bytemuck::cast_slice(&self.flux)),
            (ColumnSpec::of::<[f32; 3]>(name::INCIDENT), bytemuck::cast_slice(&self.incident)),
        ];
        if self.emitters.len() > 1 {
            c.push((ColumnSpec::of::<u16>(name::EMITTER), bytemuck::cast_slice(&self.emitter)));
        }
        if self.param_dims > 0 {
            let spec = ColumnSpec::new(name::PARAMS, crate::format::DType::F32, self.param_dims);
            c.push((spec, bytemuck::cast_slice(&self.params)));
        }
        c.push((ColumnSpec::of::<f32>(name::PATH_LENGTH), bytemuck::cast_slice(&self.path_length)));
        c.push((ColumnSpec::of::<u8>(name::BOUNCES), bytemuck::cast_slice(&self.bounces)));
        c.push((ColumnSpec::of::<u64>(name::EMISSION_INDEX), bytemuck::cast_slice(&self.emission_index)));
        c
    }

    /// Writes these photons to `path` as a PHM file and opens it (for tests).
    #[cfg(test)]
    pub fn written_to(&self, path: &std::path::Path) -> crate::format::PhotonMap {
        let info = self.info("test", 0, "2026-11-23T00:00:00Z");
        crate::format::write_map(crate::format::Output::Path(path.to_path_buf()), info, &self.columns())
            .unwrap();
        crate::format::PhotonMap::open_path(path).unwrap()
    }

    /// Metadata for the map, with a history entry stamped at `time` (fixed for reproducible files).
    pub fn info(&self, generator: &str, seed: u64, time: &str) -> MapInfo {
        let mut info = MapInfo::new(self.emitters.clone(), State::Traced);
        let mut rec =
            StageRecord::now("synthetic", serde_json::json!({ "generator": generator, "seed": seed }));
        rec.time = time.to_string();
        info.history.push(rec);
        info
    }

    fn push(
        &mut self,
        pos: [f32; 3],
        flux: [f32; 3],
        incident: [f32; 3],
        emitter: u16,
        params: &[f32],
        path: f32,
    ) {
        self.emission_index.push(self.position.len() as u64);
        self.position.push(pos);
        self.normal.push([0.0, 0.0, 1.0]);
        self.flux.push(flux);
        self.incident.push(incident);
        self.emitter.push(emitter);
        self.params.extend_from_slice(params);
        self.params.extend(std::iter::repeat_n(0.0, self.param_dims as usize - params.len()));
        self.path_length.push(path);
        self.bounces.push(1);
    }
}

/// A collimated emitter 1 m × 1 m, 2 m above the floor, `power_w` watts of white light.
pub fn collimated_emitter(id: u32, power_w: f64) -> Emitter {
    Emitter {
        id,
        kind: EmitterKind::Collimated,
        parameterisation: Parameterisation::RectUv,
        param_dims: 2,
        power_w,
        colour: [1.0, 1.0, 1.0],
        param_measure: Some(1.0),
        geometry: serde_json::json!({ "origin": [-0.5, -0.5, 2.0], "edge_u": [1.0, 0.0, 0.0],
                                      "edge_v": [0.0, 1.0, 0.0], "direction": [0.0, 0.0, -1.0] }),
        dimensions: Vec::new(),
        extra: Default::default(),
    }
}

/// An isotropic point emitter 1 m above the floor.
pub fn point_emitter(id: u32, power_w: f64) -> Emitter {
    Emitter {
        id,
        kind: EmitterKind::Point,
        parameterisation: Parameterisation::Direction,
        param_dims: 3,
        power_w,
        colour: [1.0, 0.9, 0.7],
        param_measure: Some(4.0 * std::f64::consts::PI),
        geometry: serde_json::json!({ "position": [0.0, 0.0, 1.0] }),
        dimensions: Vec::new(),
        extra: Default::default(),
    }
}

/// Floor position of a collimated photon leaving the emitter at (u, v) through a cylindrical
/// "lens": x folds over itself where 0.6 − 0.5π·cos(2π(u − ½)) < 0, making two fold caustics
/// with three overlapping filaments between them; y passes straight through.
pub fn cusp_map(u: f64, v: f64) -> [f64; 2] {
    let s = u - 0.5;
    [0.6 * s - 0.25 * (2.0 * std::f64::consts::PI * s).sin(), v - 0.5]
}

/// `n` photons from one collimated emitter through [`cusp_map`].
pub fn collimated_cusp(n: usize, seed: u64) -> SyntheticMap {
    let mut m =
        SyntheticMap { param_dims: 2, emitters: vec![collimated_emitter(0, 10.0)], ..Default::default() };
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let f = (10.0 / 3.0 / n.max(1) as f64) as f32;
    for _ in 0..n {
        let (u, v) = (rng.random::<f64>(), rng.random::<f64>());
        let [x, y] = cusp_map(u, v);
        m.push([x as f32, y as f32, 0.0], [f; 3], [0.0, 0.0, -1.0], 0, &[u as f32, v as f32], 2.0);
    }
    m
}

/// `n` photons of a collimated beam dispersed as by a prism (format 1.1's `rect_uv_spectral`):
/// (u, v) uniform on the emitter, the wavelength λ uniform on 380–720 nm, landing at
/// x = 0.1·u + 0.4·t, y = 0.02·v with t = (λ − 380)/340: the spectrum spreads the beam over
/// 0.4 m along x, each photon's flux that of its wavelength's colour.
pub fn dispersed_beam(n: usize, seed: u64) -> SyntheticMap {
    spectral_beam(n, seed, |u, v, rng| {
        let t = rng.random::<f32>();
        ([0.1 * u + 0.4 * t, 0.02 * v, 0.0], 380.0 + 340.0 * t)
    })
}

/// `n` photons of a collimated beam whose optics focus each of two wavelengths, 450 and 650 nm
/// (alternately), onto its own line through the origin (format 1.1's `rect_uv_spectral`):
/// (u, v) uniform on the emitter, landing at s·(0, 1) for 450 nm and s·(1, 0) for
/// 650 nm, s = 0.3·(u − ½), whatever v. The two filaments cross at the origin, where photons of
/// both wavelengths left the same part of the emitter (u near ½).
pub fn two_wavelength_lines(n: usize, seed: u64) -> SyntheticMap {
    let mut k = 0;
    spectral_beam(n, seed, move |u, _, _| {
        k += 1;
        let s = 0.3 * (u - 0.5);
        if k % 2 == 0 { ([0.0, s, 0.0], 450.0) } else { ([s, 0.0, 0.0], 650.0) }
    })
}

/// `n` photons of one `rect_uv_spectral` emitter of 10 W: (u, v) uniform, and `land(u, v, rng)`
/// their landing point and wavelength (nm), each photon's flux that of its wavelength's colour.
fn spectral_beam(
    n: usize,
    seed: u64,
    mut land: impl FnMut(f32, f32, &mut Pcg64Mcg) -> ([f32; 3], f32),
) -> SyntheticMap {
    let mut e = collimated_emitter(0, 10.0);
    e.parameterisation = Parameterisation::RectUvSpectral;
    e.param_dims = 3;
    e.dimensions = Parameterisation::RectUvSpectral.dimensions();
    let mut m = SyntheticMap { param_dims: 3, emitters: vec![e], ..Default::default() };
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let per = 10.0 / 3.0 / n.max(1) as f64;
    for _ in 0..n {
        let (u, v) = (rng.random::<f32>(), rng.random::<f32>());
        let (x, l) = land(u, v, &mut rng);
        let flux = crate::scene::material::wavelength_rgb(l).to_array().map(|c| (per * c as f64) as f32);
        m.push(x, flux, [0.0, 0.0, -1.0], 0, &[u, v, l], 2.0);
    }
    m
}

/// `n` photons from a point emitter whose lower hemisphere is focused into a ring of radius
/// 0.3 m on the floor (as by a ring lens): direction parameters on the sphere, positions on a
/// thin annulus with a sharp inner edge.
pub fn point_ring(n: usize, seed: u64) -> SyntheticMap {
    let mut m = SyntheticMap { param_dims: 3, emitters: vec![point_emitter(0, 5.0)], ..Default::default() };
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let e = m.emitters[0].colour;
    let total: f32 = e.iter().sum();
    let per = 5.0 / n.max(1) as f64;
    for _ in 0..n {
        let (d, pos) = ring_photon(&mut rng);
        let flux = e.map(|c| (per * (c / total) as f64) as f32);
        m.push(pos, flux, incident_from([0.0, 0.0, 1.0], pos), 0, &d, 1.2);
    }
    m
}

fn ring_photon(rng: &mut Pcg64Mcg) -> ([f32; 3], [f32; 3]) {
    // Uniform direction on the lower hemisphere.
    let z = -rng.random::<f64>();
    let phi = 2.0 * std::f64::consts::PI * rng.random::<f64>();
    let s = (1.0 - z * z).sqrt();
    let d = [s * phi.cos(), s * phi.sin(), z];
    // The ring lens sends polar angle θ to radius 0.3 + 0.1·(1 − cos θ)² : sharp inner edge.
    let r = 0.3 + 0.1 * (1.0 + z) * (1.0 + z);
    let pos = [(r * phi.cos()) as f32, (r * phi.sin()) as f32, 0.0];
    (d.map(|c| c as f32), pos)
}

fn incident_from(src: [f32; 3], to: [f32; 3]) -> [f32; 3] {
    let d = [to[0] - src[0], to[1] - src[1], to[2] - src[2]];
    let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    d.map(|c| c / l)
}

/// Both emitters at once: a collimated cusp and a point ring, 3 parameter components
/// (the collimated photons leave the third at zero).
pub fn two_emitters(n: usize, seed: u64) -> SyntheticMap {
    let mut m = SyntheticMap {
        param_dims: 3,
        emitters: vec![collimated_emitter(0, 10.0), point_emitter(1, 5.0)],
        ..Default::default()
    };
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let per = (15.0 / n.max(1) as f64) as f32;
    for _ in 0..n {
        // Emitters are chosen in proportion to power.
        if rng.random::<f64>() < 10.0 / 15.0 {
            let (u, v) = (rng.random::<f64>(), rng.random::<f64>());
            let [x, y] = cusp_map(u, v);
            m.push(
                [x as f32, y as f32, 0.0],
                [per / 3.0; 3],
                [0.0, 0.0, -1.0],
                0,
                &[u as f32, v as f32],
                2.0,
            );
        } else {
            let (d, pos) = ring_photon(&mut rng);
            let c = m.emitters[1].colour;
            let t: f32 = c.iter().sum();
            m.push(pos, c.map(|k| per * k / t), incident_from([0.0, 0.0, 1.0], pos), 1, &d, 1.2);
        }
    }
    m
}

/// Uniform random photons on the unit square of the floor, `total_w` watts in all, with
/// collimated (u, v) parameters equal to their position: the blue-noise test bed.
pub fn uniform_square(n: usize, seed: u64, total_w: f64) -> SyntheticMap {
    let mut m =
        SyntheticMap { param_dims: 2, emitters: vec![collimated_emitter(0, total_w)], ..Default::default() };
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let f = (total_w / 3.0 / n.max(1) as f64) as f32;
    for _ in 0..n {
        let (u, v) = (rng.random::<f32>(), rng.random::<f32>());
        m.push([u, v, 0.0], [f; 3], [0.0, 0.0, -1.0], 0, &[u, v], 2.0);
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cusp_map_folds_where_its_derivative_changes_sign() {
        // dx/du = 0.6 − 0.5π cos(2π s): negative at s = 0, positive at s = ±0.5.
        let h = 1e-6;
        let d = |u: f64| (cusp_map(u + h, 0.0)[0] - cusp_map(u - h, 0.0)[0]) / (2.0 * h);
        assert!(d(0.5) < 0.0);
        assert!(d(0.01) > 0.0 && d(0.99) > 0.0);
    }

    #[test]
    fn generators_conserve_emitted_power() {
        for m in [collimated_cusp(1000, 1), point_ring(1000, 2), two_emitters(1000, 3)] {
            let total: f64 = m.flux.iter().flatten().map(|&f| f as f64).sum();
            let power: f64 = m.emitters.iter().map(|e| e.power_w).sum();
            assert!((total - power).abs() / power < 0.05, "{total} vs {power}");
            assert_eq!(m.params.len(), m.len() * m.param_dims as usize);
        }
    }

    #[test]
    fn ring_directions_are_unit_vectors() {
        let m = point_ring(200, 9);
        for d in m.params.chunks(3) {
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            assert!((n - 1.0).abs() < 1e-5);
        }
    }
}
