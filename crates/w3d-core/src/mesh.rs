//! Triangle meshes: validated storage, attributes and topology queries.

use glam::Vec3;

use crate::error::{Error, Result};
use crate::image::Image;
pub use crate::weld::weld_by_position;

/// A triangle mesh: positions, counter-clockwise triangles (seen from outside) and
/// optional per-vertex normals, texture coordinates, colours and a base-colour texture.
///
/// A `Mesh` is always valid: finite positions, at least one triangle, indices in range,
/// no triangle repeating a vertex, attribute arrays as long as `positions`. Units are
/// whatever the source file used until [`Mesh::normalize_unit_cube`] is applied.
#[derive(Debug, Clone, PartialEq)]
pub struct Mesh {
    positions: Vec<[f32; 3]>,
    triangles: Vec<[u32; 3]>,
    normals: Option<Vec<[f32; 3]>>,
    uvs: Option<Vec<[f32; 2]>>,
    colours: Option<Vec<[f32; 3]>>,
    texture: Option<Image>,
}

/// The similarity applied by [`Mesh::normalize_unit_cube`]: `p' = (p - centre) · scale`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Normalization {
    /// Centre of the original bounding box.
    pub centre: Vec3,
    /// Uniform scale factor (1 / longest bbox side).
    pub scale: f32,
}

impl Normalization {
    /// Applies the transform to a point (in f64, so coordinates near the f32 range, whose
    /// differences overflow in f32, still map into the unit cube).
    pub fn apply(&self, p: Vec3) -> Vec3 {
        ((p.as_dvec3() - self.centre.as_dvec3()) * f64::from(self.scale)).as_vec3()
    }

    /// Maps a normalised point back to the original frame (in f64, like [`Normalization::apply`]).
    pub fn invert(&self, p: Vec3) -> Vec3 {
        (p.as_dvec3() / f64::from(self.scale) + self.centre.as_dvec3()).as_vec3()
    }
}

/// Topology summary of a mesh after merging vertices by position (as reported by
/// `wonder3d info`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Topology {
    /// Vertices referenced by at least one triangle (after merging).
    pub vertices: usize,
    /// Unique undirected edges.
    pub edges: usize,
    /// Triangles (after dropping those that merging made degenerate).
    pub faces: usize,
    /// Edges used by exactly one triangle.
    pub boundary_edges: usize,
    /// Edges used by more than two triangles.
    pub non_manifold_edges: usize,
    /// Connected components: groups of triangles linked through edges shared by exactly
    /// two triangles (parts that touch only at a vertex or a non-manifold edge count
    /// separately, as in trimesh's `split`).
    pub components: usize,
    /// V − E + F.
    pub euler: i64,
}

impl Topology {
    /// Every edge is shared by exactly two triangles, and there is at least one triangle (a
    /// mesh whose triangles all collapse when merging by position is not a closed surface).
    pub fn is_watertight(&self) -> bool {
        self.faces > 0 && self.boundary_edges == 0 && self.non_manifold_edges == 0
    }

    /// Genus `(2·components − euler) / 2` of a watertight mesh; `None` if the mesh has
    /// boundaries or non-manifold edges or the value is not a whole number.
    pub fn genus(&self) -> Option<i64> {
        let twice = 2 * self.components as i64 - self.euler;
        (self.is_watertight() && twice >= 0 && twice % 2 == 0).then_some(twice / 2)
    }
}

impl Mesh {
    /// A validated mesh from positions and triangles.
    ///
    /// Errors name the first offending element: a non-finite coordinate
    /// (`positions[i].y`), an index out of range or a repeated index (`triangles[i]`), or
    /// an empty array.
    pub fn new(positions: Vec<[f32; 3]>, triangles: Vec<[u32; 3]>) -> Result<Self> {
        if triangles.is_empty() {
            return Err(Error::invalid(
                "triangles",
                format!("at least one triangle, got none (and {} vertices)", positions.len()),
            ));
        }
        if positions.is_empty() {
            return Err(Error::invalid("positions", "at least 3 vertices, got none"));
        }
        validate_geometry(&positions, &triangles)?;
        Ok(Mesh { positions, triangles, normals: None, uvs: None, colours: None, texture: None })
    }

