//! What keeps a command from damaging the user's files.
//!
//! - Every input a command opens is registered here, and no output may replace one: outputs are
//!   compared with inputs by device and inode, so `x`, `./x`, a symlink to `x` and a hard link
//!   all count as the same file ([`check_output`], called when an output's temporary file is
//!   created, i.e. before any work is written).
//! - Every temporary file an output is written to is registered, and SIGINT, SIGTERM and SIGHUP
//!   remove the ones still pending before the process exits with 128 + the signal number
//!   ([`install_signal_handlers`]). Only SIGKILL (or a power cut) can leave one behind: they
//!   are named `.<stage>-XXXXXX.tmp` beside the target.
//! - A memory-mapped input that another process truncates raises SIGBUS on the next read of a
//!   vanished page; the handler names the mapped inputs instead of dying without a word.

use std::ffi::CString;
use std::os::unix::ffi::OsStrExt;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicPtr, AtomicUsize, Ordering};

struct Input {
    /// Which registration this is (an inode number alone may be a deleted input's, reused).
    id: u64,
    dev: u64,
    ino: u64,
    path: PathBuf,
}

static NEXT_ID: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

static INPUTS: Mutex<Vec<Input>> = Mutex::new(Vec::new());
/// Temporary files not yet renamed into place, as C strings so a signal handler can unlink them.
static PENDING: Mutex<Vec<CString>> = Mutex::new(Vec::new());
/// The SIGBUS message (leaked, rebuilt when a mapped input is registered) and its length.
static BUS_MESSAGE: AtomicPtr<u8> = AtomicPtr::new(std::ptr::null_mut());
static BUS_MESSAGE_LEN: AtomicUsize = AtomicUsize::new(0);
static MAPPED: Mutex<Vec<String>> = Mutex::new(Vec::new());

/// Records `path` as an input for the rest of the process (files read whole: scenes, OBJ,
/// imported files). A path that cannot be read is ignored here: opening it reports the error.
pub fn register_input(path: &Path) {
    std::mem::forget(hold_input(path));
}

/// An input registered while this value lives (a memory-mapped photon map holds one).
#[derive(Debug)]
pub struct InputHold {
    id: u64,
}

impl Drop for InputHold {
    fn drop(&mut self) {
        let mut inputs = INPUTS.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(k) = inputs.iter().position(|i| i.id == self.id) {
            inputs.swap_remove(k);
        }
    }
}

/// Records `path` as an input until the returned hold is dropped.
pub fn hold_input(path: &Path) -> Option<InputHold> {
    let m = std::fs::metadata(path).ok()?;
    let id = NEXT_ID.fetch_add(1, Ordering::Relaxed);
    INPUTS.lock().unwrap_or_else(|e| e.into_inner()).push(Input {
        id,
        dev: m.dev(),
        ino: m.ino(),
        path: path.to_path_buf(),
    });
    Some(InputHold { id })
}

/// Records `path` as a memory-mapped input until the hold is dropped; a SIGBUS (the file was
/// truncated underneath) is then reported by name.
pub fn hold_mapped_input(path: &Path) -> Option<InputHold> {
    let hold = hold_input(path);
    let mut mapped = MAPPED.lock().unwrap_or_else(|e| e.into_inner());
    mapped.push(path.display().to_string());
    let message = format!(
        "photonkit: error: a memory-mapped input changed underneath this command (truncated or \
         rewritten by another process while being read): {}\n",
        mapped.join(", ")
    );
    let leaked: &'static mut [u8] = Box::leak(message.into_bytes().into_boxed_slice());
    BUS_MESSAGE_LEN.store(0, Ordering::SeqCst);
    BUS_MESSAGE.store(leaked.as_mut_ptr(), Ordering::SeqCst);
    BUS_MESSAGE_LEN.store(leaked.len(), Ordering::SeqCst);
    hold
}

/// Refuses an output that is one of this command's inputs (same device and inode).
pub fn check_output(path: &Path) -> std::io::Result<()> {
    let Ok(m) = std::fs::metadata(path) else { return Ok(()) };
    let inputs = INPUTS.lock().unwrap_or_else(|e| e.into_inner());
    // An input deleted since it was read may have passed its inode on to a new file: a match
    // counts only while the input's own path still names that inode.
    let same = |i: &&Input| {
        i.dev == m.dev()
            && i.ino == m.ino()
            && std::fs::metadata(&i.path).is_ok_and(|now| now.dev() == i.dev && now.ino() == i.ino)
    };
    if let Some(i) = inputs.iter().find(same) {
        return Err(std::io::Error::new(
            std::io::ErrorKind::AlreadyExists,
            format!(
                "refusing to overwrite {}: it is the input {} of this command (write to another file)",
                path.display(),
                i.path.display()
            ),
        ));
    }
    Ok(())
}

