//! photonkit: caustic photon maps with parameter-space relaxation constraints.
pub mod format;
pub mod inspect;
pub mod synthetic;
