//! Acceleration structures for the rays the tracer and the renderer cast into a scene: the
//! bounding volume hierarchy over every mesh triangle, and the half-spaces of a closed convex
//! mesh. They know rays and triangles, not shapes or materials ([`crate::scene`] uses them).

pub mod bvh;
pub(crate) mod hull;
