//! Seeded, area-weighted sampling of points on a mesh surface.

use glam::DVec3;
use rayon::prelude::*;
use w3d_core::{Error, Mesh, Result};

/// Points sampled uniformly (by area) on a mesh surface, with the unit normal of the
/// triangle each point lies on. Units and frame are the mesh's.
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceSamples {
    /// Sample positions.
    pub points: Vec<[f32; 3]>,
    /// Unit normal of the sampled triangle (counter-clockwise winding = outward).
    pub normals: Vec<[f32; 3]>,
}

/// The SplitMix64 generator (Steele, Lea, Flood 2014): a 64-bit counter advanced by the
/// golden-ratio increment and passed through a bijective mixer. Being counter-based, the
/// `k`-th output can be computed directly, which keeps parallel sampling deterministic.
#[derive(Debug, Clone, Copy)]
struct SplitMix64 {
    state: u64,
}

const GOLDEN_GAMMA: u64 = 0x9E37_79B9_7F4A_7C15;

impl SplitMix64 {
    /// The generator positioned just before output number `index` of the stream `seed`.
    fn at(seed: u64, index: u64) -> Self {
        SplitMix64 { state: mix64(seed).wrapping_add(index.wrapping_mul(GOLDEN_GAMMA)) }
    }

    fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(GOLDEN_GAMMA);
        mix64(self.state)
    }

    /// A uniform value in `[0, 1)` with 53 random bits.
    fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The most points [`sample_surface`] draws (and so the most samples
/// [`EvalOptions::samples`](crate::EvalOptions::samples) may ask for): 10⁷ samples with their k-d tree take about
/// 1 GB; 10¹¹ asked for 1.2 TB and aborted the process on allocation.
pub const MAX_SAMPLES: usize = 10_000_000;

/// Samples `count` points uniformly by area on `mesh`'s surface.
///
/// Point `i` uses outputs `3i+1 … 3i+3` of a SplitMix64 stream seeded by `seed`: the first
/// picks a triangle with probability proportional to its area, the other two pick a
/// uniform point in it (`√u₁` barycentric warp). The result depends only on
/// `(mesh, count, seed)`, never on the number of threads: the same seed gives the same bytes.
///
/// Errors: `count == 0`, or a mesh whose total area is zero.
pub fn sample_surface(mesh: &Mesh, count: usize, seed: u64) -> Result<SurfaceSamples> {
    if count == 0 {
        return Err(Error::invalid("sample count", "at least 1 point, got 0"));
    }
    if count > MAX_SAMPLES {
        return Err(Error::invalid(
            "sample count",
            format!("at most {MAX_SAMPLES} points (~24 bytes each, plus a k-d tree to match them), got {count}"),
        ));
    }
    let corners: Vec<[DVec3; 3]> =
        (0..mesh.triangle_count()).map(|t| mesh.triangle_corners(t).map(|v| v.as_dvec3())).collect();
    let mut cdf = Vec::with_capacity(corners.len());
    let mut total = 0.0f64;
    for &t in mesh.triangles() {
        total += 0.5 * w3d_core::normals::face_normal(mesh.positions(), t).length();
        cdf.push(total);
    }
    if total <= 0.0 || !total.is_finite() {
        return Err(Error::invalid("mesh surface area", format!("a positive, finite area, got {total}")));
    }
    let normals: Vec<[f32; 3]> = mesh.face_normals();
    let (points, normals): (Vec<[f32; 3]>, Vec<[f32; 3]>) = (0..count)
        .into_par_iter()
        .map(|i| {
            let mut rng = SplitMix64::at(seed, 3 * i as u64);
            let target = rng.next_f64() * total;
            // First triangle whose cumulative area exceeds the target (zero-area
            // triangles are never chosen: their cdf entry equals the previous one).
            let t = cdf.partition_point(|&c| c <= target).min(cdf.len() - 1);
            let r1 = rng.next_f64().sqrt();
            let u2 = rng.next_f64();
            let [a, b, c] = corners[t];
            let p = a * (1.0 - r1) + b * (r1 * (1.0 - u2)) + c * (r1 * u2);
            (p.as_vec3().to_array(), normals[t])
        })
        .unzip();
    Ok(SurfaceSamples { points, normals })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square() -> Mesh {
        // A 2 × 1 rectangle in the z = 0 plane made of one big and two small triangles.
        let positions = vec![[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 1.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]];
        Mesh::new(positions, vec![[0, 1, 4], [1, 2, 4], [0, 4, 3]]).unwrap()
    }

    #[test]
    fn same_seed_same_bytes_other_seed_differs() {
        let m = square();
        let a = sample_surface(&m, 1000, 7).unwrap();
        let b = sample_surface(&m, 1000, 7).unwrap();
        let c = sample_surface(&m, 1000, 8).unwrap();
        assert_eq!(a, b);
        assert_ne!(a.points, c.points);
    }

    #[test]
    fn samples_are_uniform_by_area() {
        let m = square();
        let s = sample_surface(&m, 200_000, 1).unwrap();
        // The big triangle (0,1,4) has area 1 of 2: half of the points lie below the
        // line from (0,0) to (1,1) and the line from (2,0) to (1,1).
        let in_big = s.points.iter().filter(|p| p[1] <= p[0].min(2.0 - p[0])).count() as f64 / 200_000.0;
        assert!((in_big - 0.5).abs() < 0.005, "fraction in the big triangle {in_big}");
        // Left half x < 1 holds half of the area.
        let left = s.points.iter().filter(|p| p[0] < 1.0).count() as f64 / 200_000.0;
        assert!((left - 0.5).abs() < 0.005, "fraction left {left}");
        assert!(s.points.iter().all(|p| p[2] == 0.0 && (0.0..=2.0).contains(&p[0]) && (0.0..=1.0).contains(&p[1])));
        assert!(s.normals.iter().all(|n| *n == [0.0, 0.0, 1.0]));
    }

    #[test]
    fn zero_count_and_zero_area_are_errors() {
        assert!(sample_surface(&square(), 0, 0).unwrap_err().to_string().contains("sample count"));
        let flat = Mesh::new(vec![[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]], vec![[0, 1, 2]]).unwrap();
        assert!(sample_surface(&flat, 10, 0).unwrap_err().to_string().contains("surface area"));
        // 10¹¹ samples (1.2 TB) aborted the process on allocation: now a clear error.
        let err = sample_surface(&square(), 100_000_000_000, 0).unwrap_err().to_string();
        assert!(err.contains("at most 10000000"), "{err}");
    }
}
