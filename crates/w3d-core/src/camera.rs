//! Pinhole and orthographic cameras in the canonical frame.
//!
//! Conventions (see `docs/architecture.md`, "Conventions"): the camera frame is OpenGL's — +x to the right of
//! the image, +y up, the camera looks along −z. Pixel coordinates are continuous with
//! the origin at the top-left corner of the image, x to the right and y down, so the
//! centre of pixel `(i, j)` (column `i`, row `j`) is at `(i + 0.5, j + 0.5)`.
//! *Depth* is the distance in front of the camera along its viewing axis (world units,
//! positive for visible points), for both projections.

use glam::{Mat3, Mat4, Vec3};

use crate::error::{Error, Result};

/// How a camera maps its 3D frame onto the image plane.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(tag = "type", rename_all = "snake_case"))]
pub enum Projection {
    /// Parallel projection; the image spans `[-half_height·aspect, half_height·aspect] ×
    /// [-half_height, half_height]` world units around the viewing axis.
    Orthographic {
        /// Half of the image height in world units (0.75 for the Wonder3D rig).
        half_height: f32,
    },
    /// Pinhole projection with a vertical field of view.
    Perspective {
        /// Full vertical field of view in radians.
        fov_y: f32,
    },
}

impl Projection {
    /// A perspective projection from a lens focal length and a sensor width, both in mm,
    /// for a square image (Blender's convention; 35 mm on 32 mm gives 49.13°).
    pub fn from_lens(focal_mm: f32, sensor_mm: f32) -> Self {
        Projection::Perspective { fov_y: 2.0 * (0.5 * sensor_mm / focal_mm).atan() }
    }
}

/// A ray in world space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    /// Start point (the camera centre, or the image-plane point for orthographic cameras).
    pub origin: Vec3,
    /// Unit direction.
    pub direction: Vec3,
}

/// A camera placed with look-at parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Camera {
    /// Camera centre in world space.
    pub eye: Vec3,
    /// Point the camera looks at.
    pub target: Vec3,
    /// Approximate up direction; the exact up axis is re-orthogonalised.
    pub up: Vec3,
    /// The projection.
    pub projection: Projection,
}

impl Camera {
    /// A look-at camera. Fails if `eye == target`, if `up` is parallel to the viewing
    /// direction, or if the projection's size is not positive and finite.
    pub fn look_at(eye: Vec3, target: Vec3, up: Vec3, projection: Projection) -> Result<Self> {
        let camera = Camera { eye, target, up, projection };
        camera.validate()?;
        Ok(camera)
    }

    /// Checks the invariants [`Camera::look_at`] enforces (used after deserialising).
    pub fn validate(&self) -> Result<()> {
        let forward = self.target - self.eye;
        if !self.eye.is_finite() || !self.target.is_finite() || !self.up.is_finite() {
            return Err(Error::invalid("camera", "finite eye, target and up vectors"));
        }
        if forward.length_squared() < 1e-12 {
            return Err(Error::invalid("camera.target", "a target different from the eye"));
        }
        if forward.normalize().cross(self.up).length_squared() < 1e-12 {
            return Err(Error::invalid("camera.up", "an up vector not parallel to the viewing direction"));
        }
        match self.projection {
            Projection::Orthographic { half_height } if !(half_height > 0.0 && half_height.is_finite()) => {
                Err(Error::invalid("camera.projection.half_height", format!("a positive size, got {half_height}")))
            }
            Projection::Perspective { fov_y } if !(fov_y > 0.0 && fov_y < std::f32::consts::PI) => {
                Err(Error::invalid("camera.projection.fov_y", format!("an angle in (0, π) radians, got {fov_y}")))
            }
            _ => Ok(()),
        }
    }

    /// Unit vector along the viewing axis (camera −z) in world space.
    pub fn forward(&self) -> Vec3 {
        (self.target - self.eye).normalize()
    }

    /// World-space rotation whose columns are the camera's right (+x), up (+y) and
    /// back (+z) axes.
    pub fn basis(&self) -> Mat3 {
        let back = -self.forward();
        let right = self.up.cross(back).normalize();
        let up = back.cross(right);
        Mat3::from_cols(right, up, back)
    }

    /// The world → camera rigid transform (OpenGL view matrix).
    pub fn world_to_camera(&self) -> Mat4 {
        let r = self.basis().transpose();
        Mat4::from_mat3(r) * Mat4::from_translation(-self.eye)
    }

    /// The camera → world rigid transform.
    pub fn camera_to_world(&self) -> Mat4 {
        Mat4::from_translation(self.eye) * Mat4::from_mat3(self.basis())
    }

    /// A world point in the camera frame.
    pub fn to_camera(&self, world: Vec3) -> Vec3 {
        self.basis().transpose() * (world - self.eye)
    }

    /// Distance of a world point in front of the camera along its viewing axis.
    pub fn depth(&self, world: Vec3) -> f32 {
        (world - self.eye).dot(self.forward())
    }

