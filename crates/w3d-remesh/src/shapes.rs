//! Initial meshes: geodesic (icosahedral) spheres.

use std::collections::HashMap;

use glam::Vec3;
use w3d_core::{Error, Mesh, Result};

/// An icosphere: the icosahedron with every face cut into `4^subdivisions` triangles and
/// the points projected onto the sphere of `radius` around the origin. Has
/// `10·4^s + 2` vertices (level 2: 162 vertices, 320 triangles, the reference's start
/// mesh at radius 0.5). Triangles are counter-clockwise seen from outside.
pub fn icosphere(subdivisions: u32, radius: f32) -> Result<Mesh> {
    if subdivisions > 10 {
        return Err(Error::invalid("subdivisions", format!("at most 10 (10 486 762 vertices), got {subdivisions}")));
    }
    geodesic_sphere(1 << subdivisions, radius)
}

/// A geodesic sphere of `frequency` `n`: every icosahedron face cut into an `n × n`
/// triangular grid, projected onto the sphere of `radius`; `10·n² + 2` vertices (e.g.
/// `n = 32` → 10 242, `n = 71` → 50 412). Triangles are counter-clockwise seen from
/// outside.
pub fn geodesic_sphere(frequency: u32, radius: f32) -> Result<Mesh> {
    if !(1..=1024).contains(&frequency) {
        return Err(Error::invalid("frequency", format!("1 ..= 1024, got {frequency}")));
    }
    if !(radius.is_finite() && radius > 0.0) {
        return Err(Error::invalid("radius", format!("a finite number > 0, got {radius}")));
    }
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let corners: [Vec3; 12] = [
        Vec3::new(-1.0, t, 0.0),
        Vec3::new(1.0, t, 0.0),
        Vec3::new(-1.0, -t, 0.0),
        Vec3::new(1.0, -t, 0.0),
        Vec3::new(0.0, -1.0, t),
        Vec3::new(0.0, 1.0, t),
        Vec3::new(0.0, -1.0, -t),
        Vec3::new(0.0, 1.0, -t),
        Vec3::new(t, 0.0, -1.0),
        Vec3::new(t, 0.0, 1.0),
        Vec3::new(-t, 0.0, -1.0),
        Vec3::new(-t, 0.0, 1.0),
    ];
    let mut faces: [[u32; 3]; 20] = [
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for f in &mut faces {
        let [a, b, c] = f.map(|i| corners[i as usize]);
        if (b - a).cross(c - a).dot(a + b + c) < 0.0 {
            f.swap(1, 2);
        }
    }
    let n = frequency;
    let mut positions: Vec<Vec3> = corners.to_vec();
    let mut on_edge: HashMap<(u32, u32, u32), u32> = HashMap::new();
    let mut triangles = Vec::with_capacity(20 * (n * n) as usize);
    for face in faces {
        let [a, b, c] = face;
        let (pa, pb, pc) = (corners[a as usize], corners[b as usize], corners[c as usize]);
        // Grid point (i, j): weight n − i − j on a, i on b, j on c.
        let mut grid = vec![0u32; ((n + 1) * (n + 2) / 2) as usize];
        let slot = |i: u32, j: u32| (i * (n + 1) - i * (i.saturating_sub(1)) / 2 + j) as usize;
        for i in 0..=n {
            for j in 0..=n - i {
                let weights = [(a, n - i - j), (b, i), (c, j)];
                let nonzero: Vec<(u32, u32)> = weights.into_iter().filter(|w| w.1 > 0).collect();
                let id = match nonzero.as_slice() {
                    [(v, _)] => *v,
                    [(u, wu), (v, _)] => {
                        let key = if u < v { (*u, *v, *wu) } else { (*v, *u, n - *wu) };
                        *on_edge.entry(key).or_insert_with(|| {
                            let p = (corners[key.0 as usize] * key.2 as f32
                                + corners[key.1 as usize] * (n - key.2) as f32)
                                / n as f32;
                            positions.push(p);
                            positions.len() as u32 - 1
                        })
                    }
                    _ => {
                        positions.push((pa * (n - i - j) as f32 + pb * i as f32 + pc * j as f32) / n as f32);
                        positions.len() as u32 - 1
                    }
                };
                grid[slot(i, j)] = id;
            }
        }
        for i in 0..n {
            for j in 0..n - i {
                triangles.push([grid[slot(i, j)], grid[slot(i + 1, j)], grid[slot(i, j + 1)]]);
                if i + j + 1 < n {
                    triangles.push([grid[slot(i + 1, j)], grid[slot(i + 1, j + 1)], grid[slot(i, j + 1)]]);
                }
            }
        }
    }
    let positions = positions.into_iter().map(|p| (p.normalize() * radius).to_array()).collect();
    Mesh::new(positions, triangles)
}
