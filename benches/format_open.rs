//! Opening a 10 M-photon PHM file and streaming every column, as a ratio to reading the same
//! bytes with a plain sequential `read` (issue 2's goal: ≤ 1.5×).
//!
//! `cargo bench --bench format_open` (set PHOTONKIT_BENCH_PHOTONS to change the size).
//! Both sides do the same work per byte (a wrapping sum of 8-byte words), with the file in the
//! page cache, alternating runs; the best of each is compared.

use std::io::Read;
use std::path::Path;
use std::time::Instant;

use photonkit::format::{Output, PhotonMap, write_map};

fn sum_words(bytes: &[u8]) -> u64 {
    let (head, words, tail) = unsafe { bytes.align_to::<u64>() };
    let mut s = words.iter().fold(0u64, |a, &w| a.wrapping_add(w));
    for &b in head.iter().chain(tail) {
        s = s.wrapping_add(b as u64);
    }
    s
}

fn plain_read(path: &Path, buf: &mut [u64]) -> u64 {
    let mut f = std::fs::File::open(path).unwrap();
    let bytes: &mut [u8] = bytemuck::cast_slice_mut(buf);
    let mut s = 0u64;
    loop {
        let n = f.read(bytes).unwrap();
        if n == 0 {
            return s;
        }
        s = s.wrapping_add(sum_words(&bytes[..n]));
    }
}

fn open_and_stream(path: &Path, verify: bool) -> u64 {
    let map = PhotonMap::open_path(path).unwrap();
    if verify {
        map.verify_checksums().unwrap();
    }
    map.columns().iter().fold(0u64, |s, (_, b)| s.wrapping_add(sum_words(b)))
}

fn main() {
    let n: usize =
        std::env::var("PHOTONKIT_BENCH_PHOTONS").ok().and_then(|s| s.parse().ok()).unwrap_or(10_000_000);
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/bench-data");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(format!("uniform-{n}.phm"));
    if PhotonMap::open_path(&path).is_err() {
        eprintln!("writing {} ({n} photons)…", path.display());
        let t = Instant::now();
        let m = photonkit::synthetic::uniform_square(n, 1, 100.0);
        let gen_s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        write_map(Output::Path(path.clone()), m.info("uniform_square", 1, "bench"), &m.columns()).unwrap();
        let w = t.elapsed().as_secs_f64();
        let bytes = std::fs::metadata(&path).unwrap().len() as f64;
        println!(
            "write: {n} photons, {:.0} MB in {w:.2} s ({:.0} MB/s, {:.1} ns/photon; generating took {gen_s:.2} s)",
            bytes / 1e6,
            bytes / 1e6 / w,
            w * 1e9 / n as f64
        );
    }
    let bytes = std::fs::metadata(&path).unwrap().len() as f64;
    let mut buf = vec![0u64; 1 << 17]; // 1 MiB
    // Warm the page cache, and check both sides see the same bytes' sum… of columns only,
    // so compare nothing here; just run each once.
    plain_read(&path, &mut buf);
    open_and_stream(&path, false);
    let (mut best_read, mut best_map, mut best_verify) = (f64::MAX, f64::MAX, f64::MAX);
    for _ in 0..5 {
        let t = Instant::now();
        std::hint::black_box(plain_read(&path, &mut buf));
        best_read = best_read.min(t.elapsed().as_secs_f64());
        let t = Instant::now();
        std::hint::black_box(open_and_stream(&path, false));
        best_map = best_map.min(t.elapsed().as_secs_f64());
        let t = Instant::now();
        std::hint::black_box(open_and_stream(&path, true));
        best_verify = best_verify.min(t.elapsed().as_secs_f64());
    }
    println!("file: {n} photons, {:.0} MB", bytes / 1e6);
    println!("plain sequential read:        {:.3} s  ({:.2} GB/s)", best_read, bytes / best_read / 1e9);
    println!(
        "open + stream every column:   {:.3} s  ({:.2} GB/s)  ratio {:.2}× (goal ≤ 1.5×)",
        best_map,
        bytes / best_map / 1e9,
        best_map / best_read
    );
    println!(
        "  … with CRC-32 verification: {:.3} s  ({:.2} GB/s)  ratio {:.2}×",
        best_verify,
        bytes / best_verify / 1e9,
        best_verify / best_read
    );
}