    fn check_len(&self, field: &str, len: usize) -> Result<()> {
        if len != self.positions.len() {
            return Err(Error::invalid(field, format!("one value per vertex ({}), got {len}", self.positions.len())));
        }
        Ok(())
    }

    /// Adds per-vertex normals (finite; one per vertex).
    pub fn with_normals(mut self, normals: Vec<[f32; 3]>) -> Result<Self> {
        self.check_len("normals", normals.len())?;
        check_finite("normals", normals.iter().flatten())?;
        self.normals = Some(normals);
        Ok(self)
    }

    /// Adds per-vertex texture coordinates in the OBJ convention: u to the right, v up,
    /// `(0, 0)` the bottom-left corner of the texture (glTF IO flips v).
    pub fn with_uvs(mut self, uvs: Vec<[f32; 2]>) -> Result<Self> {
        self.check_len("uvs", uvs.len())?;
        check_finite("uvs", uvs.iter().flatten())?;
        self.uvs = Some(uvs);
        Ok(self)
    }

    /// Adds per-vertex colours, sRGB-encoded in `[0, 1]`.
    pub fn with_colours(mut self, colours: Vec<[f32; 3]>) -> Result<Self> {
        self.check_len("colours", colours.len())?;
        check_finite("colours", colours.iter().flatten())?;
        self.colours = Some(colours);
        Ok(self)
    }

    /// Adds a base-colour texture (RGB or RGBA, sRGB-encoded in `[0, 1]`); requires uvs.
    pub fn with_texture(mut self, texture: Image) -> Result<Self> {
        if self.uvs.is_none() {
            return Err(Error::invalid("texture", "a mesh with uvs before a texture is attached"));
        }
        if !matches!(texture.channels(), 3 | 4) {
            return Err(Error::invalid(
                "texture",
                format!("an RGB or RGBA image, got {} channels", texture.channels()),
            ));
        }
        self.texture = Some(texture);
        Ok(self)
    }

    /// Vertex positions.
    pub fn positions(&self) -> &[[f32; 3]] {
        &self.positions
    }

    /// Triangles as vertex-index triples, counter-clockwise seen from outside.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// Per-vertex normals, if present.
    pub fn normals(&self) -> Option<&[[f32; 3]]> {
        self.normals.as_deref()
    }

    /// Per-vertex texture coordinates, if present.
    pub fn uvs(&self) -> Option<&[[f32; 2]]> {
        self.uvs.as_deref()
    }

    /// Per-vertex sRGB colours, if present.
    pub fn colours(&self) -> Option<&[[f32; 3]]> {
        self.colours.as_deref()
    }

    /// The base-colour texture, if present.
    pub fn texture(&self) -> Option<&Image> {
        self.texture.as_ref()
    }

    /// Removes the texture, uvs, normals and colours, keeping the geometry.
    pub fn without_attributes(mut self) -> Self {
        self.normals = None;
        self.uvs = None;
        self.colours = None;
        self.texture = None;
        self
    }

    /// Number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// The corner positions of triangle `t`.
    pub fn triangle_corners(&self, t: usize) -> [Vec3; 3] {
        self.triangles[t].map(|i| Vec3::from(self.positions[i as usize]))
    }

