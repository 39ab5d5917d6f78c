//! Regenerates `detect::SIMULATED`, the noise model μ(K), σ(K) of Eq. 4–6 under detection's
//! normalisation (src/detect/noise.rs explains it), and prints it as Rust to paste there.
//!
//! `cargo bench --bench mu_sigma` (PHOTONKIT_MU_SIGMA_SETS=N sets per K; default 200 000).
//! It also prints the paper's check (Fig. 7a: K = 100 uniform in a disc, normalised by the
//! disc's radius²: mean 0.2219, sd 0.0188) and the farthest-point normalisation beside it.

use photonkit::detect::{in_disc, lambda2_of, simulate};
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

const KS: &[u32] = &[
    3, 4, 5, 6, 7, 8, 9, 10, 12, 14, 16, 20, 24, 28, 32, 40, 50, 64, 80, 100, 128, 160, 200, 256, 320, 400,
    512, 640, 800, 1000,
];

fn main() {
    let sets: usize =
        std::env::var("PHOTONKIT_MU_SIGMA_SETS").ok().and_then(|s| s.parse().ok()).unwrap_or(200_000);
    let t = std::time::Instant::now();
    // Split each K's sets over 8 seeded streams so the table is reproducible on any core count.
    let rows: Vec<(u32, f64, f64)> = KS
        .par_iter()
        .map(|&k| {
            let parts: Vec<(f64, f64)> = (0..8u64)
                .into_par_iter()
                .map(|s| {
                    let mut rng = Pcg64Mcg::seed_from_u64(1000 * k as u64 + s);
                    simulate(k as usize, sets / 8, &mut rng)
                })
                .collect();
            // Pool the streams' means and variances (equal sizes).
            let mean = parts.iter().map(|p| p.0).sum::<f64>() / parts.len() as f64;
            let var =
                parts.iter().map(|p| p.1 * p.1 + (p.0 - mean).powi(2)).sum::<f64>() / parts.len() as f64;
            (k, mean, var.sqrt())
        })
        .collect();
    println!("pub const SIMULATED: &[Row] = &[");
    for (k, m, s) in &rows {
        println!("    ({k}, {m:.6}, {s:.6}),");
    }
    println!("];");
    // The paper's check, and the farthest-point normalisation.
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    let (mut disc, mut far) = (Vec::new(), Vec::new());
    let mut pts = Vec::with_capacity(100);
    for _ in 0..100_000 {
        pts.clear();
        pts.extend((0..100).map(|_| in_disc(&mut rng)));
        let l = lambda2_of(&pts);
        let r2 = pts.iter().map(|p| p[0] * p[0] + p[1] * p[1]).fold(0.0, f64::max);
        disc.push(l);
        far.push(l / r2);
    }
    let stats = |v: &[f64]| {
        let m = v.iter().sum::<f64>() / v.len() as f64;
        (m, (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt())
    };
    let (dm, ds) = stats(&disc);
    let (fm, fs) = stats(&far);
    eprintln!(
        "K = 100 uniform in the unit disc, 100 000 sets: by disc radius² mean {dm:.4} sd {ds:.4}; by farthest point mean {fm:.4} sd {fs:.4}"
    );
    eprintln!("{sets} sets per K, {:.1} s", t.elapsed().as_secs_f64());
}
