//! Volume IoU on regular grids, with "inside" decided by the generalised winding number.

use glam::{DVec3, Vec3};
use rayon::prelude::*;
use w3d_core::{Error, Mesh, Result};

use crate::winding::WindingNumber;

/// A regular lattice of `resolution³` sample points `origin + (i, j, k) · step`
/// (mesh units, canonical frame), stored x-major: index `(i · n + j) · n + k`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    /// Position of sample `(0, 0, 0)`.
    pub origin: Vec3,
    /// Spacing between samples along each axis.
    pub step: Vec3,
    /// Samples per axis.
    pub resolution: usize,
}

impl Grid {
    /// The SyncDreamer / `mesh2sdf.compute(v, f, 64)` lattice: the 64³ partition of
    /// `[−1, 1]³`, sampled at `−1 + 2i/64` (the low corner of each voxel, which is where
    /// mesh2sdf evaluates its SDF).
    pub fn syncdreamer64() -> Self {
        Grid { origin: Vec3::splat(-1.0), step: Vec3::splat(2.0 / 64.0), resolution: 64 }
    }

    /// `resolution³` voxels partitioning the box `[lo, hi]`, sampled at voxel centres.
    /// Errors on a zero resolution or a box that is empty or not finite along some axis.
    pub fn voxel_centres(lo: Vec3, hi: Vec3, resolution: usize) -> Result<Self> {
        if resolution == 0 {
            return Err(Error::invalid("grid resolution", "at least 1 voxel per axis, got 0"));
        }
        if !(lo.is_finite() && hi.is_finite() && hi.cmpgt(lo).all()) {
            return Err(Error::invalid(
                "grid box",
                format!("finite corners with hi > lo on every axis, got {lo} .. {hi}"),
            ));
        }
        let step = (hi - lo) / resolution as f32;
        Ok(Grid { origin: lo + 0.5 * step, step, resolution })
    }

    /// The sample point with integer coordinates `(i, j, k)`.
    pub fn point(&self, i: usize, j: usize, k: usize) -> DVec3 {
        self.origin.as_dvec3() + DVec3::new(i as f64, j as f64, k as f64) * self.step.as_dvec3()
    }
}

/// Occupancy of `mesh` on `grid`: `true` where the generalised winding number satisfies
/// `|w| > 0.5` (the absolute value also accepts meshes wound inward, such as horse.ply).
///
/// For a *closed* mesh (after merging vertices by position, every directed edge is
/// cancelled by an opposite one, so `w` is an integer constant between surface crossings)
/// `w` is evaluated only at grid points whose neighbouring cells a triangle's bounding box
/// touches, plus once per connected region of the remaining points (a grid edge between two
/// such points cannot cross the surface). Open meshes get `w` at every point. Both paths
/// give the same answer for closed meshes; the first is several times faster.
pub fn occupancy(mesh: &Mesh, grid: &Grid) -> Vec<bool> {
    let winding = WindingNumber::new(mesh);
    let inside = |i: usize| winding.at(grid_point(grid, i)).abs() > 0.5;
    if !is_closed(mesh) {
        return (0..grid.resolution.pow(3)).into_par_iter().map(inside).collect();
    }
    let near = near_surface(mesh, grid);
    let mut occupied: Vec<bool> = (0..near.len()).into_par_iter().map(|i| near[i] && inside(i)).collect();
    // Flood-fill each region of points away from the surface with the value at its seed.
    let n = grid.resolution;
    let mut visited = near;
    let mut stack = Vec::new();
    for seed in 0..visited.len() {
        if visited[seed] {
            continue;
        }
        let value = inside(seed);
        visited[seed] = true;
        stack.push(seed);
        while let Some(i) = stack.pop() {
            occupied[i] = value;
            let (x, y, z) = (i / (n * n), (i / n) % n, i % n);
            let neighbours = [
                (x > 0).then(|| i - n * n),
                (x + 1 < n).then(|| i + n * n),
                (y > 0).then(|| i - n),
                (y + 1 < n).then(|| i + n),
                (z > 0).then(|| i - 1),
                (z + 1 < n).then(|| i + 1),
            ];
            for j in neighbours.into_iter().flatten() {
                if !visited[j] {
                    visited[j] = true;
                    stack.push(j);
                }
            }
        }
    }
    occupied
}

/// Grid point number `i` (x-major order).
fn grid_point(grid: &Grid, i: usize) -> DVec3 {
    let n = grid.resolution;
    grid.point(i / (n * n), (i / n) % n, i % n)
}

/// Whether the triangles, with vertices merged by position, form a closed 2-cycle: every
/// directed edge `(a, b)` is matched by as many `(b, a)`. Then the winding number is an
/// integer, constant off the surface between crossings.
fn is_closed(mesh: &Mesh) -> bool {
    let (merged, _) = mesh.merge_by_position();
    let mut edges: Vec<(u32, u32, i32)> = merged
        .triangles()
        .iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .map(|(a, b)| if a < b { (a, b, 1) } else { (b, a, -1) })
        .collect();
    edges.sort_unstable();
    edges.chunk_by(|p, q| (p.0, p.1) == (q.0, q.1)).all(|run| run.iter().map(|e| e.2).sum::<i32>() == 0)
}