/// Records a temporary file that an interrupt must remove.
pub fn register_temp(path: &Path) {
    if let Ok(c) = CString::new(path.as_os_str().as_bytes()) {
        PENDING.lock().unwrap_or_else(|e| e.into_inner()).push(c);
    }
}

/// Forgets a temporary file that was renamed into place or removed.
pub fn forget_temp(path: &Path) {
    let bytes = path.as_os_str().as_bytes();
    PENDING.lock().unwrap_or_else(|e| e.into_inner()).retain(|c| c.as_bytes() != bytes);
}

/// Removes every pending temporary file; returns how many were removed.
fn remove_pending() -> usize {
    let Ok(pending) = PENDING.try_lock() else { return 0 };
    // SAFETY: unlink of a valid NUL-terminated path; async-signal-safe, no allocation here.
    pending.iter().filter(|c| unsafe { libc::unlink(c.as_ptr()) } == 0).count()
}

/// Installs the handlers for SIGINT, SIGTERM, SIGHUP (remove pending temporary files, exit
/// 128 + signal) and SIGBUS (name the mapped inputs, remove pending files, exit 74). Call once,
/// first thing in `main`.
pub fn install_signal_handlers() -> std::io::Result<()> {
    use signal_hook::consts::{SIGBUS, SIGHUP, SIGINT, SIGTERM};
    let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP])?;
    std::thread::Builder::new().name("signals".into()).spawn(move || {
        if let Some(sig) = signals.forever().next() {
            let removed = remove_pending();
            let name = match sig {
                SIGINT => "SIGINT",
                SIGTERM => "SIGTERM",
                _ => "SIGHUP",
            };
            eprintln!("\nphotonkit: interrupted by {name}; removed {removed} unfinished output file(s)");
            std::process::exit(128 + sig);
        }
    })?;
    // SAFETY: the handler only reads atomics, writes a prebuilt buffer and unlinks prebuilt
    // paths (async-signal-safe calls), then exits without returning to the faulting access.
    unsafe {
        signal_hook::low_level::register(SIGBUS, || {
            let len = BUS_MESSAGE_LEN.load(Ordering::SeqCst);
            let ptr = BUS_MESSAGE.load(Ordering::SeqCst);
            if len > 0 && !ptr.is_null() {
                libc::write(2, ptr.cast(), len);
            } else {
                let m = b"photonkit: error: bus error (a memory-mapped file changed underneath)\n";
                libc::write(2, m.as_ptr().cast(), m.len());
            }
            remove_pending();
            libc::_exit(74);
        })?;
    }
    Ok(())
}

/// A pause a test can ask for (hidden environment variables `PHOTONKIT_TEST_PAUSE_<what>`, in
/// milliseconds), to send a signal or truncate an input at a known moment.
pub fn test_pause(what: &str) {
    if let Ok(ms) = std::env::var(format!("PHOTONKIT_TEST_PAUSE_{what}"))
        && let Ok(ms) = ms.parse::<u64>()
    {
        eprintln!("photonkit: test pause {what}");
        std::thread::sleep(std::time::Duration::from_millis(ms));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_input_is_refused_as_output_under_any_name() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("x.phm");
        std::fs::write(&input, b"photons").unwrap();
        let other = dir.path().join("y.phm");
        std::fs::write(&other, b"other").unwrap();
        let hold = hold_input(&input);
        assert!(check_output(&input).is_err());
        let dotted = dir.path().join(".").join("x.phm");
        assert!(check_output(&dotted).is_err());
        let link = dir.path().join("link.phm");
        std::os::unix::fs::symlink(&input, &link).unwrap();
        assert!(check_output(&link).is_err());
        let hard = dir.path().join("hard.phm");
        std::fs::hard_link(&input, &hard).unwrap();
        assert!(check_output(&hard).is_err());
        assert!(check_output(&other).is_ok());
        assert!(check_output(&dir.path().join("new.phm")).is_ok());
        drop(hold);
        assert!(check_output(&input).is_ok(), "released with its hold");
        // Once the input is gone, a new file that inherits its inode is not mistaken for it.
        let gone = dir.path().join("gone.phm");
        std::fs::write(&gone, b"read earlier").unwrap();
        register_input(&gone);
        std::fs::remove_file(&gone).unwrap();
        let reborn = dir.path().join("reborn.phm");
        std::fs::write(&reborn, b"new").unwrap();
        assert!(check_output(&reborn).is_ok());
    }

    #[test]
    fn pending_temporary_files_are_registered_and_forgotten() {
        let dir = tempfile::tempdir().unwrap();
        let a = dir.path().join("a.tmp");
        let b = dir.path().join("b.tmp");
        register_temp(&a);
        register_temp(&b);
        forget_temp(&b);
        let pending = PENDING.lock().unwrap();
        let has = |p: &Path| pending.iter().any(|c| c.as_bytes() == p.as_os_str().as_bytes());
        assert!(has(&a) && !has(&b));
    }
}
