//! Exact point-to-surface distances: the closest point on a triangle against a dense search,
//! the bounding-volume hierarchy against brute force on the spot mesh, and the
//! point-to-surface Chamfer distance without the sampling floor of the point-to-point one.

use std::path::PathBuf;

use glam::{DQuat, DVec2, DVec3, EulerRot};
use w3d_core::{Mesh, load_mesh};
use w3d_eval::{
    EvalOptions, MAX_SAMPLES, MeshDistance, SurfaceComparison, closest_point_on_triangle, evaluate, sample_surface,
    surface_chamfer,
};
use w3d_remesh::icosphere;

/// SplitMix64: a small seeded generator for the test inputs.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    /// A uniform value in `[-s, s)`.
    fn signed(&mut self, s: f64) -> f64 {
        s * (2.0 * self.next() - 1.0)
    }

    /// A point with f32-representable coordinates in `[-s, s)³` (mesh positions are f32).
    fn point(&mut self, s: f64) -> DVec3 {
        DVec3::new(self.signed(s), self.signed(s), self.signed(s)).as_vec3().as_dvec3()
    }
}

/// The repository's spot mesh, normalised into the unit cube.
fn spot() -> Mesh {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets/spot.obj");
    let mut mesh = load_mesh(path).unwrap();
    mesh.normalize_unit_cube();
    mesh
}

fn segment_distance(p: DVec3, a: DVec3, b: DVec3) -> f64 {
    let ab = b - a;
    let s = if ab.length_squared() > 0.0 { ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
    p.distance(a + ab * s)
}

/// The distance from `p` to triangle `(a, b, c)` the slow, obvious way: the nearer of the
/// three edges and, when the projection of `p` onto the plane falls inside, the plane.
fn reference_distance(p: DVec3, [a, b, c]: [DVec3; 3]) -> f64 {
    let edges = segment_distance(p, a, b).min(segment_distance(p, b, c)).min(segment_distance(p, c, a));
    let n = (b - a).cross(c - a);
    if n.length_squared() == 0.0 {
        return edges;
    }
    let q = p - n * (n.dot(p - a) / n.length_squared());
    let inside = [(a, b), (b, c), (c, a)].iter().all(|&(u, v)| n.dot((v - u).cross(q - u)) >= 0.0);
    if inside { edges.min(p.distance(q)) } else { edges }
}

/// The smallest distance from `p` to the points `a + i/n·(b − a) + j/n·(c − a)`, `i + j ≤ n`.
fn dense_distance(p: DVec3, [a, b, c]: [DVec3; 3], n: u32) -> f64 {
    let mut best = f64::INFINITY;
    for i in 0..=n {
        for j in 0..=n - i {
            let x = a + (b - a) * (f64::from(i) / f64::from(n)) + (c - a) * (f64::from(j) / f64::from(n));
            best = best.min(p.distance(x));
        }
    }
    best
}

#[test]
fn closest_point_on_a_triangle_matches_a_dense_search_also_for_degenerate_triangles() {
    let mut rng = Rng(11);
    let mut kinds = [0usize; 6];
    for case in 0..600 {
        let (a, b) = (rng.point(1.0), rng.point(1.0));
        let kind = case % 6;
        kinds[kind] += 1;
        let c = match kind {
            // Ordinary triangles of any shape.
            0 | 1 => rng.point(1.0),
            // Two coincident corners (a segment).
            2 => a,
            // Three coincident corners (a point), as a triangle `(a, a, a)`.
            3 => a,
            // Collinear corners, rounded to f32 (zero area up to that rounding), the third
            // corner between or beyond the others.
            4 => (a + (b - a) * rng.signed(2.0)).as_vec3().as_dvec3(),
            // A needle: the third corner within 1e-6 of the first.
            _ => (a + DVec3::new(rng.signed(1e-6), rng.signed(1e-6), rng.signed(1e-6))).as_vec3().as_dvec3(),
        };
        let tri = if kind == 3 { [a, a, a] } else { [a, b, c] };
        for k in 0..8 {
            // Points near and far, some in the plane of the triangle.
            let mut p = rng.point(if k % 2 == 0 { 0.5 } else { 3.0 });
            if k == 7 {
                let n = (tri[1] - tri[0]).cross(tri[2] - tri[0]);
                if n.length_squared() > 0.0 {
                    p -= n * (n.dot(p - tri[0]) / n.length_squared());
                }
            }
            let q = closest_point_on_triangle(p, tri);
            let d = p.distance(q);
            let reference = reference_distance(p, tri);
            assert!((d - reference).abs() <= 1e-9, "case {case} kind {kind}: {d} against {reference}");
            // The returned point lies on the triangle.
            assert!(reference_distance(q, tri) <= 1e-9, "case {case}: point {q} off the triangle");
            // No point of a dense barycentric grid is nearer; the grid (spacing 1/300 of
            // the edges) gets within its spacing of the distance.
            let dense = dense_distance(p, tri, 300);
            let diameter = tri[0].distance(tri[1]).max(tri[1].distance(tri[2])).max(tri[2].distance(tri[0]));
            assert!(d <= dense + 1e-12, "case {case} kind {kind}: {d} > dense {dense}");
            assert!(d >= dense - diameter / 300.0, "case {case} kind {kind}: {d} ≪ dense {dense}");
        }
    }
    assert!(kinds.iter().all(|&k| k == 100));
}

#[test]
fn slivers_of_any_thinness_are_measured_to_within_1e_7_of_their_length() {
    // Triangle (0, 0), (1, 0), (x, h) in a plane, with the distance known from 2D geometry,
    // then rotated and shifted to a general position (which moves the distance by ~1e-16).
    let mut rng = Rng(3);
    let seg = |p: DVec2, a: DVec2, b: DVec2| {
        let ab = b - a;
        p.distance(a + ab * ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0))
    };
    let cross = |u: DVec2, v: DVec2, w: DVec2| (v - u).perp_dot(w - u);
    for k in 1..=15 {
        let h = 10f64.powi(-k);
        let mut worst: f64 = 0.0;
        for _ in 0..2000 {
            let (a, b, c) = (DVec2::ZERO, DVec2::X, DVec2::new(rng.signed(1.5), h));
            // Half of the points within a few heights of the triangle's plane strip.
            let spread = if rng.next() < 0.5 { 3.0 * h } else { 2.0 };
            let p2 = DVec2::new(rng.signed(2.0), rng.signed(spread));
            let pz = if rng.next() < 0.3 { 0.0 } else { rng.signed(1.0) };
            let inside = cross(a, b, p2) >= 0.0 && cross(b, c, p2) >= 0.0 && cross(c, a, p2) >= 0.0;
            let planar = if inside { 0.0 } else { seg(p2, a, b).min(seg(p2, b, c)).min(seg(p2, c, a)) };
            let reference = planar.hypot(pz);
            let rotation = DQuat::from_euler(EulerRot::XYZ, rng.signed(3.0), rng.signed(3.0), rng.signed(3.0));
            let shift = rng.point(1.0);
            let place = |v: DVec2, z: f64| rotation * v.extend(z) + shift;
            let corners = [place(a, 0.0), place(b, 0.0), place(c, 0.0)];
            let first = k as usize % 3; // each corner first in turn
            let tri = [corners[first], corners[(first + 1) % 3], corners[(first + 2) % 3]];
            let p = place(p2, pz);
            worst = worst.max((p.distance(closest_point_on_triangle(p, tri)) - reference).abs());
        }
        assert!(worst < 1e-7, "height {h}: max error {worst}");
    }
}

