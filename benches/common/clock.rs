//! The clock speed this machine gives a single thread right now, to read a bench's times by:
//! on a shared virtual machine it varies (2.1 to 2.9 GHz seen on the same day), and a cost in
//! µs means little without it.

use std::time::Instant;

/// Billions of dependent integer additions per second on this thread: one per cycle on any
/// x86-64 of the last twenty years, so this is the clock frequency in GHz the thread ran at
/// (the best of three runs of about 40 ms, so a moment's interruption does not count).
/// `None` on other architectures, and when PHOTONKIT_BENCH_CLOCK=0 (for profilers, which
/// would count its 0.3 G additions among the bench's instructions).
pub fn ghz() -> Option<f64> {
    if std::env::var("PHOTONKIT_BENCH_CLOCK").is_ok_and(|v| v == "0") {
        return None;
    }
    #[cfg(target_arch = "x86_64")]
    {
        const ADDS: u64 = 100_000_000;
        let best = (0..3)
            .map(|_| {
                let start = Instant::now();
                let mut x = 0u64;
                for _ in 0..ADDS {
                    // SAFETY: an add on a register the asm owns; no memory, stack or flags
                    // that the compiler relies on are touched.
                    unsafe { std::arch::asm!("add {0}, 1", inout(reg) x, options(nomem, nostack)) };
                }
                assert_eq!(x, ADDS);
                start.elapsed().as_secs_f64()
            })
            .fold(f64::INFINITY, f64::min);
        Some(ADDS as f64 / best / 1e9)
    }
    #[cfg(not(target_arch = "x86_64"))]
    None
}

/// A line to print beside a bench's table: the clock, measured now.
pub fn line(when: &str) -> String {
    match ghz() {
        Some(g) => format!("clock {when}: {g:.2} GHz (dependent adds per ns, one thread)"),
        None => format!("clock {when}: not measured (PHOTONKIT_BENCH_CLOCK=0, or not x86-64)"),
    }
}
