//! Ray queries against a built [`Scene`], and the shortcuts they take: which shapes a
//! continuing ray can meet first ([`Reach`]), whether an emission ray can meet a specular
//! surface at all, and the convex mesh's hull. The shortcuts are worked out once, when the
//! scene is built ([`SceneDescription::build`](super::SceneDescription::build)).

use glam::Vec3;

use super::{Hit, Ray, Scene, Shape, SurfaceGeometry, bvh, hull};

/// The pad, in ray offsets, of the boxes that must be disjoint for [`Reach::MeshFirst`].
const MESH_APART_PAD: f32 = 4.0;
/// Meshes up to this size are checked for convexity ([`Scene::leaves_convex_mesh`]).
const CONVEX_CHECK_MAX_TRIANGLES: usize = 1024;

/// Which shapes a ray continuing from a surface can meet first ([`Scene::reach_after`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reach {
    /// Any: [`Scene::intersect`].
    All,
    /// A triangle if it meets one, otherwise an analytic shape: [`Scene::intersect_mesh_first`].
    MeshFirst,
    /// Analytic shapes only: [`Scene::intersect_analytic`].
    Analytic,
}

/// The shortcuts, worked out when the scene is built.
impl Scene {
    /// Whether the box around every triangle, padded by [`MESH_APART_PAD`] ray offsets, is
    /// disjoint from the box around each analytic shape (an infinite plane: the plane
    /// itself). False without triangles.
    pub(super) fn find_mesh_apart(&self) -> bool {
        let Some((lo, hi)) = self.bvh.bounds() else { return false };
        let pad = Vec3::splat(MESH_APART_PAD * self.ray_offset);
        let (lo, hi) = (lo - pad, hi + pad);
        if !(lo.is_finite() && hi.is_finite()) {
            return false;
        }
        self.analytic.iter().all(|(shape, _)| match *shape {
            Shape::Plane { point, normal } => {
                // The plane misses the box when every corner is on one side.
                let centre_side = ((lo + hi) * 0.5 - point).dot(normal);
                centre_side.abs() > ((hi - lo) * 0.5).dot(normal.abs())
            }
            _ => {
                let pts = shape.extent_points();
                let slo = pts.iter().fold(Vec3::INFINITY, |a, &p| a.min(p));
                let shi = pts.iter().fold(Vec3::NEG_INFINITY, |a, &p| a.max(p));
                slo.cmpgt(hi).any() || shi.cmplt(lo).any()
            }
        })
    }

    /// See [`Self::specular_box`]. With no specular surface the box is empty (every ray
    /// misses it).
    pub(super) fn find_specular_box(&self) -> Option<(Vec3, Vec3)> {
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for (shape, id) in &self.analytic {
            if !self.material(*id).is_specular() {
                continue;
            }
            if matches!(shape, Shape::Plane { .. }) {
                return None;
            }
            for p in shape.extent_points() {
                (lo, hi) = (lo.min(p), hi.max(p));
            }
        }
        for (tri, info) in self.triangles.iter().zip(&self.tri_info) {
            if self.material(info.surface).is_specular() {
                for &p in tri {
                    (lo, hi) = (lo.min(p), hi.max(p));
                }
            }
        }
        let pad = Vec3::splat(self.ray_offset);
        Some((lo - pad, hi + pad))
    }