#[test]
fn mesh_distance_matches_brute_force_over_all_triangles_of_spot() {
    // Spot plus three degenerate triangles beside it: two coincident corners (a segment),
    // three collinear corners (a segment along z) and three coincident corners (a point).
    let spot = spot();
    let (mut positions, mut triangles) = (spot.positions().to_vec(), spot.triangles().to_vec());
    let base = positions.len() as u32;
    positions.extend([[0.7, 0.0, 0.0], [0.9, 0.1, 0.0], [0.7, 0.0, 0.0]]);
    positions.extend([[0.0, 0.0, 0.75], [0.0, 0.0, 1.0], [0.0, 0.0, 0.8]]);
    positions.extend([[-0.8, 0.2, 0.1]; 3]);
    triangles.extend([[base, base + 1, base + 2], [base + 3, base + 4, base + 5], [base + 6, base + 7, base + 8]]);
    let mesh = Mesh::new(positions, triangles).unwrap();
    assert!(mesh.degenerate_triangle_count() >= 3);
    let corners: Vec<[DVec3; 3]> =
        (0..mesh.triangle_count()).map(|t| mesh.triangle_corners(t).map(|v| v.as_dvec3())).collect();
    let tree = MeshDistance::new(&mesh).unwrap();

    let mut rng = Rng(5);
    let near = sample_surface(&spot, 1000, 3).unwrap().points;
    let mut points: Vec<[f32; 3]> = Vec::new();
    for (i, s) in near.iter().enumerate() {
        let offset = if i % 4 == 0 { 0.0 } else { 0.02 };
        points.push([0, 1, 2].map(|k| (f64::from(s[k]) + rng.signed(offset)) as f32));
    }
    points.extend((0..1500).map(|_| rng.point(0.8).as_vec3().to_array()));
    points.extend((0..500).map(|_| rng.point(4.0).as_vec3().to_array()));
    let mut worst: f64 = 0.0;
    for p in &points {
        let q = DVec3::from(p.map(f64::from));
        let brute = corners.iter().map(|&t| q.distance(closest_point_on_triangle(q, t))).fold(f64::INFINITY, f64::min);
        let d = tree.distance(*p);
        worst = worst.max((d - brute).abs());
        // The reported triangle holds the reported point, at the reported distance.
        let (point, t) = tree.closest_point(q);
        assert!((q.distance(point) - d).abs() <= 1e-12);
        assert!((q.distance(closest_point_on_triangle(q, corners[t])) - d).abs() <= 1e-12);
    }
    assert!(worst <= 1e-12, "max |tree − brute force| = {worst} over {} points", points.len());
    // The degenerate triangles are measured as their edges.
    assert!((tree.distance([0.0, -0.05, 0.9]) - 0.05).abs() < 1e-7);
    assert!((tree.distance([-0.8, 0.2, 0.3]) - 0.2).abs() < 1e-7);
}

