//! Library errors as Python exceptions, with the command line's messages.
//!
//! A bad argument raises `ValueError`, a file that cannot be read or written `OSError` (its
//! subclass for the cause: `FileNotFoundError`, `PermissionError`, `FileExistsError`), and
//! everything else — a corrupt or unsuitable photon map, a scene file with an error, a stage
//! that cannot go on — [`PhotonkitError`], a `RuntimeError`. The message is what `photonkit`
//! prints after `photonkit: error: ` for the same failure.

use std::error::Error;
use std::io::ErrorKind;

use photonkit::detect::DetectError;
use photonkit::eval::compare::CompareError;
use photonkit::format::FormatError;
use photonkit::pipeline::PipelineError;
use photonkit::relax::RelaxError;
use photonkit::render::RenderError;
use photonkit::scene::SceneError;
use photonkit::trace::TraceError;
use pyo3::exceptions::{PyFileExistsError, PyFileNotFoundError, PyOSError, PyPermissionError, PyValueError};
use pyo3::prelude::*;

pyo3::create_exception!(
    photonkit,
    PhotonkitError,
    pyo3::exceptions::PyRuntimeError,
    "A photonkit stage failed: a corrupt or unsuitable photon map, a scene file with an error, \
     or a run that cannot go on. The message is the command line's."
);

/// Which Python exception a failure raises.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    Runtime,
    Value,
    Os(ErrorKind),
}

/// A failure on its way to Python: the exception's type and message.
#[derive(Debug)]
pub struct Failure {
    pub kind: Kind,
    pub message: String,
}

impl Failure {
    pub fn runtime(message: String) -> Failure {
        Failure { kind: Kind::Runtime, message }
    }

    pub fn value(message: String) -> Failure {
        Failure { kind: Kind::Value, message }
    }

    /// `e` as the command line words it: its message, then each cause the message does not
    /// already quote (as `photonkit`'s `main` does).
    fn described(kind: Kind, e: &dyn Error) -> Failure {
        let mut message = e.to_string();
        let mut cause = e.source();
        while let Some(c) = cause {
            let text = c.to_string();
            if !message.contains(&text) {
                message.push_str(": ");
                message.push_str(&text);
            }
            cause = c.source();
        }
        Failure { kind, message }
    }
}

impl From<Failure> for PyErr {
    fn from(f: Failure) -> PyErr {
        match f.kind {
            Kind::Runtime => PhotonkitError::new_err(f.message),
            Kind::Value => PyValueError::new_err(f.message),
            Kind::Os(ErrorKind::NotFound) => PyFileNotFoundError::new_err(f.message),
            Kind::Os(ErrorKind::PermissionDenied) => PyPermissionError::new_err(f.message),
            Kind::Os(ErrorKind::AlreadyExists) => PyFileExistsError::new_err(f.message),
            Kind::Os(_) => PyOSError::new_err(f.message),
        }
    }
}

/// A panic's payload as a [`PhotonkitError`]: a bug in photonkit, reported and survived.
pub fn from_panic(payload: Box<dyn std::any::Any + Send>) -> PyErr {
    let what = payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown cause".into());
    PhotonkitError::new_err(format!("internal error (a bug in photonkit; please report it): {what}"))
}

/// The exception kind of an I/O error.
fn os(e: &std::io::Error) -> Kind {
    Kind::Os(e.kind())
}

impl From<FormatError> for Failure {
    fn from(e: FormatError) -> Failure {
        let kind = match &e {
            FormatError::Io { source, .. } => os(source),
            _ => Kind::Runtime,
        };
        Failure::described(kind, &e)
    }
}

impl From<SceneError> for Failure {
    fn from(e: SceneError) -> Failure {
        let kind = match &e {
            SceneError::Io { source, .. } => os(source),
            SceneError::NotFound { .. } => Kind::Os(ErrorKind::NotFound),
            _ => Kind::Runtime,
        };
        Failure::described(kind, &e)
    }
}

impl From<TraceError> for Failure {
    fn from(e: TraceError) -> Failure {
        let kind = match e {
            TraceError::Format(e) => return e.into(),
            TraceError::BadShard { .. } | TraceError::StoredWithShard => Kind::Value,
            TraceError::Spool { ref source, .. } => os(source),
            _ => Kind::Runtime,
        };
        Failure::described(kind, &e)
    }
}

impl From<photonkit::tiles::BudgetTooSmall> for Failure {
    fn from(e: photonkit::tiles::BudgetTooSmall) -> Self {
        Failure::value(format!(
            "memory={}: {} photons need at least {} bytes (what the map needs per photon, one tile, and the {} bytes \
             the process holds already)",
            e.budget, e.photons, e.need, e.held
        ))
    }
}

impl From<DetectError> for Failure {
    fn from(e: DetectError) -> Failure {
        let kind = match e {
            DetectError::Format(e) => return e.into(),
            DetectError::Parameter(_) => Kind::Value,
            _ => Kind::Runtime,
        };
        Failure::described(kind, &e)
    }
}

impl From<RelaxError> for Failure {
    fn from(e: RelaxError) -> Failure {
        match e {
            RelaxError::Format(e) => e.into(),
            e => Failure::described(Kind::Runtime, &e),
        }
    }
}

impl From<PipelineError> for Failure {
    fn from(e: PipelineError) -> Failure {
        match e {
            PipelineError::Detect(e) => e.into(),
            PipelineError::Relax(e) => e.into(),
            PipelineError::Format(e) => e.into(),
            e => Failure::described(Kind::Runtime, &e),
        }
    }
}

impl From<RenderError> for Failure {
    fn from(e: RenderError) -> Failure {
        let kind = match e {
            RenderError::Format(e) => return e.into(),
            RenderError::Scene(e) => return e.into(),
            RenderError::Io { ref source, .. } => os(source),
            RenderError::Invalid(_) | RenderError::Budget { .. } => Kind::Value,
            _ => Kind::Runtime,
        };
        Failure::described(kind, &e)
    }
}

impl From<CompareError> for Failure {
    fn from(e: CompareError) -> Failure {
        let kind = match e {
            CompareError::Format(e) => return e.into(),
            CompareError::Trace(e) => return e.into(),
            CompareError::Detect(e) => return e.into(),
            CompareError::Relax(e) => return e.into(),
            CompareError::Pipeline(e) => return e.into(),
            CompareError::Render(e) => return e.into(),
            CompareError::Io { ref source, .. } => os(source),
            CompareError::Invalid(_) => Kind::Value,
            _ => Kind::Runtime,
        };
        Failure::described(kind, &e)
    }
}

impl From<std::io::Error> for Failure {
    fn from(e: std::io::Error) -> Failure {
        Failure::described(os(&e), &e)
    }
}
