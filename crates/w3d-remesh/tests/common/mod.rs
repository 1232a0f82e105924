//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

use w3d_core::Mesh;

/// A `w × h` grid of unit squares in the z = 0 plane (vertex `r·(w+1) + c` at `(c, r, 0)`),
/// two counter-clockwise triangles per cell; `flip[row][col]` (row 0 = top row, as the
/// reference test helper draws it) picks the other diagonal.
pub fn grid(flip: &[Vec<bool>]) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let h = flip.len() as u32;
    let w = flip[0].len() as u32;
    let positions = (0..=h).flat_map(|r| (0..=w).map(move |c| [c as f32, r as f32, 0.0])).collect();
    let mut faces = Vec::new();
    for r in 0..h {
        for col in 0..w {
            let c = r * (w + 1) + col;
            if flip[(h - 1 - r) as usize][col as usize] {
                faces.push([c, c + 1, c + w + 1]);
                faces.push([c + 1, c + 1 + w + 1, c + w + 1]);
            } else {
                faces.push([c, c + 1, c + 1 + w + 1]);
                faces.push([c, c + 1 + w + 1, c + w + 1]);
            }
        }
    }
    (positions, faces)
}

/// Faces as a canonical multiset: each rotated to start at its smallest index, then sorted.
pub fn canonical(faces: &[[u32; 3]]) -> Vec<[u32; 3]> {
    let mut out: Vec<[u32; 3]> = faces
        .iter()
        .map(|t| {
            let k = (0..3).min_by_key(|&k| t[k]).unwrap();
            [t[k], t[(k + 1) % 3], t[(k + 2) % 3]]
        })
        .collect();
    out.sort();
    out
}

/// Signed z-components of the face normals (twice the signed area in the xy plane).
pub fn signed_areas_z(positions: &[[f32; 3]], faces: &[[u32; 3]]) -> Vec<f32> {
    faces
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| positions[i as usize]);
            (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        })
        .collect()
}

/// `../shared/data/meshes/<name>` beside the repository.
pub fn shared_mesh(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/meshes").join(name)
}

/// A shared test mesh, seams merged, normalised into the unit cube.
pub fn load_unit(name: &str) -> Mesh {
    let mesh = w3d_core::load_mesh(shared_mesh(name)).expect("load test mesh");
    let (mut mesh, _) = mesh.merge_by_position();
    mesh.normalize_unit_cube();
    mesh
}

use glam::Vec3;