    /// Axis-aligned bounding box `(min, max)` of the vertices.
    pub fn bbox(&self) -> (Vec3, Vec3) {
        self.positions.iter().fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)), |(lo, hi), p| {
            let p = Vec3::from(*p);
            (lo.min(p), hi.max(p))
        })
    }

    /// Per-triangle unit normals (zero for zero-area triangles); see [`crate::normals`].
    pub fn face_normals(&self) -> Vec<[f32; 3]> {
        crate::normals::unit_face_normals(&self.positions, &self.triangles)
    }

    /// Per-vertex unit normals: the area-weighted average of the adjacent face normals
    /// (zero for vertices with no non-degenerate face); see [`crate::normals`].
    pub fn vertex_normals(&self) -> Vec<[f32; 3]> {
        crate::normals::vertex_normals(&self.positions, &self.triangles)
    }

    /// Total surface area (in squared mesh units).
    pub fn surface_area(&self) -> f64 {
        (0..self.triangles.len())
            .map(|t| 0.5 * crate::normals::face_normal(&self.positions, self.triangles[t]).length())
            .sum()
    }

    /// Signed enclosed volume (divergence theorem); positive for closed meshes with
    /// outward (counter-clockwise) triangles.
    pub fn signed_volume(&self) -> f64 {
        (0..self.triangles.len())
            .map(|t| {
                let [a, b, c] = self.triangle_corners(t).map(|v| v.as_dvec3());
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }

    /// Unique undirected edges `[min, max]` of the triangles, sorted.
    pub fn edges(&self) -> Vec<[u32; 2]> {
        let mut edges: Vec<[u32; 2]> = self.triangles.iter().flat_map(|t| triangle_edges(*t)).collect();
        edges.sort_unstable();
        edges.dedup();
        edges
    }

    /// Topology of the mesh *as stored* (vertices with identical positions are distinct;
    /// see [`Mesh::merge_by_position`] for the analysis most tools report).
    pub fn topology(&self) -> Topology {
        // Every (edge, triangle) incidence, sorted so equal edges are adjacent.
        let mut incidences: Vec<([u32; 2], u32)> = Vec::with_capacity(3 * self.triangles.len());
        for (t, tri) in self.triangles.iter().enumerate() {
            incidences.extend(triangle_edges(*tri).map(|e| (e, t as u32)));
        }
        incidences.sort_unstable();
        let (mut unique, mut boundary, mut non_manifold) = (0, 0, 0);
        let mut faces = DisjointSets::new(self.triangles.len());
        for group in incidences.chunk_by(|a, b| a.0 == b.0) {
            unique += 1;
            match group.len() {
                1 => boundary += 1,
                2 => faces.union(group[0].1, group[1].1),
                _ => non_manifold += 1,
            }
        }
        let mut used = vec![false; self.positions.len()];
        for &v in self.triangles.iter().flatten() {
            used[v as usize] = true;
        }
        let vertices = used.iter().filter(|&&u| u).count();
        let components = (0..self.triangles.len() as u32).filter(|&t| faces.find(t) == t).count();
        Topology {
            vertices,
            edges: unique,
            faces: self.triangles.len(),
            boundary_edges: boundary,
            non_manifold_edges: non_manifold,
            components,
            euler: vertices as i64 - unique as i64 + self.triangles.len() as i64,
        }
    }

    /// Number of edges used by exactly one triangle (as stored).
    pub fn boundary_edge_count(&self) -> usize {
        self.topology().boundary_edges
    }

    /// Number of connected components (as stored).
    pub fn connected_components(&self) -> usize {
        self.topology().components
    }

    /// Euler characteristic V − E + F (as stored, counting referenced vertices only).
    pub fn euler_characteristic(&self) -> i64 {
        self.topology().euler
    }

    /// Merges vertices with bit-identical positions (−0 and +0 are equal), dropping
    /// triangles that become degenerate and all per-vertex attributes (they may differ
    /// across seams). Returns the merged mesh and, for each input vertex, its new index.
    pub fn merge_by_position(&self) -> (Mesh, Vec<u32>) {
        let remap = weld_by_position(&self.positions);
        let mut positions = Vec::new();
        for (p, &class) in self.positions.iter().zip(&remap) {
            if class as usize == positions.len() {
                positions.push(*p);
            }
        }
        let triangles: Vec<[u32; 3]> = self
            .triangles
            .iter()
            .map(|t| t.map(|v| remap[v as usize]))
            .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
            .collect();
        let mesh = Mesh { positions, triangles, normals: None, uvs: None, colours: None, texture: None };
        (mesh, remap)
    }

    /// Centres the bounding box at the origin and scales the longest side to 1 (the unit
    /// cube `[-0.5, 0.5]³`), transforming normals consistently. Returns the transform.
    /// A mesh whose bbox is a single point is only translated (scale 1).
    pub fn normalize_unit_cube(&mut self) -> Normalization {
        let (lo, hi) = self.bbox();
        // In f64: for coordinates near ±f32::MAX the side and the centre overflow in f32.
        let (lo, hi) = (lo.as_dvec3(), hi.as_dvec3());
        let centre = ((lo + hi) * 0.5).as_vec3();
        let side = (hi - lo).max_element();
        let scale = if side > 0.0 { (1.0 / side) as f32 } else { 1.0 };
        let t = Normalization { centre, scale };
        for p in &mut self.positions {
            *p = t.apply(Vec3::from(*p)).to_array();
        }
        t
    }

    /// Applies `f` to every position (e.g. a rigid transform). Normals are left as they
    /// are; the caller recomputes them if `f` is not a translation / uniform scale.
    pub fn map_positions(&mut self, f: impl Fn(Vec3) -> Vec3) -> Result<()> {
        for p in &mut self.positions {
            *p = f(Vec3::from(*p)).to_array();
        }
        check_finite("positions", self.positions.iter().flatten())
    }

    /// Number of degenerate triangles: two corners at the same position (as
    /// [`Mesh::merge_by_position`] compares them: bit-identical, −0 = +0) or three collinear
    /// corners (zero area, computed exactly in f64). `wonder3d info` reports them; they have
    /// no orientation, so [`Mesh::orient_outward`] and the topology of the merged mesh ignore
    /// them.
    pub fn degenerate_triangle_count(&self) -> usize {
        let key = |p: [f32; 3]| p.map(|v| if v == 0.0 { 0 } else { v.to_bits() });
        self.triangles
            .iter()
            .filter(|t| {
                let [a, b, c] = t.map(|i| self.positions[i as usize]);
                let (ka, kb, kc) = (key(a), key(b), key(c));
                if ka == kb || kb == kc || ka == kc {
                    return true;
                }
                let [a, b, c] = [a, b, c].map(|p| glam::DVec3::from(p.map(f64::from)));
                (b - a).cross(c - a) == glam::DVec3::ZERO
            })
            .count()
    }

    /// Whether the mesh is a closed surface wound inward: watertight after merging by
    /// position, with a negative signed volume (the divergence theorem is exact for closed
    /// surfaces, so the sign is the orientation).
    pub fn is_closed_inward(&self) -> bool {
        let (merged, _) = self.merge_by_position();
        merged.topology().is_watertight() && merged.signed_volume() < 0.0
    }

    /// Orients a closed mesh outward (counter-clockwise seen from outside, as the whole
    /// workspace assumes): when [`Mesh::is_closed_inward`], flips the winding (and the
    /// normals) and returns `true`; otherwise (already outward, or open, where inside and
    /// outside are undefined) leaves the mesh unchanged and returns `false`.
    pub fn orient_outward(&mut self) -> bool {
        let inward = self.is_closed_inward();
        if inward {
            self.flip_winding();
        }
        inward
    }

    /// Reverses the winding of every triangle (for meshes wound inward, e.g. horse.ply),
    /// negating normals.
    pub fn flip_winding(&mut self) {
        for t in &mut self.triangles {
            t.swap(1, 2);
        }
        if let Some(n) = &mut self.normals {
            for v in n.iter_mut() {
                *v = v.map(|c| -c);
            }
        }
    }

    /// Splits the mesh into its parts: positions, triangles, normals, uvs, colours, texture.
    #[allow(clippy::type_complexity)]
    pub fn into_parts(
        self,
    ) -> (
        Vec<[f32; 3]>,
        Vec<[u32; 3]>,
        Option<Vec<[f32; 3]>>,
        Option<Vec<[f32; 2]>>,
        Option<Vec<[f32; 3]>>,
        Option<Image>,
    ) {
        (self.positions, self.triangles, self.normals, self.uvs, self.colours, self.texture)
    }
}

/// Checks raw geometry arrays as [`Mesh::new`] does (without requiring them to be
/// non-empty): finite coordinates, fewer than 2³²−1 vertices, indices in range and three
/// distinct indices per triangle. Errors name the first offending element
/// (`positions[i].y`, `triangles[i]`). For crates that take plain arrays; it runs on every
/// call of the rasteriser's ops, so valid input takes one branch-free pass and only
/// invalid input pays for locating the first problem.
pub fn validate_geometry(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Result<()> {
    let finite = positions.as_flattened().iter().fold(0u32, |bad, v| bad + !v.is_finite() as u32) == 0;
    let indices_ok = u32::try_from(positions.len()).is_ok_and(|n| {
        n < u32::MAX
            && triangles.iter().fold(0u32, |bad, t| {
                let out = (t[0] >= n) | (t[1] >= n) | (t[2] >= n);
                bad + (out | (t[0] == t[1]) | (t[1] == t[2]) | (t[0] == t[2])) as u32
            }) == 0
    });
    if finite && indices_ok { Ok(()) } else { Err(first_geometry_error(positions, triangles)) }
}

/// The error [`validate_geometry`] reports for invalid arrays: the first offending element.
fn first_geometry_error(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Error {
    if positions.len() >= u32::MAX as usize {
        return Error::invalid("positions", "fewer than 2³²−1 vertices");
    }
    for (i, p) in positions.iter().enumerate() {
        for (axis, v) in ["x", "y", "z"].iter().zip(p) {
            if !v.is_finite() {
                return Error::invalid(format!("positions[{i}].{axis}"), format!("a finite number, got {v}"));
            }
        }
    }
    let n = positions.len() as u32;
    for (i, t) in triangles.iter().enumerate() {
        if let Some(&bad) = t.iter().find(|&&v| v >= n) {
            return Error::invalid(format!("triangles[{i}]"), format!("vertex indices below {n}, got {bad} in {t:?}"));
        }
        if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
            return Error::invalid(format!("triangles[{i}]"), format!("three distinct vertex indices, got {t:?}"));
        }
    }
    unreachable!("first_geometry_error is only called for arrays that failed the scan")
}

fn check_finite<'a>(field: &str, values: impl Iterator<Item = &'a f32>) -> Result<()> {
    for (i, v) in values.enumerate() {
        if !v.is_finite() {
            return Err(Error::invalid(format!("{field} (value {i})"), format!("a finite number, got {v}")));
        }
    }
    Ok(())
}

/// The three undirected edges `[min, max]` of a triangle.
pub fn triangle_edges(t: [u32; 3]) -> [[u32; 2]; 3] {
    let e = |a: u32, b: u32| if a < b { [a, b] } else { [b, a] };
    [e(t[0], t[1]), e(t[1], t[2]), e(t[2], t[0])]
}

/// Union-find over indices with path halving.
struct DisjointSets {
    parent: Vec<u32>,
}

impl DisjointSets {
    fn new(n: usize) -> Self {
        DisjointSets { parent: (0..n as u32).collect() }
    }

    fn find(&mut self, mut v: u32) -> u32 {
        while self.parent[v as usize] != v {
            let grand = self.parent[self.parent[v as usize] as usize];
            self.parent[v as usize] = grand;
            v = grand;
        }
        v
    }

    fn union(&mut self, a: u32, b: u32) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            self.parent[ra.max(rb) as usize] = ra.min(rb);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetrahedron() -> Mesh {
        let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let t = vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
        Mesh::new(p, t).unwrap()
    }

    #[test]
    fn tetrahedron_measures() {
        let m = tetrahedron();
        assert!((m.signed_volume() - 1.0 / 6.0).abs() < 1e-9);
        let topo = m.topology();
        assert_eq!((topo.vertices, topo.edges, topo.faces, topo.euler), (4, 6, 4, 2));
        assert!(topo.is_watertight());
        assert_eq!(topo.genus(), Some(0));
        assert_eq!(m.edges().len(), 6);
        let area = 1.5 + 0.5 * 3f64.sqrt();
        assert!((m.surface_area() - area).abs() < 1e-6);
    }

    #[test]
    fn rejects_bad_meshes() {
        let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        assert!(Mesh::new(vec![], vec![[0, 1, 2]]).is_err());
        assert!(Mesh::new(p.clone(), vec![]).is_err());
        let err = Mesh::new(p.clone(), vec![[0, 1, 3]]).unwrap_err().to_string();
        assert!(err.contains("triangles[0]") && err.contains("below 3"), "{err}");
        let err = Mesh::new(p.clone(), vec![[0, 1, 1]]).unwrap_err().to_string();
        assert!(err.contains("distinct"), "{err}");
        let mut bad = p.clone();
        bad[2][1] = f32::NAN;
        let err = Mesh::new(bad, vec![[0, 1, 2]]).unwrap_err().to_string();
        assert!(err.contains("positions[2].y"), "{err}");
        let m = Mesh::new(p, vec![[0, 1, 2]]).unwrap();
        assert!(m.clone().with_normals(vec![[0.0; 3]; 2]).is_err());
        assert_eq!(m.degenerate_triangle_count(), 0);
        assert!(m.with_texture(Image::filled(2, 2, 3, 0.5).unwrap()).is_err());
    }

    #[test]
    fn degenerate_triangles_are_counted_and_not_watertight() {
        // Three distinct indices at one position: merging leaves no triangle at all, which
        // is not a closed surface (it was reported "watertight, genus 0").
        let m = Mesh::new(vec![[0.5, 0.5, 0.5]; 3], vec![[0, 1, 2]]).unwrap();
        assert_eq!(m.degenerate_triangle_count(), 1);
        let topo = m.merge_by_position().0.topology();
        assert_eq!(topo.faces, 0);
        assert!(!topo.is_watertight());
        assert_eq!(topo.genus(), None);
        // Collinear corners, and a sliver with two equal corners beside a good triangle.
        let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
        let m = Mesh::new(p, vec![[0, 1, 2], [0, 1, 3], [1, 3, 4]]).unwrap();
        assert_eq!(m.degenerate_triangle_count(), 2);
        assert_eq!(tetrahedron().degenerate_triangle_count(), 0);
    }

    #[test]
    fn orient_outward_flips_closed_inward_meshes_only() {
        let outward = tetrahedron();
        let mut inward = outward.clone();
        inward.flip_winding();
        assert!(inward.signed_volume() < 0.0 && inward.is_closed_inward());
        let mut m = inward.clone();
        assert!(m.orient_outward());
        assert_eq!(m, outward);
        assert!(!m.orient_outward(), "already outward");
        assert_eq!(m, outward);
        // Open meshes have no inside: left as they are, whatever their signed volume.
        let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let mut open = Mesh::new(p, vec![[0, 1, 2], [0, 3, 1], [0, 2, 3]]).unwrap();
        let before = open.clone();
        assert!(!open.orient_outward());
        assert_eq!(open, before);
    }

    #[test]
    fn merge_joins_seams() {
        // Two triangles of a square stored with duplicated seam vertices.
        let p =
            vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [-0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
        let m = Mesh::new(p, vec![[0, 1, 2], [3, 4, 5]]).unwrap();
        assert_eq!(m.topology().components, 2);
        let (merged, remap) = m.merge_by_position();
        assert_eq!(merged.vertex_count(), 4);
        assert_eq!(remap, vec![0, 1, 2, 0, 2, 3]);
        let topo = merged.topology();
        assert_eq!((topo.components, topo.boundary_edges, topo.euler), (1, 4, 1));
    }
}
