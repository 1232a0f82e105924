//! Render helpers: normal, mask, depth and colour images of a mesh through a whole rig,
//! and the oracle view set used by `wonder3d render`.

use glam::Vec3;
use rayon::prelude::*;
use w3d_core::{Image, Mesh, Result, ViewImages, ViewRig, ViewSet};

use crate::antialias::{EdgeTopology, antialias};
use crate::interpolate::interpolate;
use crate::raster::{NO_TRIANGLE, Raster, rasterize_views};
use crate::texture::{WrapMode, texture};

/// Which normals [`render_normals`] shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NormalMode {
    /// Area-weighted vertex normals (vertices welded by position, so UV seams do not show),
    /// interpolated and renormalised per pixel.
    Smooth,
    /// The face normal of the visible triangle.
    Flat,
}

/// Rasterises a mesh through every camera of `rig` at `size × size` pixels.
pub fn rasterize_rig(mesh: &Mesh, rig: &ViewRig, size: u32) -> Result<Vec<Raster>> {
    rig.validate()?;
    let cameras: Vec<_> = rig.cameras().copied().collect();
    rasterize_views(mesh.positions(), mesh.triangles(), &cameras, size, size)
}

/// Unit normals per vertex, area-weighted over all vertices sharing the position
/// ([`w3d_core::normals::welded_vertex_normals`]), flattened to `x, y, z` per vertex.
fn welded_vertex_normals(mesh: &Mesh) -> Vec<f32> {
    w3d_core::normals::welded_vertex_normals(mesh.positions(), mesh.triangles()).into_iter().flatten().collect()
}

fn image(raster: &Raster, channels: u32, data: Vec<f32>) -> Result<Image> {
    Image::new(raster.width, raster.height, channels, data)
}

/// World-space (canonical frame) unit normals, 3 channels, 0 on the background.
fn normal_image(mesh: &Mesh, raster: &Raster, mode: NormalMode, vertex_normals: &[f32]) -> Result<Image> {
    let mut data = match mode {
        NormalMode::Smooth => interpolate(vertex_normals, 3, mesh.triangles(), raster)?,
        NormalMode::Flat => {
            let faces = mesh.face_normals();
            raster.triangle.iter().flat_map(|&t| if t == NO_TRIANGLE { [0.0; 3] } else { faces[t as usize] }).collect()
        }
    };
    for n in data.chunks_exact_mut(3) {
        let v = Vec3::new(n[0], n[1], n[2]).normalize_or_zero();
        n.copy_from_slice(&v.to_array());
    }
    image(raster, 3, data)
}

/// Anti-aliased coverage in `[0, 1]`, 1 channel.
fn mask_image(mesh: &Mesh, raster: &Raster, topology: &EdgeTopology) -> Result<Image> {
    let aa = antialias(&raster.coverage(), 1, raster, mesh.positions(), mesh.triangles(), topology)?;
    image(raster, 1, aa.image.into_iter().map(|v| v.clamp(0.0, 1.0)).collect())
}

/// Depth along the view axis (world units), 0 on the background, 1 channel.
fn depth_image(raster: &Raster) -> Result<Image> {
    image(raster, 1, raster.depth.clone())
}

/// sRGB colour, 3 channels, 0 on the background.
fn colour_image(mesh: &Mesh, raster: &Raster) -> Result<Image> {
    let data = match (mesh.texture(), mesh.uvs(), mesh.colours()) {
        (Some(tex), Some(uvs), _) => {
            let flat: Vec<f32> = uvs.iter().flatten().copied().collect();
            let uv_image = interpolate(&flat, 2, mesh.triangles(), raster)?;
            let uv: Vec<[f32; 2]> = uv_image.chunks_exact(2).map(|p| [p[0], p[1]]).collect();
            let c = tex.channels() as usize;
            let rgb = texture(tex, &uv, WrapMode::Repeat)?;
            rgb.chunks_exact(c)
                .zip(&raster.triangle)
                .flat_map(|(p, &t)| if t == NO_TRIANGLE { [0.0; 3] } else { [p[0], p[1], p[2]] })
                .collect()
        }
        (_, _, Some(colours)) => {
            let flat: Vec<f32> = colours.iter().flatten().copied().collect();
            interpolate(&flat, 3, mesh.triangles(), raster)?
        }
        _ => raster.triangle.iter().flat_map(|&t| [if t == NO_TRIANGLE { 0.0 } else { 0.5 }; 3]).collect(),
    };
    image(raster, 3, data)
}

/// Normal images of a mesh through every view of `rig` (`size × size`, rig order):
/// world-space unit normals in `[-1, 1]` (encode with `(n + 1) / 2` for files), 0 on the
/// background.
pub fn render_normals(mesh: &Mesh, rig: &ViewRig, size: u32, mode: NormalMode) -> Result<Vec<Image>> {
    let normals = welded_vertex_normals(mesh);
    rasterize_rig(mesh, rig, size)?.par_iter().map(|r| normal_image(mesh, r, mode, &normals)).collect()
}

