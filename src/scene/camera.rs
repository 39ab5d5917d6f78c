//! The scene's camera: a pinhole looking at a point with a vertical field of view, or an
//! orthographic view of a given height. The tracer does not use it; the renderer does.

use glam::Vec3;

use super::shape::Ray;

/// A view of the scene: where it looks from, how it projects, and the image size.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    /// Pinhole or orthographic.
    pub projection: Projection,
    /// The eye (pinhole) or the centre of the rectangle rays start from (orthographic), metres.
    pub eye: Vec3,
    /// Unit viewing direction (towards `look_at`).
    pub forward: Vec3,
    /// Unit vector along the image's rows, to the right.
    pub right: Vec3,
    /// Unit vector along the image's columns, up; with `right`, spans the image plane.
    pub up: Vec3,
    /// Image size in pixels (width, height).
    pub resolution: [u32; 2],
}

/// How the camera projects the scene onto the image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Projection {
    /// A pinhole camera: rays fan out from the eye.
    Pinhole {
        /// Vertical field of view, radians.
        fov_y_rad: f32,
    },
    /// Parallel rays along the viewing direction, from a rectangle centred on the eye.
    Orthographic {
        /// Height of the view, metres.
        height_m: f32,
    },
}

impl Camera {
    /// A camera at `eye` looking at `look_at` with `up` roughly up; `None` if they are degenerate.
    pub fn look_at(
        projection: Projection,
        eye: Vec3,
        look_at: Vec3,
        up: Vec3,
        resolution: [u32; 2],
    ) -> Option<Self> {
        let forward = (look_at - eye).try_normalize()?;
        let right = forward.cross(up).try_normalize()?;
        let up = right.cross(forward);
        Some(Camera { projection, eye, forward, right, up, resolution })
    }

    /// The camera of the scene scaled by `f` > 0 about the origin: the eye moves, the view
    /// directions stay, an orthographic view's height scales.
    pub fn scaled(&self, f: f32) -> Camera {
        let projection = match self.projection {
            Projection::Orthographic { height_m } => Projection::Orthographic { height_m: height_m * f },
            p => p,
        };
        Camera { projection, eye: self.eye * f, ..self.clone() }
    }

    /// The ray through image position (x, y) in pixels, (0, 0) the top-left corner.
    pub fn ray(&self, x: f32, y: f32) -> Ray {
        let [w, h] = self.resolution.map(|r| r as f32);
        // Image-plane coordinates in units of half the view height.
        let sx = (2.0 * x - w) / h;
        let sy = (h - 2.0 * y) / h;
        match self.projection {
            Projection::Pinhole { fov_y_rad } => {
                let k = (0.5 * fov_y_rad).tan();
                Ray::new(self.eye, (self.forward + self.right * (sx * k) + self.up * (sy * k)).normalize())
            }
            Projection::Orthographic { height_m } => {
                let o = self.eye + (self.right * sx + self.up * sy) * (0.5 * height_m);
                Ray::new(o, self.forward)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pinhole_centre_looks_at_target_and_edges_span_the_fov() {
        let c = Camera::look_at(
            Projection::Pinhole { fov_y_rad: 60f32.to_radians() },
            Vec3::new(0.0, -5.0, 1.0),
            Vec3::new(0.0, 0.0, 1.0),
            Vec3::Z,
            [800, 600],
        )
        .unwrap();
        assert!((c.ray(400.0, 300.0).dir - Vec3::Y).length() < 1e-6);
        // Top edge centre: 30° above the axis.
        let top = c.ray(400.0, 0.0).dir;
        assert!((top.dot(Vec3::Y).acos().to_degrees() - 30.0).abs() < 1e-3 && top.z > 0.0);
        assert!(c.ray(800.0, 300.0).dir.x > 0.0, "image right is world +x here");
        assert!(
            Camera::look_at(Projection::Pinhole { fov_y_rad: 1.0 }, Vec3::ZERO, Vec3::Z, Vec3::Z, [1, 1])
                .is_none()
        );
    }

    #[test]
    fn orthographic_rays_are_parallel_and_span_the_height() {
        let c = Camera::look_at(
            Projection::Orthographic { height_m: 2.0 },
            Vec3::new(0.0, 0.0, 5.0),
            Vec3::ZERO,
            Vec3::Y,
            [100, 100],
        )
        .unwrap();
        let (a, b) = (c.ray(50.0, 0.0), c.ray(50.0, 100.0));
        assert_eq!(a.dir, b.dir);
        assert!(((a.origin - b.origin).length() - 2.0).abs() < 1e-6);
    }
}