/// Marks every grid point that is a corner of a grid cell touched by some triangle's
/// bounding box (conservatively, with a small margin): a grid edge between two unmarked
/// points cannot meet the surface.
fn near_surface(mesh: &Mesh, grid: &Grid) -> Vec<bool> {
    let n = grid.resolution;
    let (origin, step) = (grid.origin.as_dvec3(), grid.step.as_dvec3());
    let mut near = vec![false; n * n * n];
    for t in 0..mesh.triangle_count() {
        let [a, b, c] = mesh.triangle_corners(t).map(|v| (v.as_dvec3() - origin) / step);
        let lo = (a.min(b).min(c) - 1e-6).floor().max(DVec3::ZERO);
        let hi = (a.max(b).max(c) + 1e-6).ceil().min(DVec3::splat((n - 1) as f64));
        if lo.cmpgt(hi).any() {
            continue;
        }
        let (lo, hi) = (lo.as_uvec3(), hi.as_uvec3());
        for x in lo.x..=hi.x {
            for y in lo.y..=hi.y {
                let row = (x as usize * n + y as usize) * n;
                near[row + lo.z as usize..=row + hi.z as usize].fill(true);
            }
        }
    }
    near
}

/// Intersection over union of two occupancy grids of the same length.
/// Errors on different lengths or when neither grid has an occupied sample.
pub fn occupancy_iou(a: &[bool], b: &[bool]) -> Result<f64> {
    if a.len() != b.len() {
        return Err(Error::invalid("occupancy grids", format!("grids of equal size, got {} and {}", a.len(), b.len())));
    }
    let (mut inter, mut union) = (0usize, 0usize);
    for (&x, &y) in a.iter().zip(b) {
        inter += usize::from(x && y);
        union += usize::from(x || y);
    }
    if union == 0 {
        return Err(Error::invalid("occupancy", "at least one occupied grid sample in either mesh, got none"));
    }
    Ok(inter as f64 / union as f64)
}

/// Volume IoU of `pred` and `gt` sampled on `grid` (see [`occupancy`]).
pub fn volume_iou(pred: &Mesh, gt: &Mesh, grid: &Grid) -> Result<f64> {
    occupancy_iou(&occupancy(pred, grid), &occupancy(gt, grid))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An axis-aligned closed box mesh from `lo` to `hi` (outward winding).
    fn cuboid(lo: [f32; 3], hi: [f32; 3]) -> Mesh {
        let p: Vec<[f32; 3]> = (0..8)
            .map(|i| {
                [
                    if i & 1 == 0 { lo[0] } else { hi[0] },
                    if i & 2 == 0 { lo[1] } else { hi[1] },
                    if i & 4 == 0 { lo[2] } else { hi[2] },
                ]
            })
            .collect();
        let t = vec![
            [0, 2, 1],
            [1, 2, 3],
            [4, 5, 6],
            [5, 7, 6], // z faces
            [0, 1, 4],
            [1, 5, 4],
            [2, 6, 3],
            [3, 6, 7], // y faces
            [0, 4, 2],
            [2, 4, 6],
            [1, 3, 5],
            [3, 7, 5], // x faces
        ];
        Mesh::new(p, t).unwrap()
    }

    #[test]
    fn boxes_give_the_voxel_count_ratio() {
        let grid = Grid::voxel_centres(Vec3::splat(-1.0), Vec3::splat(1.0), 20).unwrap();
        // 0.1 voxels: box a covers voxel centres with x in (-0.5, 0.5) = 10 per axis;
        // box b is shifted by 0.2 (2 voxels) along x.
        let a = cuboid([-0.5; 3], [0.5; 3]);
        let b = cuboid([-0.3, -0.5, -0.5], [0.7, 0.5, 0.5]);
        assert_eq!(occupancy(&a, &grid).iter().filter(|&&o| o).count(), 1000);
        let iou = volume_iou(&a, &b, &grid).unwrap();
        assert!((iou - 800.0 / 1200.0).abs() < 1e-12, "iou {iou}");
        assert_eq!(volume_iou(&a, &a, &Grid::syncdreamer64()).unwrap(), 1.0);
    }

    #[test]
    fn closed_fast_path_matches_evaluating_every_point() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data/meshes/spot.obj");
        let mut spot = w3d_core::load_mesh(path).unwrap();
        spot.normalize_unit_cube();
        assert!(is_closed(&spot));
        let (lo, hi) = spot.bbox();
        let grid = Grid::voxel_centres(lo, hi, 40).unwrap();
        let winding = WindingNumber::new(&spot);
        let direct: Vec<bool> = (0..40 * 40 * 40).map(|i| winding.at(grid_point(&grid, i)).abs() > 0.5).collect();
        let fast = occupancy(&spot, &grid);
        assert_eq!(fast, direct);
        assert!(fast.iter().filter(|&&o| o).count() > 10_000);
        // Dropping one triangle opens the mesh (the every-point path is taken).
        let open = Mesh::new(spot.positions().to_vec(), spot.triangles()[1..].to_vec()).unwrap();
        assert!(!is_closed(&open));
    }

    #[test]
    fn inward_winding_still_counts_as_inside() {
        let grid = Grid::voxel_centres(Vec3::splat(-1.0), Vec3::splat(1.0), 10).unwrap();
        let a = cuboid([-0.5; 3], [0.5; 3]);
        let mut flipped = a.clone();
        flipped.flip_winding();
        assert_eq!(occupancy(&a, &grid), occupancy(&flipped, &grid));
    }

    #[test]
    fn bad_grids_are_errors() {
        assert!(Grid::voxel_centres(Vec3::ZERO, Vec3::ONE, 0).is_err());
        assert!(
            Grid::voxel_centres(Vec3::ZERO, Vec3::new(1.0, 0.0, 1.0), 8).unwrap_err().to_string().contains("grid box")
        );
        assert!(occupancy_iou(&[false; 3], &[false; 3]).is_err());
        assert!(occupancy_iou(&[false; 3], &[true; 2]).is_err());
    }
}