/// Anti-aliased silhouette masks (coverage in `[0, 1]`, 1 channel), one per view.
pub fn render_mask(mesh: &Mesh, rig: &ViewRig, size: u32) -> Result<Vec<Image>> {
    let topology = EdgeTopology::new(mesh.positions(), mesh.triangles())?;
    rasterize_rig(mesh, rig, size)?.par_iter().map(|r| mask_image(mesh, r, &topology)).collect()
}

/// Depth images (world units along each camera's viewing axis, 0 on the background).
pub fn render_depth(mesh: &Mesh, rig: &ViewRig, size: u32) -> Result<Vec<Image>> {
    rasterize_rig(mesh, rig, size)?.iter().map(depth_image).collect()
}

/// Colour images (3 channels, sRGB as stored in the mesh, 0 on the background): the
/// texture sampled bilinearly (repeat addressing) when the mesh has one, else the vertex
/// colours interpolated, else a neutral grey (0.5).
pub fn render_colours(mesh: &Mesh, rig: &ViewRig, size: u32) -> Result<Vec<Image>> {
    rasterize_rig(mesh, rig, size)?.par_iter().map(|r| colour_image(mesh, r)).collect()
}

/// The largest view side the front ends (`wonder3d render --size`, Python's `render_views`)
/// accept for [`render_oracle_views`]: a 4096² view set of the 16-view rig takes about 13 GB
/// while rendering (rasters plus normal, colour, mask and depth images, ~50 bytes a pixel a
/// view); larger sizes used to abort on allocation.
pub const MAX_VIEW_SIZE: u32 = 4096;

/// The oracle views of a mesh for `rig` at `size × size`, as a [`ViewSet`] owning a copy of
/// `rig`: smooth world-space normals, colours (as [`render_colours`]), anti-aliased masks and
/// depth, ready for [`ViewSet::save`]. The mesh is used as given (normalise it to the unit cube first for
/// the canonical framing).
pub fn render_oracle_views(mesh: &Mesh, rig: &ViewRig, size: u32) -> Result<ViewSet> {
    let normals = welded_vertex_normals(mesh);
    let topology = EdgeTopology::new(mesh.positions(), mesh.triangles())?;
    let rasters = rasterize_rig(mesh, rig, size)?;
    let views = rasters
        .par_iter()
        .zip(&rig.views)
        .map(|(r, view)| {
            Ok(ViewImages {
                name: view.name.clone(),
                normal: normal_image(mesh, r, NormalMode::Smooth, &normals)?,
                colour: Some(colour_image(mesh, r)?),
                mask: mask_image(mesh, r, &topology)?,
                depth: Some(depth_image(r)?),
            })
        })
        .collect::<Result<Vec<_>>>()?;
    ViewSet::new(rig.clone(), views)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetra() -> Mesh {
        let positions = vec![[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 2.0]];
        let mut mesh = Mesh::new(positions, vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]).unwrap();
        mesh.normalize_unit_cube();
        mesh
    }

    #[test]
    fn oracle_views_are_consistent() {
        let mesh = tetra();
        let rig = ViewRig::wonder3d_ortho();
        let set = render_oracle_views(&mesh, &rig, 32).unwrap();
        assert_eq!((set.rig(), set.len(), set.width(), set.height()), (&rig, 6, 32, 32));
        for v in set.views() {
            let depth = v.depth.as_ref().unwrap().data();
            let colour = v.colour.as_ref().unwrap().data();
            let mut covered = 0;
            for (i, n) in v.normal.data().chunks_exact(3).enumerate() {
                let len = Vec3::new(n[0], n[1], n[2]).length();
                if depth[i] > 0.0 {
                    covered += 1;
                    assert!((len - 1.0).abs() < 1e-4);
                    assert_eq!(colour[3 * i], 0.5);
                } else {
                    assert_eq!(len, 0.0);
                    assert_eq!(colour[3 * i], 0.0);
                }
            }
            assert!(covered > 50, "{}: {covered}", v.name);
            assert!(v.mask.data().iter().all(|&m| (0.0..=1.0).contains(&m)));
        }
        // The front view sees the face with normal +z-ish in the middle.
        let front = &set.views()[0];
        let mid = front.normal.pixel(12, 20);
        assert!(mid[2] > 0.3, "{mid:?}");
        assert_eq!(render_normals(&mesh, &rig, 32, NormalMode::Smooth).unwrap()[0], front.normal);
        assert_eq!(render_mask(&mesh, &rig, 32).unwrap()[2], set.views()[2].mask);
        assert_eq!(&render_depth(&mesh, &rig, 32).unwrap()[3], set.views()[3].depth.as_ref().unwrap());
        assert_eq!(&render_colours(&mesh, &rig, 32).unwrap()[5], set.views()[5].colour.as_ref().unwrap());
        let flat = render_normals(&mesh, &rig, 32, NormalMode::Flat).unwrap();
        assert_ne!(flat[0], front.normal);
    }

    #[test]
    fn zero_size_is_an_error() {
        assert!(render_oracle_views(&tetra(), &ViewRig::wonder3d_ortho(), 0).is_err());
    }
}
