//! photonkit: caustic photon maps with parameter-space relaxation constraints.
pub mod detect;
pub mod eval;
pub mod export;
pub mod format;
pub mod import;
pub mod inspect;
pub mod relax;
pub mod render;
pub mod scene;
pub mod spatial;
pub mod synthetic;
pub mod trace;

