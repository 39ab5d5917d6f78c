//! photonkit: caustic photon maps with parameter-space relaxation constraints (Spencer &
//! Jones, "Photon Parameterisation for Robust Relaxation Constraints").
//!
//! The pipeline, one module per stage, every stage reading and writing PHM files ([`format`](mod@format)):
//!
//! 1. [`trace`]: photons from the emitters of a [`scene`] through mirrors and glass to diffuse
//!    surfaces, each keeping its primal trajectory parameters ((u, v) on a collimated
//!    emitter, the emission direction for a point emitter).
//! 2. [`detect`]: parameter-space density (Eq. 1), the Kc nearest neighbours restricted in
//!    parameter space ([`spatial`]), tangent-plane PCA and the constraint basis (Eq. 2–7).
//! 3. [`relax`]: repulsion over Kf neighbours projected on each basis (Eq. 8–9); collapse
//!    drops the parameter dimensions; relax again in world space.
//! 4. [`render`]: eye rays to diffuse hits, k-NN density estimation, OpenEXR and PNG.
//!
//! [`pipeline`] runs stages 2–3 in memory, one map handed to the next.
//!
//! Around it: [`import`] and [`export`] (PLY, CSV, Radiance), [`inspect`], and [`eval`]
//! (ground truth, error metrics and the comparison of every method); beneath the scene,
//! [`accel`] (the BVH and convex hulls that rays are cast against); [`sampling`] (the
//! Halton emission sequence and per-photon random streams); and [`tiles`] (a map cut into
//! spatial tiles with halos, processed tile by tile with the whole map's result).
#![warn(missing_docs)]
pub mod accel;
pub mod detect;
pub mod eval;
pub mod export;
pub mod format;
pub mod import;
pub mod inspect;
pub mod pipeline;
pub mod refine;
pub mod relax;
pub mod render;
pub mod sampling;
pub mod scene;
pub mod spatial;
pub mod synthetic;
pub mod tiles;
pub mod trace;