    /// Focal length in pixels for an image `height` pixels tall (perspective only;
    /// `None` for orthographic cameras).
    pub fn focal_pixels(&self, height: u32) -> Option<f32> {
        match self.projection {
            Projection::Perspective { fov_y } => Some(0.5 * height as f32 / (0.5 * fov_y).tan()),
            Projection::Orthographic { .. } => None,
        }
    }

    /// Projects a camera-frame point to normalised device coordinates: x, y in
    /// `[-1, 1]` across the image (y up), and z = depth. `aspect` is width / height.
    pub fn camera_to_ndc(&self, cam: Vec3, aspect: f32) -> Vec3 {
        let depth = -cam.z;
        match self.projection {
            Projection::Orthographic { half_height } => {
                Vec3::new(cam.x / (half_height * aspect), cam.y / half_height, depth)
            }
            Projection::Perspective { fov_y } => {
                let t = (0.5 * fov_y).tan();
                Vec3::new(cam.x / (depth * t * aspect), cam.y / (depth * t), depth)
            }
        }
    }

    /// Projects a world point into a `width × height` image: returns
    /// `(pixel x, pixel y, depth)` with pixel centres at +0.5.
    pub fn project(&self, world: Vec3, width: u32, height: u32) -> Vec3 {
        let ndc = self.camera_to_ndc(self.to_camera(world), width as f32 / height as f32);
        Vec3::new((ndc.x + 1.0) * 0.5 * width as f32, (1.0 - ndc.y) * 0.5 * height as f32, ndc.z)
    }

    /// Inverse of [`Camera::project`]: the world point at pixel `(px, py)` and `depth`.
    pub fn unproject(&self, px: f32, py: f32, depth: f32, width: u32, height: u32) -> Vec3 {
        let aspect = width as f32 / height as f32;
        let nx = px / width as f32 * 2.0 - 1.0;
        let ny = 1.0 - py / height as f32 * 2.0;
        let cam = match self.projection {
            Projection::Orthographic { half_height } => Vec3::new(nx * half_height * aspect, ny * half_height, -depth),
            Projection::Perspective { fov_y } => {
                let t = (0.5 * fov_y).tan();
                Vec3::new(nx * depth * t * aspect, ny * depth * t, -depth)
            }
        };
        self.eye + self.basis() * cam
    }

    /// The ray through pixel position `(px, py)` (use `i + 0.5` for pixel centres).
    /// Orthographic rays start on the plane through the eye; perspective rays at the eye.
    /// A hit at ray parameter `t` has depth `t · direction·forward` (= `t` for orthographic).
    pub fn ray(&self, px: f32, py: f32, width: u32, height: u32) -> Ray {
        match self.projection {
            Projection::Orthographic { .. } => {
                let origin = self.unproject(px, py, 0.0, width, height);
                Ray { origin, direction: self.forward() }
            }
            Projection::Perspective { .. } => {
                let p = self.unproject(px, py, 1.0, width, height);
                Ray { origin: self.eye, direction: (p - self.eye).normalize() }
            }
        }
    }

    /// Unit direction from the camera towards a world point (the viewing direction there;
    /// constant for orthographic cameras).
    pub fn view_direction(&self, world: Vec3) -> Vec3 {
        match self.projection {
            Projection::Orthographic { .. } => self.forward(),
            Projection::Perspective { .. } => (world - self.eye).normalize_or(self.forward()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn front_camera_maps_origin_to_image_centre() {
        let cam = Camera::look_at(
            Vec3::new(0.0, 0.0, 2.0),
            Vec3::ZERO,
            Vec3::Y,
            Projection::Orthographic { half_height: 0.75 },
        )
        .unwrap();
        let p = cam.project(Vec3::ZERO, 256, 256);
        assert_relative_eq!(p.x, 128.0);
        assert_relative_eq!(p.y, 128.0);
        assert_relative_eq!(p.z, 2.0);
        // +x world is to the right, +y world is up (smaller row index).
        let q = cam.project(Vec3::new(0.75, 0.75, 0.0), 256, 256);
        assert_relative_eq!(q.x, 256.0);
        assert_relative_eq!(q.y, 0.0);
    }

    #[test]
    fn lens_gives_blender_fov() {
        let Projection::Perspective { fov_y } = Projection::from_lens(35.0, 32.0) else { unreachable!() };
        assert_relative_eq!(fov_y.to_degrees(), 49.1343, epsilon = 1e-3);
    }

    #[test]
    fn rejects_degenerate_cameras() {
        let ortho = Projection::Orthographic { half_height: 1.0 };
        assert!(Camera::look_at(Vec3::ONE, Vec3::ONE, Vec3::Y, ortho).is_err());
        assert!(Camera::look_at(Vec3::Y, Vec3::ZERO, Vec3::Y, ortho).is_err());
        assert!(Camera::look_at(Vec3::Z, Vec3::ZERO, Vec3::Y, Projection::Perspective { fov_y: 4.0 }).is_err());
        assert!(
            Camera::look_at(Vec3::Z, Vec3::ZERO, Vec3::Y, Projection::Orthographic { half_height: f32::NAN }).is_err()
        );
    }
}