    /// The scene's only mesh surface and its vertices' centroid, if the mesh is convex: each
    /// triangle has every vertex of the mesh on one side of its plane (within a few f32 ulps,
    /// far below the ray offset). Meshes of more than [`CONVEX_CHECK_MAX_TRIANGLES`]
    /// triangles are not checked (the check compares every triangle with every vertex).
    pub(super) fn find_convex_mesh(&self) -> Option<(u32, Vec3)> {
        let surface = self.tri_info.first()?.surface;
        if self.triangles.len() > CONVEX_CHECK_MAX_TRIANGLES
            || self.tri_info.iter().any(|t| t.surface != surface)
        {
            return None;
        }
        let vertices: Vec<Vec3> = self.triangles.iter().flatten().copied().collect();
        let tol = self.mesh_plane_tolerance();
        if !tol.is_finite() || 4.0 * tol >= self.ray_offset {
            return None;
        }
        for (tri, info) in self.triangles.iter().zip(&self.tri_info) {
            if info.normal == Vec3::ZERO {
                return None;
            }
            let (mut below, mut above) = (false, false);
            for v in &vertices {
                let d = (*v - tri[0]).dot(info.normal);
                below |= d < -tol;
                above |= d > tol;
                if below && above {
                    return None;
                }
            }
        }
        let centroid = vertices.iter().copied().sum::<Vec3>() / vertices.len() as f32;
        Some((surface, centroid))
    }

    /// The convex mesh's half-spaces ([`hull::Hull`]) when the mesh is closed and has no
    /// shading normals (a hit's normal is then its face's, which the planes give).
    pub(super) fn find_hull(&self) -> Option<hull::Hull> {
        self.convex_mesh?;
        if self.tri_info.iter().any(|t| t.vertex_normals.is_some()) {
            return None;
        }
        let normals: Vec<Vec3> = self.tri_info.iter().map(|t| t.normal).collect();
        hull::Hull::new(&self.triangles, &normals, self.mesh_plane_tolerance())
    }

    /// How far from a triangle's plane a vertex may lie and still count as on it: 16 f32
    /// ulps of the mesh's largest coordinate (the convexity check's and the hull's).
    fn mesh_plane_tolerance(&self) -> f32 {
        let far = self.triangles.iter().flatten().map(|v| v.abs().max_element()).fold(0.0f32, f32::max);
        16.0 * f32::EPSILON * far
    }
}

/// The queries.
impl Scene {
    /// Which shapes the ray continuing from `p` on surface `surface`, started off it along
    /// `offset_dir` (± the unit geometric normal there), can meet first:
    /// - [`Reach::Analytic`] when it [leaves the convex mesh](Scene::leaves_convex_mesh);
    /// - [`Reach::MeshFirst`] when `surface` is a mesh and no analytic shape comes near the
    ///   triangles' box: the ray starts within a ray offset of a triangle, so inside the box
    ///   padded by four ray offsets (`MESH_APART_PAD`), and the segment to any triangle it meets
    ///   stays inside that box, where no analytic shape is. So a triangle it meets is the
    ///   nearest hit, and analytic shapes need testing only when it meets none;
    /// - [`Reach::All`] otherwise.
    #[inline]
    pub fn reach_after(&self, surface: u32, p: Vec3, offset_dir: Vec3, ray: &Ray) -> Reach {
        if self.leaves_convex_mesh(surface, p, offset_dir, ray) {
            Reach::Analytic
        } else if self.mesh_apart
            && matches!(self.desc.surfaces[surface as usize].geometry, SurfaceGeometry::Mesh(_))
        {
            Reach::MeshFirst
        } else {
            Reach::All
        }
    }

    /// The nearest hit among the shapes `reach` allows (see [`Scene::reach_after`]).
    #[inline(always)]
    pub fn intersect_reach(&self, ray: &Ray, reach: Reach, t_min: f32, t_max: f32) -> Option<Hit> {
        match reach {
            Reach::All => self.intersect(ray, t_min, t_max),
            Reach::MeshFirst => self.intersect_mesh_first(ray, t_min, t_max),
            Reach::Analytic => self.intersect_analytic(ray, t_min, t_max),
        }
    }

    /// Whether the ray (from its origin on) may meet a mirror or dielectric surface: false
    /// only when it misses the box around all of them. The tracer stops a photon whose
    /// emission ray cannot meet one: its first hit is diffuse (or nothing), so it can never
    /// be a caustic photon.
    pub fn may_meet_specular(&self, ray: &Ray) -> bool {
        let Some((lo, hi)) = self.specular_box else { return true };
        if lo.cmpgt(hi).any() {
            return false; // no specular surface at all
        }
        bvh::ray_box(lo, hi, ray.origin, ray.dir.recip(), 0.0, f32::INFINITY).is_some()
    }

