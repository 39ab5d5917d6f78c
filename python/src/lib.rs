//! photonkit for Python: PHM photon maps as numpy arrays that view the memory map, and every
//! stage of the pipeline as a call.
//!
//! This crate is the extension module `photonkit._photonkit`; the package `photonkit`
//! (python/photonkit/) re-exports it and carries the type stubs. Every stage runs with the
//! interpreter released ([`run`]), so Python threads go on meanwhile; a library error becomes a
//! Python exception carrying the command line's message ([`errors`]), and a panic becomes a
//! [`PhotonkitError`] instead of unwinding into the interpreter.

use pyo3::prelude::*;

mod errors;
mod map;
mod options;
mod render;
mod stages;

pub use errors::PhotonkitError;

/// Runs `work` with the interpreter released (other Python threads run meanwhile) on `threads`
/// worker threads (default: rayon's, all cores or RAYON_NUM_THREADS). A panic anywhere in it,
/// in a worker thread too (rayon carries it to the caller), comes back as an error.
pub(crate) fn run<T, F>(py: Python<'_>, threads: Option<usize>, work: F) -> PyResult<T>
where
    T: Send,
    F: FnOnce() -> Result<T, errors::Failure> + Send,
{
    let outcome = py.detach(|| {
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| match threads {
            Some(0) => Err(errors::Failure::value("threads needs at least 1".into())),
            Some(n) => rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|e| errors::Failure::runtime(format!("starting the worker threads: {e}")))?
                .install(work),
            None => work(),
        }))
    });
    match outcome {
        Ok(result) => result.map_err(PyErr::from),
        Err(panic) => Err(errors::from_panic(panic)),
    }
}

/// The extension module: the map type, `open` and `write`, the stages, and the exception.
#[pymodule]
fn _photonkit(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("PhotonkitError", m.py().get_type::<PhotonkitError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<map::PhotonMap>()?;
    m.add_function(wrap_pyfunction!(map::open, m)?)?;
    m.add_function(wrap_pyfunction!(map::write, m)?)?;
    m.add_function(wrap_pyfunction!(stages::trace, m)?)?;
    m.add_function(wrap_pyfunction!(stages::detect, m)?)?;
    m.add_function(wrap_pyfunction!(stages::relax, m)?)?;
    m.add_function(wrap_pyfunction!(stages::collapse, m)?)?;
    m.add_function(wrap_pyfunction!(stages::pipeline, m)?)?;
    m.add_function(wrap_pyfunction!(render::render, m)?)?;
    m.add_function(wrap_pyfunction!(render::compare, m)?)?;
    Ok(())
}
