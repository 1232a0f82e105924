//! World → clip → pixel mapping of one camera, in f64, with the chain rule back to world
//! positions.
//!
//! Clip coordinates `(x, y, w)` follow the homogeneous convention of the reference: NDC is
//! `(x / w, y / w)`. Orthographic cameras have `w = 1`; perspective cameras have `w = depth`.
//! Pixel coordinates follow [`w3d_core::Camera::project`]: origin top-left, y down, pixel
//! centres at `+0.5`.

use glam::{DMat3, DVec3};
use w3d_core::{Camera, Error, Projection, Result};

/// Triangles with a vertex closer than this to the camera plane (world units along the
/// viewing axis) are not drawn; the rasteriser does not clip against the near plane.
pub const NEAR_DEPTH: f64 = 1e-4;

/// One vertex seen by one camera.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct ClipVertex {
    /// Homogeneous clip x.
    pub x: f64,
    /// Homogeneous clip y.
    pub y: f64,
    /// Homogeneous w (1 for orthographic cameras, the depth for perspective ones).
    pub w: f64,
    /// Depth along the viewing axis, world units.
    pub depth: f64,
    /// Pixel column coordinate (continuous, centres at +0.5).
    pub sx: f64,
    /// Pixel row coordinate (continuous, top-down, centres at +0.5).
    pub sy: f64,
}

/// The projection of one camera into a `width × height` image.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Projector {
    world_to_camera: DMat3,
    eye: DVec3,
    kx: f64,
    ky: f64,
    perspective: bool,
    width: f64,
    height: f64,
}

impl Projector {
    pub fn new(camera: &Camera, width: u32, height: u32) -> Self {
        let aspect = width as f64 / height as f64;
        let (half_height, perspective) = match camera.projection {
            Projection::Orthographic { half_height } => (half_height as f64, false),
            Projection::Perspective { fov_y } => ((0.5 * fov_y as f64).tan(), true),
        };
        let basis = camera.basis().as_dmat3();
        Projector {
            world_to_camera: basis.transpose(),
            eye: camera.eye.as_dvec3(),
            kx: 1.0 / (half_height * aspect),
            ky: 1.0 / half_height,
            perspective,
            width: width as f64,
            height: height as f64,
        }
    }

    pub fn project(&self, p: DVec3) -> ClipVertex {
        let cam = self.world_to_camera * (p - self.eye);
        let depth = -cam.z;
        let w = if self.perspective { depth } else { 1.0 };
        let (x, y) = (self.kx * cam.x, self.ky * cam.y);
        ClipVertex { x, y, w, depth, sx: (x / w + 1.0) * 0.5 * self.width, sy: (1.0 - y / w) * 0.5 * self.height }
    }

    pub fn project_all(&self, positions: &[[f32; 3]]) -> Vec<ClipVertex> {
        positions.iter().map(|&p| self.project(to_dvec(p))).collect()
    }

    /// NDC `(X, Y)` of the centre of pixel `(column, row)`.
    pub fn pixel_ndc(&self, column: u32, row: u32) -> (f64, f64) {
        ((2.0 * column as f64 + 1.0) / self.width - 1.0, 1.0 - (2.0 * row as f64 + 1.0) / self.height)
    }

    /// Gradient of pixel coordinates `(sx, sy)` pulled back to clip `(x, y, w)`.
    pub fn screen_grad_to_clip(&self, v: &ClipVertex, gsx: f64, gsy: f64) -> [f64; 3] {
        let (hw, hh) = (0.5 * self.width, 0.5 * self.height);
        let gx = gsx * hw / v.w;
        let gy = -gsy * hh / v.w;
        let gw = -(gx * v.x + gy * v.y) / v.w;
        [gx, gy, gw]
    }

    /// Pulls a gradient on clip `(x, y, w)` and depth back to the world position.
    pub fn clip_grad_to_world(&self, g: [f64; 4]) -> DVec3 {
        let gw = if self.perspective { g[2] } else { 0.0 };
        let g_cam = DVec3::new(self.kx * g[0], self.ky * g[1], -gw - g[3]);
        self.world_to_camera.transpose() * g_cam
    }
}

/// Checks an image size: both sides in `1..=16384`.
pub(crate) fn check_size(width: u32, height: u32) -> Result<()> {
    for (field, v) in [("width", width), ("height", height)] {
        if v == 0 || v > 16384 {
            return Err(Error::invalid(field, format!("an image side in 1..=16384 pixels, got {v}")));
        }
    }
    Ok(())
}

/// Converts f32 world positions to f64.
pub(crate) fn to_dvec(p: [f32; 3]) -> DVec3 {
    DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}