/// Closest point to `p` on triangle `(a, b, c)` (Voronoi-region walk, after Ericson,
/// "Real-Time Collision Detection" §5.1.5).
pub fn closest_on_triangle(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> Vec3 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

/// Exact closest-point queries on a triangle soup through a uniform grid of buckets
/// (a brute-force search restricted to the cells that can hold the answer).
pub struct ClosestPoints {
    triangles: Vec<[Vec3; 3]>,
    origin: Vec3,
    cell: f32,
    dims: [i32; 3],
    buckets: Vec<Vec<u32>>,
}

impl ClosestPoints {
    /// Buckets the triangles `faces` of `positions` into cells of size `cell`.
    pub fn new(positions: &[[f32; 3]], faces: &[[u32; 3]], cell: f32) -> Self {
        let triangles: Vec<[Vec3; 3]> = faces.iter().map(|t| t.map(|v| Vec3::from(positions[v as usize]))).collect();
        Self::from_triangles(triangles, cell)
    }

    /// Nearest-point queries on a point set.
    pub fn points(points: &[Vec3], cell: f32) -> Self {
        Self::from_triangles(points.iter().map(|&p| [p, p, p]).collect(), cell)
    }

    fn from_triangles(triangles: Vec<[Vec3; 3]>, cell: f32) -> Self {
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for t in &triangles {
            for p in t {
                lo = lo.min(*p);
                hi = hi.max(*p);
            }
        }
        let origin = lo - Vec3::splat(cell);
        let dims = ((hi - origin) / cell).ceil().as_ivec3() + 2;
        let dims = [dims.x, dims.y, dims.z];
        let mut buckets = vec![Vec::new(); (dims[0] * dims[1] * dims[2]) as usize];
        for (i, t) in triangles.iter().enumerate() {
            let tlo = ((t[0].min(t[1]).min(t[2]) - origin) / cell).floor().as_ivec3();
            let thi = ((t[0].max(t[1]).max(t[2]) - origin) / cell).floor().as_ivec3();
            for x in tlo.x..=thi.x {
                for y in tlo.y..=thi.y {
                    for z in tlo.z..=thi.z {
                        buckets[((x * dims[1] + y) * dims[2] + z) as usize].push(i as u32);
                    }
                }
            }
        }
        ClosestPoints { triangles, origin, cell, dims, buckets }
    }

    /// The closest point and the index of its triangle.
    pub fn query(&self, p: Vec3) -> (Vec3, usize) {
        let c = ((p - self.origin) / self.cell).floor().as_ivec3();
        let c = [c.x, c.y, c.z];
        let (mut best, mut best_d2, mut best_i) = (p, f32::INFINITY, 0);
        let outside = (0..3).map(|k| (-c[k]).max(c[k] - self.dims[k] + 1).max(0)).max().unwrap();
        let max_ring = self.dims.iter().max().unwrap() + outside;
        for r in 0..=max_ring {
            for x in c[0] - r..=c[0] + r {
                for y in c[1] - r..=c[1] + r {
                    for z in c[2] - r..=c[2] + r {
                        let on_shell = (x - c[0]).abs() == r || (y - c[1]).abs() == r || (z - c[2]).abs() == r;
                        let inside =
                            x >= 0 && y >= 0 && z >= 0 && x < self.dims[0] && y < self.dims[1] && z < self.dims[2];
                        if !on_shell || !inside {
                            continue;
                        }
                        for &i in &self.buckets[((x * self.dims[1] + y) * self.dims[2] + z) as usize] {
                            let [a, b, cc] = self.triangles[i as usize];
                            let q = closest_on_triangle(p, a, b, cc);
                            let d2 = (q - p).length_squared();
                            if d2 < best_d2 || (d2 == best_d2 && (i as usize) < best_i) {
                                (best, best_d2, best_i) = (q, d2, i as usize);
                            }
                        }
                    }
                }
            }
            // Everything beyond ring r lies at least (r − outside) cells away.
            let reach = (r - outside) as f32 * self.cell;
            if best_d2.is_finite() && reach > 0.0 && best_d2 <= reach * reach {
                break;
            }
        }
        (best, best_i)
    }
}

/// Sample points of a mesh: its vertices and face centroids.
pub fn samples(positions: &[[f32; 3]], faces: &[[u32; 3]]) -> Vec<Vec3> {
    let mut out: Vec<Vec3> = positions.iter().map(|&p| Vec3::from(p)).collect();
    out.extend(faces.iter().map(|t| t.iter().map(|&v| Vec3::from(positions[v as usize])).sum::<Vec3>() / 3.0));
    out
}

/// Unnormalised face normal `cross(p1 − p0, p2 − p0)` (length = twice the area), as the
/// remesh operations compute it ([`w3d_core::normals::face_normal`]), rounded to `f32`
/// (zero exactly where theirs is).
pub fn face_normal(positions: &[[f32; 3]], t: [u32; 3]) -> Vec3 {
    w3d_core::normals::face_normal(positions, t).as_vec3()
}

/// Flipped faces of a consistently oriented mesh: a face is flipped when its unit normal
/// points against the sum of the unit normals of its edge neighbours.
pub fn flipped_faces(positions: &[[f32; 3]], faces: &[[u32; 3]]) -> Vec<bool> {
    let normals: Vec<Vec3> = faces.iter().map(|&t| face_normal(positions, t).normalize_or_zero()).collect();
    let mut by_edge = std::collections::HashMap::with_capacity(3 * faces.len());
    for (f, t) in faces.iter().enumerate() {
        for k in 0..3 {
            by_edge.insert((t[k], t[(k + 1) % 3]), f);
        }
    }
    faces
        .iter()
        .enumerate()
        .map(|(f, t)| {
            let around: Vec3 = (0..3).filter_map(|k| by_edge.get(&(t[(k + 1) % 3], t[k])).map(|&g| normals[g])).sum();
            normals[f].dot(around) < 0.0
        })
        .collect()
}
