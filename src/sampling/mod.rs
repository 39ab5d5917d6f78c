//! Sampling: the low-discrepancy sequences and random streams the tracer emits photons with
//! (and the renderer draws its own samples from), each a function of an index and a seed alone.

pub mod halton;
