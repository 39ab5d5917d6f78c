//! The tracer against ground truth computed from the optics alone (`photonkit::eval::truth`).

use photonkit::format::{PhotonMap, name};
use photonkit::eval::truth::SphereCaustic;

use super::common::*;

/// The default scene (glass sphere R = 0.5 m, n = 1.5, centre 0.8 m above the floor, a 10 W
/// collimated beam over 1 m²): the floor irradiance of photons refracted once in and once out
/// (two specular bounces), binned in annuli, equals the quadrature's within photon noise.
#[test]
fn the_default_scenes_caustic_matches_the_quadrature_truth() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t.phm");
    let o = photonkit(&["trace", "--photons", "400000", "-o", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let map = PhotonMap::open_path(&out).unwrap();
    let bounces = map.column::<u8>(name::BOUNCES).unwrap().unwrap();
    let edges: Vec<f64> = (0..=40).map(|i| 0.025 * i as f64).collect();
    let mut flux = vec![0.0f64; edges.len() - 1];
    let mut count = vec![0usize; edges.len() - 1];
    for ((p, f), &b) in map.positions().iter().zip(map.flux()).zip(bounces) {
        if b != 2 {
            continue;
        }
        let r = ((p[0] as f64).powi(2) + (p[1] as f64).powi(2)).sqrt();
        let bin = edges.partition_point(|&e| e <= r);
        if bin >= 1 && bin < edges.len() {
            flux[bin - 1] += f.iter().map(|&c| c as f64).sum::<f64>();
            count[bin - 1] += 1;
        }
    }
    let truth =
        SphereCaustic { radius: 0.5, centre_height: 0.8, ior: 1.5, beam_irradiance: 10.0, fresnel: true }
            .radial(&edges, 400_000);
    let mut checked = 0;
    for i in 0..flux.len() {
        let area = std::f64::consts::PI * (edges[i + 1].powi(2) - edges[i].powi(2));
        let e = flux[i] / area;
        if count[i] < 100 {
            // Too few photons to say much: at least no light where the truth has none.
            assert!(
                truth[i] > 0.0 || count[i] == 0,
                "annulus {i}: {} photons where the truth is dark",
                count[i]
            );
            continue;
        }
        // Halton emission is better than Poisson; 5 standard deviations of Poisson noise.
        let tol = 5.0 * e / (count[i] as f64).sqrt();
        assert!(
            (e - truth[i]).abs() <= tol,
            "annulus {i} ({:.3} m): traced {e:.4} W/m², truth {:.4} W/m² (±{tol:.4})",
            edges[i],
            truth[i]
        );
        checked += 1;
    }
    assert!(checked >= 10, "only {checked} annuli had enough photons");
}