#[test]
fn a_mesh_against_itself_scores_zero_without_the_sampling_floor() {
    let spot = spot();
    let exact = surface_chamfer(&spot, &spot, 100_000, 0).unwrap();
    assert!(exact.chamfer < 1e-6, "point-to-surface chamfer {exact:?}");
    assert!(exact.pred_to_gt < 1e-6 && exact.gt_to_pred < 1e-6);
    assert_eq!((exact.samples, exact.seed), (100_000, 0));
    // The point-to-point Chamfer distance of the same samples sits on its floor.
    let pred = sample_surface(&spot, 100_000, 0).unwrap();
    let gt = sample_surface(&spot, 100_000, 1).unwrap();
    let sampled = SurfaceComparison::new(&pred, &gt).unwrap().chamfer();
    assert!(sampled > 1e-3, "point-to-point chamfer {sampled}");
}

#[test]
fn a_sphere_against_the_sphere_one_percent_larger_scores_one_percent_of_the_radius() {
    let r = 0.5;
    let gt = icosphere(5, r as f32).unwrap();
    let pred = icosphere(5, (1.01 * r) as f32).unwrap();
    let d = surface_chamfer(&pred, &gt, 50_000, 7).unwrap();
    // The facets are parallel, 0.01·r·cos(facet angle) apart (cos ≥ 0.9998 at 20 480 faces).
    for v in [d.chamfer, d.pred_to_gt, d.gt_to_pred] {
        assert!((v / (0.01 * r) - 1.0).abs() < 0.02, "{d:?}");
    }
    // Deterministic, and serialisable with the field names as keys.
    assert_eq!(surface_chamfer(&pred, &gt, 50_000, 7).unwrap(), d);
    let json = serde_json::to_string(&d).unwrap();
    assert!(json.contains("\"chamfer\"") && json.contains("\"gt_to_pred\"") && json.contains("\"seed\":7"), "{json}");
    // The unsigned distance of single points: at the centre, outside and inside (the facets
    // lie up to 3e-4·r inside the sphere).
    let tree = MeshDistance::new(&gt).unwrap();
    for (p, expected) in [([0.0, 0.0, 0.0], r), ([0.0, 0.0, 0.8], 0.8 - r), ([0.3, 0.0, 0.0], r - 0.3)] {
        assert!((tree.distance(p) - expected).abs() < 4e-4 * r, "{p:?}: {}", tree.distance(p));
    }
}

#[test]
fn zero_samples_and_zero_area_meshes_are_errors() {
    let sphere = icosphere(1, 1.0).unwrap();
    let err = surface_chamfer(&sphere, &sphere, 0, 0).unwrap_err().to_string();
    assert!(err.contains("samples") && err.contains("got 0"), "{err}");
    let err = surface_chamfer(&sphere, &sphere, MAX_SAMPLES + 1, 0).unwrap_err().to_string();
    assert!(err.contains("samples"), "{err}");
    // Every triangle collinear or with coincident corners: no surface.
    let flat = Mesh::new(vec![[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 0.0, 0.0]], vec![[0, 1, 2], [0, 1, 3]])
        .unwrap();
    let err = MeshDistance::new(&flat).unwrap_err().to_string();
    assert!(err.contains("mesh surface area"), "{err}");
    let err = surface_chamfer(&sphere, &flat, 100, 0).unwrap_err().to_string();
    assert!(err.contains("gt mesh surface area"), "{err}");
    let err = surface_chamfer(&flat, &sphere, 100, 0).unwrap_err().to_string();
    assert!(err.contains("pred mesh surface area"), "{err}");
}

/// `evaluate` refuses more surface samples than `sample_surface` allows, naming the option,
/// before it samples anything.
#[test]
fn evaluate_refuses_more_samples_than_the_cap() {
    let square =
        Mesh::new(vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]], vec![[0, 1, 2], [0, 2, 3]])
            .unwrap();
    let err = evaluate(&square, &square, &EvalOptions::default().with_samples(MAX_SAMPLES + 1)).unwrap_err();
    assert!(err.to_string().contains("options.samples"), "{err}");
}