    /// Whether `ray`, continuing from `p` on surface `surface` and started off it along
    /// `offset_dir` (± the unit geometric normal there), can meet no triangle of the scene:
    /// the surface is the scene's convex mesh, the ray starts on the side of the hit
    /// triangle's plane away from the mesh (every vertex lies on the other side, the
    /// centroid by more than the ray offset) and does not turn back towards that plane. Then
    /// [`Scene::intersect_analytic`] finds the same hit as [`Scene::intersect`]: a ray that
    /// leaves a convex body cannot meet it again.
    pub fn leaves_convex_mesh(&self, surface: u32, p: Vec3, offset_dir: Vec3, ray: &Ray) -> bool {
        // The three tests combined with `&`, not `&&`: one branch on the result instead of
        // three (measured by benches/trace.rs).
        self.convex_mesh.is_some_and(|(s, c)| {
            (s == surface) & ((c - p).dot(offset_dir) < -self.ray_offset) & (ray.dir.dot(offset_dir) >= 0.0)
        })
    }

    /// The nearest surface the ray meets with `t` in (`t_min`, `t_max`).
    #[inline(always)]
    pub fn intersect(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<Hit> {
        let best = self.intersect_analytic(ray, t_min, t_max);
        let t_best = best.map_or(t_max, |h| h.t);
        self.intersect_mesh(ray, t_min, t_best).or(best)
    }

    /// The nearest triangle hit, else the nearest analytic one: the nearest hit of a ray
    /// that [`Reach::MeshFirst`] describes.
    #[inline(always)]
    pub fn intersect_mesh_first(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<Hit> {
        self.intersect_mesh(ray, t_min, t_max).or_else(|| self.intersect_analytic(ray, t_min, t_max))
    }

    /// The nearest hit on the mesh triangles alone: against the convex mesh's face planes
    /// when it has a [`hull::Hull`] (the same hits to rounding, without cracks at edges),
    /// otherwise through the BVH.
    #[inline(always)]
    fn intersect_mesh(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<Hit> {
        if let (Some(hull), Some((surface, _))) = (&self.hull, self.convex_mesh) {
            let (t, normal) = hull.intersect(ray, t_min, t_max, self.bvh.avx())?;
            return Some(Hit { t, normal, shading: normal, shape: surface });
        }
        let h = self.bvh.intersect(ray, t_min, t_max)?;
        let info = &self.tri_info[h.index as usize];
        let shading = match &info.vertex_normals {
            Some([n0, n1, n2]) => {
                (*n0 * (1.0 - h.b1 - h.b2) + *n1 * h.b1 + *n2 * h.b2).try_normalize().unwrap_or(info.normal)
            }
            None => info.normal,
        };
        Some(Hit { t: h.t, normal: info.normal, shading, shape: info.surface })
    }

    /// Whether surface `id` is an analytic shape (not a triangle mesh).
    #[inline(always)]
    pub fn is_analytic(&self, id: u32) -> bool {
        matches!(self.desc.surfaces[id as usize].geometry, SurfaceGeometry::Analytic(_))
    }

    /// The nearest hit of a ray that starts *exactly* on the analytic surface `leaving` (a hit
    /// point, not offset from it): a hit on `leaving` itself counts only beyond
    /// [`Self::ray_offset`] (nearer, it is the point just left), every other surface from
    /// t > 0. An offset origin would instead miss a surface closer than the offset — a glass
    /// sphere resting on the floor sends the photons that leave it near the contact point
    /// straight through the floor.
    #[inline(always)]
    pub fn intersect_leaving(&self, ray: &Ray, reach: Reach, leaving: u32, t_max: f32) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut t_best = t_max;
        if reach != Reach::Analytic {
            best = self.intersect_mesh(ray, 0.0, t_max);
            t_best = best.map_or(t_max, |h| h.t);
        }
        for (s, id) in &self.analytic {
            let t_min = if *id == leaving { self.ray_offset } else { 0.0 };
            if let Some((t, n)) = s.intersect(ray, t_min, t_best) {
                t_best = t;
                best = Some(Hit { t, normal: n, shading: n, shape: *id });
            }
        }
        best
    }

    /// The nearest hit on the analytic shapes alone (the mesh triangles skipped).
    #[inline(always)]
    pub fn intersect_analytic(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut t_best = t_max;
        for (s, id) in &self.analytic {
            if let Some((t, n)) = s.intersect(ray, t_min, t_best) {
                t_best = t;
                best = Some(Hit { t, normal: n, shading: n, shape: *id });
            }
        }
        best
    }

    /// The nearest hit by testing every shape and triangle in turn (the oracle for tests).
    pub fn intersect_brute_force(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<Hit> {
        let mut best = self.intersect_analytic(ray, t_min, t_max);
        let t_best = best.map_or(t_max, |h| h.t);
        if let Some(h) = bvh::brute_force(&self.triangles, ray, t_min, t_best) {
            let info = &self.tri_info[h.index as usize];
            best = Some(Hit { t: h.t, normal: info.normal, shading: info.normal, shape: info.surface });
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use glam::Vec3;

    use super::super::tests::{BASE, parse};
    use super::*;

    #[test]
    fn intersection_uses_the_nearest_of_shapes_and_meshes() {
        let src = format!(
            "{BASE}\n[[shapes]]\nkind = \"extrusion\"\nmaterial = \"glass\"\noutline = [[-1,-1],[1,-1],[1,1],[-1,1]]\n\
             z_range = [1, 1.5]\n\n[[shapes]]\nkind = \"sphere\"\nmaterial = \"glass\"\ncenter = [0, 0, 3]\nradius = 0.5\n"
        );
        let s = parse(&src).unwrap();
        assert_eq!(s.triangle_count(), 12);
        let down = |x: f32| Ray::new(Vec3::new(x, 0.0, 5.0), Vec3::NEG_Z);
        let h = s.intersect(&down(0.0), 1e-4, f32::INFINITY).unwrap();
        assert_eq!((h.shape, h.t), (2, 1.5)); // the sphere's top at z = 3.5
        let h = s.intersect(&down(0.9), 1e-4, f32::INFINITY).unwrap();
        assert_eq!((h.shape, h.t, h.normal), (1, 3.5, Vec3::Z)); // the slab's top at z = 1.5
        let h = s.intersect(&down(3.0), 1e-4, f32::INFINITY).unwrap();
        assert_eq!((h.shape, h.t), (0, 5.0)); // the floor
        for k in 0..100 {
            let r = Ray::new(
                Vec3::new(-2.0 + 0.04 * k as f32, 0.3, 5.0),
                Vec3::new(0.1, -0.05, -1.0).normalize(),
            );
            let (a, b) =
                (s.intersect(&r, 1e-4, f32::INFINITY), s.intersect_brute_force(&r, 1e-4, f32::INFINITY));
            assert_eq!(a.map(|h| (h.shape, h.t)), b.map(|h| (h.shape, h.t)));
        }
    }

    /// A ray `may_meet_specular` turns away never has a mirror or dielectric as its first
    /// hit (the brute-force scan says so), on sample scenes with meshes and analytic
    /// shapes; rays are turned away and let through, so the check is not vacuous. A scene
    /// without specular surfaces turns every ray away; one with an infinite mirror, none.
    #[test]
    fn rays_that_miss_the_specular_box_never_meet_a_specular_surface_first() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(12);
        for name in ["prism", "glass-sphere", "ring", "reflector", "point-glass"] {
            let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("samples/scenes/{name}.toml"));
            let scene = Scene::load(&path).unwrap();
            let (lo, hi) = scene.bounds();
            let (mut away, mut through) = (0, 0);
            for _ in 0..20_000 {
                let o = lo + (hi - lo) * Vec3::new(rng.random(), rng.random(), rng.random());
                let w = Vec3::new(
                    rng.random::<f32>() - 0.5,
                    rng.random::<f32>() - 0.5,
                    rng.random::<f32>() - 0.5,
                );
                let Some(dir) = w.try_normalize() else { continue };
                let ray = Ray::new(o, dir);
                if scene.may_meet_specular(&ray) {
                    through += 1;
                    continue;
                }
                away += 1;
                if let Some(h) = scene.intersect_brute_force(&ray, 0.0, f32::INFINITY) {
                    assert!(!scene.material(h.shape).is_specular(), "{name}: {ray:?} meets {h:?}");
                }
            }
            assert!(away > 200 && through > 200, "{name}: {away} turned away, {through} let through");
        }
        let plain = parse(BASE).unwrap();
        assert!(!plain.may_meet_specular(&Ray::new(Vec3::new(0.0, 0.0, 2.0), Vec3::NEG_Z)));
        let mirror = parse(&BASE.replace("material = \"floor\"", "material = \"glass\"")).unwrap();
        assert!(mirror.may_meet_specular(&Ray::new(Vec3::new(0.0, 0.0, 2.0), Vec3::Z)));
    }

    /// A ray leaving a random point of a random triangle of `scene` as the tracer starts one:
    /// a ray offset off it, to either side, in a random direction (grazing ones included).
    /// Returns the triangle, the point, the side (± its unit normal) and the ray.
    fn ray_leaving_a_triangle(
        scene: &Scene,
        rng: &mut rand_pcg::Pcg64Mcg,
    ) -> Option<(usize, Vec3, Vec3, Ray)> {
        use rand::RngExt;
        let k = rng.random_range(0..scene.triangles.len());
        let [a, b, c] = scene.triangles[k];
        let (mut u, mut v) = (rng.random::<f32>(), rng.random::<f32>());
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        let p = a + (b - a) * u + (c - a) * v;
        let n = scene.tri_info[k].normal;
        let side = if rng.random::<bool>() { n } else { -n };
        let w = Vec3::new(rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5);
        let tangent = (w - n * w.dot(n)).normalize_or_zero();
        let lift = if rng.random::<bool>() { rng.random::<f32>() } else { rng.random::<f32>() * 1e-3 };
        let dir = (tangent + side * lift).try_normalize()?;
        Some((k, p, side, Ray::new(p + side * scene.ray_offset(), dir)))
    }

    #[test]
    fn rays_leaving_a_convex_mesh_meet_none_of_its_triangles() {
        use rand::SeedableRng;
        let prism =
            Scene::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/scenes/prism.toml")).unwrap();
        let Some((surface, _)) = prism.convex_mesh else { panic!("the prism is convex") };
        // Not convex: an L-shaped extrusion; and a box beside a second mesh.
        let l_shape = format!(
            "{BASE}\n[[shapes]]\nkind = \"extrusion\"\nmaterial = \"glass\"\n\
             outline = [[0,0],[2,0],[2,1],[1,1],[1,2],[0,2]]\nz_range = [1, 1.5]\n"
        );
        assert!(parse(&l_shape).unwrap().convex_mesh.is_none());
        let cube =
            "[[shapes]]\nkind = \"extrusion\"\nmaterial = \"glass\"\noutline = [[0,0],[1,0],[1,1],[0,1]]\n";
        let one = format!("{BASE}\n{cube}z_range = [1, 1.5]\n");
        assert!(parse(&one).unwrap().convex_mesh.is_some());
        let two = format!("{one}\n{cube}z_range = [2, 2.5]\n");
        assert!(parse(&two).unwrap().convex_mesh.is_none());

        // Rays from random points of the prism's triangles, on either side, in random
        // directions (grazing ones included): whenever the skip applies, the full
        // intersection agrees with the analytic shapes alone and no triangle is met.
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(11);
        let mut skipped = 0;
        for _ in 0..200_000 {
            let Some((_, p, side, ray)) = ray_leaving_a_triangle(&prism, &mut rng) else { continue };
            if prism.leaves_convex_mesh(surface, p, side, &ray) {
                skipped += 1;
                assert!(bvh::brute_force(&prism.triangles, &ray, 0.0, f32::INFINITY).is_none());
                assert_eq!(
                    prism.intersect(&ray, 0.0, f32::INFINITY),
                    prism.intersect_analytic(&ray, 0.0, f32::INFINITY)
                );
            }
        }
        // About half the rays start outside.
        assert!((80_000..120_000).contains(&skipped), "{skipped}");
    }

    #[test]
    fn a_triangle_met_by_a_ray_leaving_a_mesh_apart_is_the_nearest_hit() {
        use rand::SeedableRng;
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/scenes");
        let cube = "[[shapes]]\nkind = \"extrusion\"\nmaterial = \"glass\"\noutline = [[0,0],[1,0],[1,1],[0,1]]\n\
                    z_range = [1, 1.5]\n";
        let with = |shape: &str| {
            parse(&format!("{BASE}\n{cube}\n[[shapes]]\nmaterial = \"floor\"\n{shape}\n")).unwrap()
        };
        let mut scenes: Vec<(&str, Scene)> = ["prism", "cognac", "water", "point-glass", "reflector"]
            .into_iter()
            .map(|name| (name, Scene::load(&dir.join(format!("{name}.toml"))).unwrap()))
            .collect();
        // A sphere half inside the cube: not apart.
        scenes.push(("cube and sphere", with("kind = \"sphere\"\ncenter = [0.5, 0.5, 1.5]\nradius = 0.3")));
        // The triangles themselves, as the brute force tests them: the prism's and the cube's
        // planes (`hull`, checked against the triangles in its own tests) would give the same
        // hits only to rounding, and this checks which shapes a ray is tested against.
        for (_, scene) in &mut scenes {
            scene.hull = None;
        }
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(13);
        for (name, scene) in &scenes {
            let apart = *name != "cube and sphere";
            assert_eq!(scene.mesh_apart, apart, "{name}");
            // Rays leaving random points of random triangles as the tracer starts them, to
            // either side, in random directions (grazing ones included), checked by brute force.
            let rays = (20_000_000 / scene.triangles.len()).min(20_000);
            let mut first = 0;
            for _ in 0..rays {
                let Some((k, p, side, ray)) = ray_leaving_a_triangle(scene, &mut rng) else { continue };
                let reach = scene.reach_after(scene.tri_info[k].surface, p, side, &ray);
                assert_eq!(reach == Reach::MeshFirst, apart && reach != Reach::Analytic);
                let got = scene.intersect_reach(&ray, reach, 0.0, f32::INFINITY);
                let want = scene.intersect_brute_force(&ray, 0.0, f32::INFINITY);
                assert_eq!(
                    got.map(|h| (h.t, h.normal, h.shape)),
                    want.map(|h| (h.t, h.normal, h.shape)),
                    "{name}"
                );
                first += (reach == Reach::MeshFirst) as usize;
            }
            assert!(!apart || first > rays / 3, "{name}: {first} of {rays}");
        }
        // A sphere inside the mesh's box, or a plane through it, or a floor closer than the
        // pad: not apart. The same floor far enough below: apart.
        assert!(!with("kind = \"sphere\"\ncenter = [0.5, 0.5, 1.2]\nradius = 0.1").mesh_apart);
        assert!(!with("kind = \"plane\"\npoint = [0, 0, 1.4]\nnormal = [1, 1, 1]").mesh_apart);
        let gap =
            |g: f32| format!("kind = \"plane\"\npoint = [0, 0, {}]\nnormal = [0, 0, 1]", 1.0 - g * 5e-5);
        assert_eq!(with(&gap(0.0)).ray_offset(), 5e-5, "extent 2 m");
        assert!(!with(&gap(2.0)).mesh_apart);
        assert!(with(&gap(8.0)).mesh_apart);
    }
}
