//! Evaluation: ground truth computed from the optics alone, error metrics, and the
//! speed–accuracy comparison of every method (issue 7).

pub mod compare;
pub mod metrics;
#[cfg(feature = "plots")]
pub mod plots;
pub mod reference;
pub mod report;
pub mod truth;
